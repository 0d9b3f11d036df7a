"""`archself init`: a valid, runnable starting point."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from archself.cli import app


def test_init_writes_a_valid_file_that_adapts(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    result = runner.invoke(app, ["init", "tank"])
    assert result.exit_code == 0, result.stderr
    text = (tmp_path / "tank.yaml").read_text()
    first = text.splitlines()[0]
    assert first.startswith("# yaml-language-server: $schema=")
    schema = (tmp_path / first.split("$schema=", 1)[1]).resolve()
    assert schema.name == "architecture.schema.json" and schema.is_file()
    assert runner.invoke(app, ["validate", "--strict", "tank.yaml"]).exit_code == 0
    out = runner.invoke(app, ["simulate", "tank.yaml", "-s", "level_drift", "--compare", "--json"])
    assert out.exit_code == 0, out.stderr
    fixed, adaptive = json.loads(out.stdout)
    assert [s["to"] for s in adaptive["switches"]] == ["on_b"]
    assert adaptive["metrics"]["final_error_m"] < 0.5 * fixed["metrics"]["final_error_m"]


def test_init_never_overwrites_without_force(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.yaml").write_text("my work\n")
    result = CliRunner().invoke(app, ["init", "mine"])
    assert result.exit_code == 1 and "exists" in result.stderr
    assert (tmp_path / "mine.yaml").read_text() == "my work\n"
    assert CliRunner().invoke(app, ["init", "mine", "--force"]).exit_code == 0
    assert "archself: 1" in (tmp_path / "mine.yaml").read_text()


def test_init_quotes_the_name(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert CliRunner().invoke(app, ["init", 'odd: "name"']).exit_code == 0
    from archself.loader import load_architecture

    assert load_architecture(tmp_path / 'odd: "name".yaml').arch.name == 'odd: "name"'
