"""Loader: YAML 1.2 parsing, caps, positions and golden error messages."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from archself.cli import app
from archself.errors import ArchselfError, LoadError
from archself.model.loader import (
    MAX_FILE_BYTES,
    SchemaError,
    load_architecture,
    load_data,
    load_text,
)

from conftest import DIFFDRIVE, FIXTURES, ROOT, compare_golden

INVALID = sorted((FIXTURES / "invalid").glob("*.yaml"))


@pytest.mark.parametrize("path", INVALID, ids=[p.stem for p in INVALID])
def test_invalid_fixture_gives_golden_one_line_error(path: Path, regen: bool, monkeypatch) -> None:
    monkeypatch.chdir(ROOT)
    rel = path.relative_to(ROOT)
    result = CliRunner().invoke(app, ["validate", str(rel)])
    assert result.exit_code == 1
    assert result.stdout == ""
    assert "Traceback" not in result.stderr
    lines = result.stderr.splitlines()
    assert lines and all(line.startswith(f"{rel}:") for line in lines), "one line per finding"
    assert any(": error: " in line for line in lines)
    compare_golden(_golden(path), result.stderr, regen)


def _golden(path: Path) -> Path:
    """``NAME.expected``, or ``NAME.pure.expected`` where that exists and the pure-Python
    YAML parser runs (no ruamel.yaml.clib: CI's last leg), whose wording differs."""
    import importlib.util

    pure = path.with_suffix(".pure.expected")
    return pure if pure.exists() and importlib.util.find_spec("_ruamel_yaml") is None \
        else path.with_suffix(".expected")


def test_goldens_do_not_depend_on_installed_plugins(tmp_path: Path, monkeypatch) -> None:
    """A third-party ``sensor.*`` type installed beside archself leaves the goldens alone."""
    import importlib.metadata
    import sys

    from archself import registry

    from conftest import in_repo_entry_points

    info = tmp_path / "third_cam-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: third-cam\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[archself.modules]\nsensor.camera_x = third_cam:Cam\n")
    monkeypatch.setattr(sys, "path", [str(tmp_path), *sys.path])
    group = importlib.metadata.entry_points(group=registry.ENTRY_POINT_GROUP)
    assert "sensor.camera_x" in group.names  # installed, as far as Python knows
    assert "sensor.camera_x" not in in_repo_entry_points()
    assert "sensor.camera_x" not in registry.known_types()
    monkeypatch.chdir(ROOT)
    out = CliRunner().invoke(app, ["validate", "tests/fixtures/invalid/hostile_name.yaml"])
    assert "camera_x" not in out.stderr
    compare_golden(FIXTURES / "invalid" / "hostile_name.expected", out.stderr, False)


def test_positions_point_at_the_offending_node() -> None:
    with pytest.raises(SchemaError) as info:
        load_architecture(FIXTURES / "invalid" / "wrong_type.yaml")
    f = info.value.findings[0]
    assert (f.line, f.col, f.path) == (20, 66, "runtime.stability.horizon_steps")
    line = (FIXTURES / "invalid" / "wrong_type.yaml").read_text().splitlines()[f.line - 1]
    assert line[f.col - 1 :].startswith("ten")


def test_unknown_key_suggests_the_close_one() -> None:
    with pytest.raises(SchemaError) as info:
        load_architecture(FIXTURES / "invalid" / "unknown_field.yaml")
    assert "did you mean 'params'?" in str(info.value)


def test_yaml_12_scalars() -> None:
    data, _ = load_data("a: yes\nb: 1e-3\nc: 0o10\nd: on\ne: true\n")
    assert data == {"a": "yes", "b": 0.001, "c": 8, "d": "on", "e": True}


def test_alias_bomb_is_refused_without_expansion() -> None:
    text = (FIXTURES / "invalid" / "alias_bomb.yaml").read_text()
    assert len(text) < 1024
    with pytest.raises(LoadError, match="alias bomb"):
        load_data(text)


def test_a_few_aliases_are_fine() -> None:
    data, _ = load_data("base: &b {x: 1}\none: *b\ntwo: *b\n")
    assert data["one"] == data["two"] == {"x": 1}


def test_oversized_file_is_refused(tmp_path: Path) -> None:
    big = tmp_path / "big.yaml"
    big.write_bytes(b"# " + b"x" * MAX_FILE_BYTES + b"\n")
    with pytest.raises(LoadError, match="cap") as info:
        load_architecture(big)
    assert str(info.value).startswith(f"{big}: ")


def test_missing_file_and_directory(tmp_path: Path) -> None:
    with pytest.raises(LoadError, match="no such file"):
        load_architecture(tmp_path / "nope.yaml")
    with pytest.raises(LoadError, match="directory"):
        load_architecture(tmp_path)


def test_not_utf8(tmp_path: Path) -> None:
    p = tmp_path / "latin1.yaml"
    p.write_bytes("name: caf\xe9\n".encode("latin-1"))
    with pytest.raises(LoadError, match="UTF-8"):
        load_architecture(p)


def test_python_tags_are_never_constructed() -> None:
    with pytest.raises(LoadError, match="unsupported YAML tag") as info:
        load_data("a: !!python/object/apply:os.system ['echo pwned']\n", "t.yaml")
    assert str(info.value).startswith("t.yaml:1:4:")


def test_explicit_core_tags_are_honoured() -> None:
    data, _ = load_data("a: !!str 5\nb: !!float 1\nc: '1'\nd: 1_000\n")
    assert data == {"a": "5", "b": 1.0, "c": "1", "d": "1_000"}


def test_float_tag_on_hex_and_octal_is_the_number_or_a_located_error() -> None:
    data, _ = load_data("a: !!float 0x1F\nb: !!float 0o17\n")
    assert data == {"a": 31.0, "b": 15.0} and isinstance(data["a"], float)
    with pytest.raises(LoadError, match="out of the range of a float") as info:
        load_data("a: !!float 0x" + "F" * 300 + "\n", "t.yaml")
    assert str(info.value).startswith("t.yaml:1:4:")


def test_diffdrive_loads_with_positions() -> None:
    loaded = load_architecture(DIFFDRIVE)
    assert loaded.arch.name == "diffdrive"
    assert set(loaded.arch.configurations) >= {"a1", "a2", "a3"}
    line, col = loaded.source.locate(("modules", "imu", "kind"))
    assert DIFFDRIVE.read_text().splitlines()[line - 1][col - 1 :].startswith("kind")


def test_every_error_is_an_archself_error() -> None:
    for text in ["", "[", "a: [", ":", "- 1", "archself: 1", "{a: 1, a: 2}", "\t- x", "*x"]:
        with pytest.raises(ArchselfError):
            load_text(text)


def test_validate_json_output(monkeypatch) -> None:
    monkeypatch.chdir(ROOT)
    result = CliRunner().invoke(
        app, ["validate", "--json", "tests/fixtures/invalid/bad_kind.yaml"]
    )
    assert result.exit_code == 1
    (report,) = json.loads(result.stdout)  # a list, even for one file
    assert report["ok"] is False
    (f,) = report["findings"]
    assert f["severity"] == "error" and f["path"] == "modules.level_sensor.kind"
    assert (f["line"], f["col"]) == (5, 11)


def test_a_pipe_is_refused_before_reading() -> None:
    """An anonymous pipe (``/dev/fd/N``) is not a regular file: refused, nothing read."""
    import os

    from archself.errors import LoadError
    from archself.io.yaml_source import read_text

    r, w = os.pipe()
    try:
        os.write(w, b"a: 1\n")
        with pytest.raises(LoadError, match="is a FIFO"):
            read_text(f"/dev/fd/{r}")
        assert os.read(r, 100) == b"a: 1\n", "the pipe was not read"
    finally:
        os.close(w)
        os.close(r)


def test_loading_leaves_the_garbage_collector_as_it_was() -> None:
    """The loader pauses the cyclic collector while it works, and restores it, errors or not."""
    import gc

    assert load_architecture(DIFFDRIVE).arch.edges
    assert gc.isenabled()
    with pytest.raises(SchemaError):
        load_text("archself: 1\nnmae: x\n", "x.yaml")
    assert gc.isenabled()
    gc.disable()
    try:
        load_architecture(DIFFDRIVE)
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_loading_works_without_ruamel_yaml_clib() -> None:
    """Pure-Python ruamel.yaml (PyPy, or no wheel of the C extension): the same model."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "sys.modules['_ruamel_yaml'] = None  # as if ruamel.yaml.clib were not installed\n"
        "from archself.model.loader import load_architecture\n"
        f"a = load_architecture({str(DIFFDRIVE)!r}).arch\n"
        "print(len(a.modules), len(a.edges), a.runtime.threshold)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    arch = load_architecture(DIFFDRIVE).arch
    assert proc.stdout.split() == [str(len(arch.modules)), str(len(arch.edges)),
                                   str(arch.runtime.threshold)]
