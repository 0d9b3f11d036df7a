"""Hardening of the command line (issue 19): inputs never overwritten, exit codes,
orphan-free campaigns, worker deaths, work estimates, atomic reports, messages.

Processes and signals are bounded in time (every wait has a timeout) and use no
network but the loopback.
"""

from __future__ import annotations

import signal
import sys
from pathlib import Path

import pytest

from archself.atomic import protect, write_text
from archself.cli import main
from archself.errors import OutputError

from conftest import FIXTURES

MINIMAL = FIXTURES / "valid" / "minimal.yaml"
ARCHSELF = [
    str(Path(sys.executable).with_name("archself"))
]


def run(args: list[str], monkeypatch: pytest.MonkeyPatch, capsys) -> tuple[int, str, str]:
    """``archself ARGS`` in this process, through ``main()`` (its exit-code mapping)."""
    monkeypatch.setattr(sys, "argv", ["archself", *map(str, args)])
    old = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(SystemExit) as info:
            main()
    finally:
        signal.signal(signal.SIGTERM, old)
    cap = capsys.readouterr()
    code = info.value.code
    return (code if isinstance(code, int) else (0 if code is None else 1)), cap.out, cap.err


@pytest.fixture
def arch(tmp_path: Path) -> Path:
    p = tmp_path / "X.yaml"
    p.write_bytes(MINIMAL.read_bytes())
    return p


def one_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "internal error" not in lines[0] and "Traceback" not in err
    return lines[0]


# --------------------------------------------------------------------------- 1. input destroyed
def test_simulate_trace_onto_the_input_is_refused(arch, monkeypatch, capsys) -> None:
    before = arch.read_bytes()
    code, _, err = run(["simulate", arch, "-s", "calm", "--trace", arch], monkeypatch, capsys)
    assert code == 1 and "is the input file X.yaml" in one_line(err)
    assert arch.read_bytes() == before


def test_hard_link_and_symlink_to_the_input_are_refused(arch, monkeypatch, capsys) -> None:
    before = arch.read_bytes()
    (arch.parent / "hard.json").hardlink_to(arch)
    (arch.parent / "soft.json").symlink_to(arch)
    for name in ("hard.json", "soft.json"):
        code, _, err = run(
            ["simulate", arch, "-s", "calm", "--trace", arch.parent / name], monkeypatch, capsys
        )
        assert code == 1 and "refusing to write over it" in one_line(err), name
    assert arch.read_bytes() == before


def test_the_fixed_trace_sibling_is_checked_too(tmp_path, monkeypatch, capsys) -> None:
    src = tmp_path / "run.fixed.json"  # the input is named like the '.fixed' sibling
    src.write_bytes(MINIMAL.read_bytes())
    before = src.read_bytes()
    code, _, err = run(
        ["simulate", src, "-s", "calm", "--compare", "--trace", tmp_path / "run.json"],
        monkeypatch,
        capsys,
    )
    assert code == 1 and "is the input file run.fixed.json" in one_line(err)
    assert src.read_bytes() == before and not (tmp_path / "run.json").exists()


def test_campaign_out_onto_the_input_is_refused_even_with_force(
    arch, monkeypatch, capsys
) -> None:
    before = arch.read_bytes()
    code, _, err = run(
        ["campaign", arch, "-s", "calm", "--seeds", "1", "-o", arch, "--force"], monkeypatch, capsys
    )
    assert code == 1 and "--out is the input file" in one_line(err)
    assert arch.read_bytes() == before


def test_campaign_trace_onto_the_input_is_refused(tmp_path, monkeypatch, capsys) -> None:
    traces = tmp_path / "traces"
    traces.mkdir()
    src = traces / "calm_r0000_fixed.json"  # exactly the name of replicate 0's fixed trace
    src.write_bytes(MINIMAL.read_bytes())
    before = src.read_bytes()
    code, _, err = run(
        ["campaign", src, "-s", "calm", "--seeds", "1", "--traces", traces,
         "-o", tmp_path / "r.parquet"],
        monkeypatch,
        capsys,
    )
    assert code == 1 and "overwrite the input file" in one_line(err)
    assert src.read_bytes() == before


def test_report_into_the_folder_of_its_input_is_refused(arch, monkeypatch, capsys) -> None:
    before = arch.read_bytes()
    for out in (arch.parent, arch.parent.parent):
        code, _, err = run(["report", arch, "-o", out, "--force"], monkeypatch, capsys)
        assert code == 1 and "holds the input file" in one_line(err)
    assert arch.read_bytes() == before


def test_write_over_a_protected_input_is_refused_at_the_write(tmp_path) -> None:
    f = tmp_path / "in.yaml"
    f.write_text("a: 1")
    with protect([f]), pytest.raises(OutputError, match="is the input file"):
        write_text(f, "overwritten")
    assert f.read_text() == "a: 1"
    write_text(f, "free again")  # protection ends with the block
    assert f.read_text() == "free again"
