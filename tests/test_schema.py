"""The JSON Schema: generated from the model, current, and usable by other validators."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from archself.cli import app
from archself.model.schema import SCHEMA_DIALECT, schema_text

from conftest import FIXTURES, ROOT

SCHEMA = ROOT / "schemas" / "architecture.schema.json"
ARCHITECTURES = sorted((ROOT / "architectures").glob("*.yaml"))

# fixtures whose defect is structural (the schema alone must reject them)
STRUCTURAL = [
    "negative_weight",  # weight ≥ 0 in the schema too (issue 40)
    "bad_kind", "wrong_type", "unknown_field", "missing_key", "not_mapping",
    "bad_improvement_method", "control_char_name",
    "two_selectors", "action_without_target",  # oneOf and if/then from json_schema_extra
]


def test_checked_in_schema_is_current() -> None:
    assert SCHEMA.read_text(encoding="utf-8") == schema_text(installed=False), (
        "schemas/architecture.schema.json is stale: run `archself schema --builtin -o "
        "schemas/architecture.schema.json`"
    )


def test_schema_check_command(tmp_path: Path) -> None:
    runner = CliRunner()
    assert runner.invoke(app, ["schema", "--builtin", "--check", str(SCHEMA)]).exit_code == 0
    stale = tmp_path / "stale.json"
    stale.write_text("{}")
    result = runner.invoke(app, ["schema", "--check", str(stale)])
    assert result.exit_code == 1 and "stale" in result.stderr


def test_schema_carries_dialect_and_forbids_extras() -> None:
    schema = json.loads(SCHEMA.read_text())
    assert schema["$schema"] == SCHEMA_DIALECT
    assert schema["additionalProperties"] is False
    assert schema["$defs"]["Module"]["additionalProperties"] is False


@pytest.mark.parametrize("path", ARCHITECTURES, ids=[p.stem for p in ARCHITECTURES])
def test_architecture_files_carry_the_modeline(path: Path) -> None:
    first = path.read_text(encoding="utf-8").splitlines()[0]
    assert first == "# yaml-language-server: $schema=../schemas/architecture.schema.json"


def _check_jsonschema() -> list[str]:
    exe = shutil.which("check-jsonschema", path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip("check-jsonschema is not installed")
    return [exe, "--schemafile", str(SCHEMA)]


def test_independent_validator_accepts_the_architectures() -> None:
    proc = subprocess.run([*_check_jsonschema(), *map(str, ARCHITECTURES)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.parametrize("name", STRUCTURAL)
def test_independent_validator_rejects_structural_breakage(name: str) -> None:
    proc = subprocess.run([*_check_jsonschema(), str(FIXTURES / "invalid" / f"{name}.yaml")],
                          capture_output=True, text=True)
    assert proc.returncode == 1, proc.stdout + proc.stderr


def test_reference_pages_are_current() -> None:
    from archself.reports.docgen import reference_pages

    for name, text in reference_pages().items():
        current = (ROOT / "docs" / name).read_text(encoding="utf-8")
        assert current == text, f"docs/{name} is stale: run `archself docs`"
    fmt = (ROOT / "docs" / "format.md").read_text(encoding="utf-8")
    for name in ("Module", "Edge", "Configuration", "Action", "Scenario", "Runtime"):
        assert f"## {name}\n" in fmt
    cli = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    for command in ("validate", "simulate", "explain", "init", "docs"):
        assert f"## archself {command}\n" in cli


def test_docs_check_command(tmp_path: Path) -> None:
    runner = CliRunner()
    assert runner.invoke(app, ["docs", "--check", str(ROOT / "docs")]).exit_code == 0
    result = runner.invoke(app, ["docs", "--check", str(tmp_path)])
    assert result.exit_code == 1


def test_schema_states_the_cross_field_rules() -> None:
    defs = json.loads(SCHEMA.read_text())["$defs"]
    selectors = [b["required"] for b in defs["Runtime"]["oneOf"]]
    assert selectors == [["threshold"], ["top_k"], ["hysteresis"]]
    assert defs["Action"]["then"]["required"] == ["to"]
    assert defs["Action"]["else"]["required"] == ["set"]


def test_independent_validator_accepts_a_null_second_selector(tmp_path: Path) -> None:
    text = (FIXTURES / "valid" / "minimal.yaml").read_text(encoding="utf-8")
    path = tmp_path / "null_top_k.yaml"
    path.write_text(text.replace("  threshold: 0.5\n", "  threshold: 0.5\n  top_k: null\n"))
    proc = subprocess.run([*_check_jsonschema(), str(path)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_module_type_offers_the_registered_types() -> None:
    from archself.model.schema import architecture_schema
    from archself.registry import _points

    registered = set(_points())  # every installed entry point (nothing imported)

    builtin = json.loads(SCHEMA.read_text())["$defs"]["Module"]["properties"]["type"]
    assert {"sensor.imu", "generic.pid", "plant.tank"} <= set(builtin["examples"])
    assert not any(t.startswith("example.") for t in builtin["examples"])  # a plugin's
    installed = architecture_schema(installed=True)["$defs"]["Module"]["properties"]["type"]
    assert set(installed["examples"]) == registered >= set(builtin["examples"])
    schema = json.loads(SCHEMA.read_text())
    assert schema["$defs"]["Runtime"]["properties"]["threshold"]["examples"] == [0.55, 0.5]
    assert schema["$defs"]["Edge"]["properties"]["carries"]["examples"][0] == "pose"
    out = CliRunner().invoke(app, ["schema"]).stdout
    assert json.loads(out)["$defs"]["Module"]["properties"]["type"]["examples"] == sorted(
        registered)
