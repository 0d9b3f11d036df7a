"""``archself validate`` verifies closed-loop stability when the file opts in."""

from __future__ import annotations

import subprocess
import sys

import pytest
from typer.testing import CliRunner

from archself.check import check
from archself.cli import app
from archself.model.loader import load_architecture, load_text

from conftest import FIXTURES, ROOT

SWAP = FIXTURES / "valid" / "actuator_swap.yaml"
UNSTABLE = FIXTURES / "invalid" / "unstable_configuration.yaml"


def _with_verify(mode: str) -> str:
    text = SWAP.read_text(encoding="utf-8")
    old = "horizon_steps: 20}"
    assert text.count(old) == 1
    return text.replace(old, f"horizon_steps: 20, verify: {mode}}}")


def _findings(text: str):
    return [f for f in check(load_text(text, "swap.yaml")) if f.code == "stability"]


def test_off_by_default_nothing_is_judged_and_that_is_said() -> None:
    assert load_architecture(SWAP).arch.runtime.stability.verify == "off"
    found = _findings(SWAP.read_text(encoding="utf-8"))
    assert [(f.severity, f.path) for f in found] == [("info", "runtime.stability.verify")]
    assert found[0].message.startswith("whole-loop stability not checked")


def test_warning_mode_reports_the_unstable_configuration_and_action_as_warnings() -> None:
    found = _findings(_with_verify("warning"))
    assert [(f.severity, f.path) for f in found] == [
        ("warning", "configurations.hot"),
        ("warning", "actions[0].to"),
    ]
    conf = found[0]
    text = _with_verify("warning").splitlines()[conf.line - 1]
    assert text[conf.col - 1 :].startswith("hot:")
    assert "max Re λ(A) = 14.8 1/s > −ε" in conf.message
    assert "|λ| = 4.395 per 0.1 s step" in conf.message
    assert "backup_hot" in conf.message and "plant" in conf.message


def test_error_mode_fails_validate_warning_mode_passes_unless_strict(tmp_path) -> None:
    runner = CliRunner()
    path = tmp_path / "swap.yaml"
    path.write_text(_with_verify("warning"), encoding="utf-8")
    assert runner.invoke(app, ["validate", str(path)]).exit_code == 0
    assert runner.invoke(app, ["validate", "--strict", str(path)]).exit_code == 1
    path.write_text(_with_verify("error"), encoding="utf-8")
    result = runner.invoke(app, ["validate", str(path)])
    assert result.exit_code == 1
    assert ": error: configurations.hot: configuration 'hot' is not stable" in result.stderr


def test_check_with_stability_judges_a_file_that_leaves_verify_off() -> None:
    text = SWAP.read_text(encoding="utf-8")
    found = [f for f in check(load_text(text, "swap.yaml"), "warning") if f.code == "stability"]
    assert [(f.severity, f.path) for f in found][:2] == [
        ("warning", "configurations.hot"), ("warning", "actions[0].to")]
    found = [f for f in check(load_text(_with_verify("error"), "swap.yaml"), "warning")
             if f.code == "stability"]
    assert {f.severity for f in found} == {"error"}  # the file's own setting wins


def test_a_stable_file_with_the_check_on_is_clean() -> None:
    text = _with_verify("error").replace("scale: {value: 40.0", "scale: {value: 1.5")
    assert _findings(text) == []


def test_a_parameter_update_is_judged_in_the_configurations_it_applies_in() -> None:
    found = [f for f in check(load_architecture(UNSTABLE)) if f.code == "stability"]
    update = [f for f in found if f.path == "actions[2].set"]
    assert len(update) == 1
    assert "action 'boost_main' makes configuration 'normal' unstable" in update[0].message


def test_files_with_errors_are_not_compiled() -> None:
    text = _with_verify("error").replace("modules: [plant, backup_hot,", "modules: [plant, nope,")
    found = check(load_text(text, "swap.yaml"))
    assert any(f.code == "reference" for f in found)
    assert not any(f.code == "stability" for f in found)


@pytest.mark.parametrize("path", [SWAP, ROOT / "architectures" / "motor_drive.yaml"])
def test_validate_without_the_opt_in_imports_no_heavy_library(path) -> None:
    code = (
        "import sys; from archself.cli import main; sys.argv = ['archself', 'validate', "
        f"{str(path)!r}]\n"
        "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
        "heavy = [m for m in ('control', 'filterpy', 'matplotlib') if m in sys.modules]\n"
        "assert not heavy, heavy"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
