"""Conventions a shell user expects: --version, -h, python -m archself."""

from __future__ import annotations

import subprocess
import sys

from typer.testing import CliRunner

from archself import __version__
from archself.cli import app


def test_version_flag() -> None:
    for flag in ("--version", "-V"):
        res = CliRunner().invoke(app, [flag])
        assert res.exit_code == 0 and res.stdout == f"archself {__version__}\n"


def test_short_help_on_the_group_and_on_commands() -> None:
    res = CliRunner().invoke(app, ["-h"])
    assert res.exit_code == 0 and "Commands:" in res.stdout
    res = CliRunner().invoke(app, ["validate", "-h"])
    assert res.exit_code == 0 and res.stdout.startswith("Usage: ")


def test_python_dash_m_runs_the_same_command_line() -> None:
    proc = subprocess.run([sys.executable, "-m", "archself", "--version"], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout.strip() == f"archself {__version__}"
