"""The command line: exit codes, streams and a light start-up."""

from __future__ import annotations

import subprocess
import sys

import pytest
from typer.testing import CliRunner

from archself.cli import app

from conftest import DIFFDRIVE, ROOT

HEAVY = ("control", "filterpy", "matplotlib", "rclpy", "scipy.interpolate", "scipy.optimize",
         "scipy.signal")  # validate builds no module that needs them (check_params)


def test_help_lists_the_commands() -> None:
    result = CliRunner().invoke(app, ["--help"])
    assert result.exit_code == 0
    for cmd in ("validate", "schema"):
        assert cmd in result.stdout


def test_validate_diffdrive_is_clean() -> None:
    result = CliRunner().invoke(app, ["validate", str(DIFFDRIVE)])
    assert result.exit_code == 0, result.stderr
    assert result.stdout.strip().endswith("ok")


def test_validate_without_paths_is_a_usage_error() -> None:
    assert CliRunner().invoke(app, ["validate"]).exit_code == 2


def test_missing_path_is_a_one_line_error() -> None:
    result = CliRunner().invoke(app, ["validate", "does/not/exist.yaml"])
    assert result.exit_code == 1
    assert result.stderr == "does/not/exist.yaml: error: no such file\n"


def test_mixed_files_exit_1_and_report_each(monkeypatch) -> None:
    monkeypatch.chdir(ROOT)
    result = CliRunner().invoke(
        app, ["validate", "architectures/diffdrive.yaml", "tests/fixtures/invalid/empty.yaml"]
    )
    assert result.exit_code == 1
    assert "architectures/diffdrive.yaml: ok" in result.stdout
    first, second = result.stderr.splitlines()[:2]
    assert first.startswith("architectures/diffdrive.yaml:") and ": info: " in first  # not checked
    assert second.startswith("tests/fixtures/invalid/empty.yaml:1:1: error:")


@pytest.mark.parametrize("argv", [["--help"], ["validate", str(DIFFDRIVE)]])
def test_startup_does_not_import_heavy_libraries(argv: list[str]) -> None:
    code = (
        "import sys\n"
        "from archself.cli import app\n"
        "try:\n"
        f"    app({argv!r})\n"
        "except SystemExit as e:\n"
        "    assert e.code == 0, e.code\n"
        f"heavy = [m for m in {HEAVY!r} if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_installed_script_runs() -> None:
    from pathlib import Path

    script = Path(sys.executable).parent / "archself"
    proc = subprocess.run([str(script), "validate", str(DIFFDRIVE)], capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr


VALID = sorted((ROOT / "tests" / "fixtures" / "valid").glob("*.yaml")) + sorted(
    (ROOT / "architectures").glob("*.yaml")
)


@pytest.mark.parametrize("path", VALID, ids=[p.stem for p in VALID])
def test_valid_files_validate_clean(path) -> None:
    result = CliRunner().invoke(app, ["validate", "--strict", str(path)])
    assert result.exit_code == 0, result.stderr


@pytest.mark.slow
def test_generated_10000_module_file_validates(tmp_path) -> None:
    from archself.model.generate import generate_architecture

    big = tmp_path / "big.yaml"
    big.write_text(generate_architecture(10_000, seed=2, feedback=5))
    result = CliRunner().invoke(app, ["validate", "--json", str(big)])
    assert result.exit_code == 0, result.stdout[-2000:]


def test_ci_runs_the_readme_test_command() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    blocks = [b.split("```")[0].strip() for b in readme.split("```sh\n")[1:]]
    assert len(blocks) == 2, "the quick start is exactly two commands"
    install_and_run, install_and_test = blocks
    assert "archself simulate" in install_and_run and "pytest" in install_and_test
    assert install_and_test in ci
    assert install_and_run in ci


def test_negative_seed_is_a_usage_error() -> None:
    result = CliRunner().invoke(app, ["simulate", str(DIFFDRIVE), "--seed", "-3"])
    assert result.exit_code == 2
    assert "--seed" in result.stderr and "greater than or equal to 0" in result.stderr
    assert "Traceback" not in result.stderr


def test_docgen_does_not_import_the_command_line() -> None:
    """cli imports docgen (``archself docs``); docgen gets the app passed, never imports cli."""
    code = (
        "import sys\n"
        "from archself.reports.docgen import reference_pages\n"
        "assert set(reference_pages()) == {'format.md'}\n"
        "assert 'archself.cli' not in sys.modules, 'docgen imported archself.cli'\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_cli_reference_page_is_current() -> None:
    from archself.reports.docgen import reference_pages

    pages = reference_pages(app)
    assert (ROOT / "docs" / "cli.md").read_text(encoding="utf-8") == pages["cli.md"]
