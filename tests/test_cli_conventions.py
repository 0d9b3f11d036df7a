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


def test_the_script_imports_only_the_command_it_runs() -> None:
    code = ("import sys; sys.argv = ['archself', 'schema', '--help']\n"
            "from archself.cli import main\n"
            "try:\n    main()\nexcept SystemExit as exc:\n    assert exc.code == 0, exc.code\n"
            "print(sorted(m for m in sys.modules if m.startswith('archself.cli.')))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split("\n")[-2] == "['archself.cli.base', 'archself.cli.files']"
    assert "Usage: archself schema" in proc.stdout


def test_running_one_command_keeps_every_command_on_the_app(monkeypatch) -> None:
    from archself.cli import main
    from archself.cli.base import COMMANDS

    monkeypatch.setattr(sys, "argv", ["archself", "schema", "--help"])
    try:
        main()
    except SystemExit as exc:
        assert exc.code == 0
    assert [c.name for c in app.registered_commands] == list(COMMANDS)
    res = CliRunner().invoke(app, ["-h"])
    assert res.exit_code == 0 and "campaign-report" in res.stdout


def test_root_help_before_a_command_lists_every_command(monkeypatch, capsys) -> None:
    from archself.cli import main

    monkeypatch.setattr(sys, "argv", ["archself", "--help", "schema"])
    try:
        main()
    except SystemExit as exc:
        assert exc.code == 0
    out = capsys.readouterr().out
    assert "campaign-report" in out and "simulate" in out and "Commands:" in out
