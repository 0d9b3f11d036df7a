"""`archself init`: a valid, runnable starting point."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from archself.cli import app
from archself.model.schema import SCHEMA_ID, schema_text


def test_init_writes_a_valid_file_that_adapts(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    result = runner.invoke(app, ["init", "tank"])
    assert result.exit_code == 0, result.stderr
    text = (tmp_path / "tank.yaml").read_text()
    first = text.splitlines()[0]
    # no project schema in or above tmp_path: the published URL, never site-packages
    assert first == "# yaml-language-server: $schema=" + SCHEMA_ID
    assert runner.invoke(app, ["validate", "--strict", "tank.yaml"]).exit_code == 0
    out = runner.invoke(app, ["simulate", "tank.yaml", "-s", "level_drift", "--compare", "--json"])
    assert out.exit_code == 0, out.stderr
    fixed, adaptive = json.loads(out.stdout)["runs"]
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
    from archself.model.loader import load_architecture

    assert load_architecture(tmp_path / 'odd: "name".yaml').arch.name == 'odd: "name"'


@pytest.mark.parametrize("args", [["a\tb"], ["a\nb"], ["x" * 129], ["t", "--schema", "a\nb"]])
def test_init_refuses_a_name_or_schema_its_file_could_not_hold(tmp_path: Path, monkeypatch,
                                                             args: list[str]) -> None:
    # the name went into `name:` (no control characters, <= 128) and the comments, the
    # schema into the modeline: the file written did not validate (a newline broke the YAML)
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["init", *args])
    assert result.exit_code == 2, result.output
    assert len(result.stderr.strip().splitlines()) == 1 and "expected" in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_init_points_at_the_project_schema_never_into_a_venv(tmp_path: Path, monkeypatch):
    project = tmp_path / "proj"
    (project / "schemas").mkdir(parents=True)
    (project / "schemas" / "architecture.schema.json").write_text(schema_text())
    (project / "plants").mkdir()
    monkeypatch.chdir(project / "plants")
    assert CliRunner().invoke(app, ["init", "tank"]).exit_code == 0
    first = (project / "plants" / "tank.yaml").read_text().splitlines()[0]
    assert first == "# yaml-language-server: $schema=../schemas/architecture.schema.json"
    # a schema inside an installed package is not a project's
    venv = tmp_path / "venv" / "lib" / "site-packages"
    (venv / "schemas").mkdir(parents=True)
    (venv / "schemas" / "architecture.schema.json").write_text("{}")
    monkeypatch.chdir(venv)
    assert CliRunner().invoke(app, ["init", "x"]).exit_code == 0
    assert (venv / "x.yaml").read_text().splitlines()[0].endswith("$schema=" + SCHEMA_ID)


def test_init_schema_copy_and_explicit_reference(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert CliRunner().invoke(app, ["init", "tank", "--schema", "copy"]).exit_code == 0
    first = (tmp_path / "tank.yaml").read_text().splitlines()[0]
    assert first == "# yaml-language-server: $schema=architecture.schema.json"
    assert (tmp_path / "architecture.schema.json").read_text() == schema_text()
    assert CliRunner().invoke(app, ["init", "b", "--schema", "s/a.json"]).exit_code == 0
    assert (tmp_path / "b.yaml").read_text().startswith("# yaml-language-server: $schema=s/a.json")


@pytest.mark.parametrize("template", ["tank", "lti", "process", "diffdrive", "motor"])
def test_every_template_writes_a_valid_file_under_the_name(tmp_path: Path, monkeypatch,
                                                             template: str) -> None:
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    result = runner.invoke(app, ["init", "plant_x", "--template", template])
    assert result.exit_code == 0, result.stderr
    text = (tmp_path / "plant_x.yaml").read_text()
    assert text.splitlines()[0] == "# yaml-language-server: $schema=" + SCHEMA_ID
    from archself.model.loader import load_architecture

    assert load_architecture(tmp_path / "plant_x.yaml").arch.name == "plant_x"
    assert runner.invoke(app, ["validate", "--strict", "plant_x.yaml"]).exit_code == 0


def test_the_lti_template_is_generic_blocks_only_and_adapts(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    assert runner.invoke(app, ["init", "loop", "-t", "lti"]).exit_code == 0
    from archself.model.loader import load_architecture

    arch = load_architecture(tmp_path / "loop.yaml").arch
    assert all(m.type.startswith("generic.") for m in arch.modules.values())
    out = runner.invoke(app, ["simulate", "loop.yaml", "-s", "sensor_drift", "--compare", "--json"])
    assert out.exit_code == 0, out.stderr
    fixed, adaptive = json.loads(out.stdout)["runs"]
    assert [s["to"] for s in adaptive["switches"]] == ["on_b"]
    assert adaptive["metrics"]["final_error"] < 0.5 * fixed["metrics"]["final_error"]
    nominal = runner.invoke(app, ["simulate", "loop.yaml", "-s", "nominal", "--json"])
    assert json.loads(nominal.stdout)["runs"][0]["switches"] == []


def test_an_unknown_template_gets_did_you_mean_and_the_choices(tmp_path: Path,
                                                                monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["init", "x", "--template", "tnak"])
    assert result.exit_code == 2
    assert "did you mean 'tank'?" in result.stderr
    assert "tank, lti, process, diffdrive, motor, thermal" in result.stderr
    assert not (tmp_path / "x.yaml").exists()
    assert "[tank|lti|process|diffdrive|motor|thermal]" in CliRunner().invoke(
        app, ["init", "--help"]).stdout
