"""Hardening against bad input and failed writes; generated architectures always run."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from archself.check import check, has_errors
from archself.cli import app
from archself.errors import OutputError
from archself.io.files import write_text
from archself.model.generate import generate_architecture
from archself.model.loader import MAX_FILE_BYTES, load_text

from conftest import FIXTURES

MINIMAL = FIXTURES / "valid" / "minimal.yaml"


# --------------------------------------------------------------------------- atomic output
def test_failed_write_keeps_the_old_file(tmp_path: Path, monkeypatch) -> None:
    target = tmp_path / "result.json"
    target.write_text("good")

    def boom(src: str, dst: str) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OutputError, match="No space left"):
        write_text(target, "new and half-written")
    assert target.read_text() == "good"
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"], "temporary file removed"


def test_interrupted_write_keeps_the_old_file(tmp_path: Path, monkeypatch) -> None:
    target = tmp_path / "trace.json"
    target.write_text("good")
    real_fdopen = os.fdopen

    class Interrupting:
        def __init__(self, fh):
            self.fh = fh

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

        def write(self, data):
            self.fh.write(data[:10])
            raise KeyboardInterrupt

    monkeypatch.setattr(os, "fdopen", lambda fd, mode: Interrupting(real_fdopen(fd, mode)))
    with pytest.raises(KeyboardInterrupt):
        write_text(target, "x" * 1000)
    assert target.read_text() == "good"
    assert len(list(tmp_path.iterdir())) == 1


def test_written_files_get_the_usual_mode(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    write_text(target, "{}")
    mask = os.umask(0)
    os.umask(mask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~mask


def test_missing_output_folder_is_a_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="does not exist"):
        write_text(tmp_path / "no" / "such" / "dir" / "x.json", "{}")
    result = CliRunner().invoke(app, ["schema", "-o", str(tmp_path / "nope" / "s.json")])
    assert result.exit_code == 1
    assert "does not exist" in result.stderr and len(result.stderr.splitlines()) == 1


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write into read-only folders")
def test_read_only_folder(tmp_path: Path) -> None:
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(OutputError, match="cannot write"):
            write_text(ro / "x.json", "{}")
    finally:
        ro.chmod(0o700)


def _denied(*args, **kwargs):
    raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))


OUTPUT_COMMANDS = {
    "schema": lambda out: ["schema", "-o", str(out)],
    "simulate --trace": lambda out: [
        "simulate",
        str(MINIMAL),
        "-s",
        "calm",
        "--fixed",
        "--trace",
        str(out),
    ],
}


@pytest.mark.parametrize("where", ["create", "replace"])
@pytest.mark.parametrize("command", sorted(OUTPUT_COMMANDS))
def test_unwritable_output_through_the_cli(tmp_path: Path, monkeypatch, command, where) -> None:
    """What test_read_only_folder checks, also as root (CI): the folder refuses the write.

    The temporary file cannot be created (``os.open``) or cannot be renamed over the
    target (``os.replace``): one line on stderr, exit 1, no traceback, the good file kept
    and no temporary file left behind.
    """
    from archself.io import files as atomic

    target = tmp_path / "out.json"
    target.write_text("good")
    if where == "create":  # only the exclusive create of the temporary file is refused
        real_open = os.open

        def create_denied(path, flags, *args, **kwargs):
            if flags & os.O_EXCL:
                _denied()
            return real_open(path, flags, *args, **kwargs)

        monkeypatch.setattr(atomic.os, "open", create_denied)
    else:
        monkeypatch.setattr(atomic.os, "replace", _denied)
    result = CliRunner().invoke(app, OUTPUT_COMMANDS[command](target))
    assert result.exit_code == 1, result.output
    assert result.stderr == f"{target}: cannot write: Permission denied\n"
    assert "Traceback" not in result.output
    assert isinstance(result.exception, SystemExit)  # handled, not a PermissionError
    assert target.read_text() == "good"
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"], "temporary file removed"


def test_oversized_file_through_the_cli(tmp_path: Path) -> None:
    """``archself validate`` of a file over the loader's size cap: refused before reading."""
    big = tmp_path / "big.yaml"
    with big.open("wb") as fh:  # sparse: the size is checked with stat(), nothing is read
        fh.truncate(MAX_FILE_BYTES + 1)
    result = CliRunner().invoke(app, ["validate", str(big)])
    assert result.exit_code == 1
    assert result.stderr == (
        f"{big}: error: file is {MAX_FILE_BYTES + 1} bytes, "
        f"larger than the {MAX_FILE_BYTES}-byte cap\n"
    )
    assert "Traceback" not in result.output
    assert result.stdout == ""


def test_output_path_that_is_a_folder(tmp_path: Path) -> None:
    (tmp_path / "taken").mkdir()
    with pytest.raises(OutputError):
        write_text(tmp_path / "taken", "{}")
    assert (tmp_path / "taken").is_dir()


# --------------------------------------------------------------------------- generated files
FAULT_KINDS = ["bias", "bias_drift", "effectiveness_loss", "noise_increase", "dropout", "stuck"]


@st.composite
def generated_architectures(draw) -> str:
    n = draw(st.integers(2, 25))
    faults = []
    for _ in range(draw(st.integers(0, 3))):
        faults.append({
            "module": f"m{draw(st.integers(0, n - 1))}",
            "kind": draw(st.sampled_from(FAULT_KINDS)),
            "onset_s": draw(st.floats(0, 4, allow_nan=False)),
            "magnitude": draw(st.floats(-5, 5, allow_nan=False)),
        })
    return generate_architecture(
        n,
        seed=draw(st.integers(0, 2**16)),
        fan_in=draw(st.integers(1, 4)),
        feedback=draw(st.integers(0, 3)),
        scenarios={"s": {"duration_s": 5, "faults": faults}},
    )


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(generated_architectures(), st.booleans())
def test_any_valid_generated_file_compiles_and_runs(text: str, adaptive: bool) -> None:
    from archself.runtime import MapeK
    from archself.sim.run import simulate

    loaded = load_text(text, "generated.yaml")
    findings = check(loaded)
    assert not has_errors(findings), [str(f) for f in findings]
    arch = loaded.arch
    result = simulate(arch, "s", seed=1, adapt=MapeK(arch) if adaptive else None)
    assert len(result.series["t"]) == 50
    assert result.mode == ("adaptive" if adaptive else "fixed")
