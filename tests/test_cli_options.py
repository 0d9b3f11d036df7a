"""The command line's shared options (issue 40): --quiet/--verbose, completion, did-you-mean."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from archself.cli import app
from archself.cli import base as cli_base

from conftest import ROOT

ZONE = str(ROOT / "architectures" / "thermal_zone.yaml")
COMMANDS = ["validate", "schema", "docs", "init", "simulate", "report", "explain", "live",
            "ros2", "campaign", "campaign-report", "export", "info", "calibrate", "identify",
            "generate"]


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_takes_quiet_and_verbose(command) -> None:
    res = CliRunner().invoke(app, [command, "-h"])
    assert res.exit_code == 0
    assert "-q, --quiet" in res.stdout and "-v, --verbose" in res.stdout


def test_quiet_leaves_out_notes_and_both_is_a_usage_error(tmp_path) -> None:
    out = tmp_path / "s.json"
    said = CliRunner().invoke(app, ["schema", "-o", str(out)])
    assert said.exit_code == 0 and f"wrote {out}" in said.stderr
    quiet = CliRunner().invoke(app, ["schema", "-o", str(out), "--quiet"])
    assert quiet.exit_code == 0 and quiet.stderr == "" and out.stat().st_size > 1000
    both = CliRunner().invoke(app, ["schema", "-q", "-v"])
    assert both.exit_code == 2 and "give --quiet or --verbose, not both" in both.stderr
    assert cli_base.LEVEL == [0]  # reset after every command


def test_quiet_keeps_errors(tmp_path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("archself: 1\nname: x\n", encoding="utf-8")
    res = CliRunner().invoke(app, ["validate", str(bad), "-q"])
    assert res.exit_code == 1 and ": error: " in res.stderr


@pytest.mark.parametrize(("level", "tty", "json_out", "shown"), [
    (0, True, False, True), (0, False, False, False), (1, False, False, True),
    (-1, True, False, False), (1, True, True, False),
])
def test_progress_is_shown_by_level(monkeypatch, level, tty, json_out, shown) -> None:
    monkeypatch.setattr(cli_base.sys.stderr, "isatty", lambda: tty, raising=False)
    monkeypatch.setattr(cli_base, "LEVEL", [level])
    assert cli_base.show_progress(json_out) is shown


def _complete(words: str) -> list[str]:
    env = {"_ARCHSELF_COMPLETE": "complete_bash", "COMP_WORDS": words,
           "COMP_CWORD": str(len(words.split()) - (0 if words.endswith(" ") else 1))}
    res = CliRunner().invoke(app, [], env=env, prog_name="archself")
    return res.stdout.split()


@pytest.mark.parametrize(("words", "offered"), [
    (f"archself simulate {ZONE} -s h", ["heater_loss"]),
    (f"archself simulate {ZONE} -s nominal -c ", ["z1", "z2", "z3", "z4"]),
    (f"archself campaign {ZONE} --scenario s", ["sensor_dropout"]),
    (f"archself calibrate {ZONE} --configuration z", ["z1", "z2", "z3", "z4"]),
    (f"archself export {ZONE} --to g", ["graphml"]),
    ("archself simulate no_such_file.yaml -s ", []),
])
def test_completion_reads_the_file_on_the_command_line(words, offered) -> None:
    assert _complete(words) == offered


@pytest.mark.parametrize(("args", "said", "code"), [
    (["simulate", ZONE, "-s", "nomnal"], "did you mean 'nominal'?", 1),
    (["simulate", ZONE, "-s", "nominal", "-c", "zz1"], "'zz1'; did you mean 'z1'? known: z1", 1),
    (["campaign", ZONE, "-s", "heater_los", "--seeds", "1"], "did you mean 'heater_loss'?", 1),
    (["export", ZONE, "--to", "grafml"], "unknown format 'grafml'; did you mean 'graphml'?", 2),
])
def test_a_typo_gets_did_you_mean(args, said, code) -> None:
    res = CliRunner().invoke(app, args)
    assert res.exit_code == code and said in res.stderr, res.stderr


def test_quiet_strict_still_says_the_warning_that_fails(tmp_path) -> None:
    text = (ROOT / "tests" / "fixtures" / "valid" / "minimal.yaml").read_text(encoding="utf-8")
    noisy = tmp_path / "w.yaml"
    unused = "  - {from: compass, to: control, weight: 0.1, carries: heading}\n"  # a warning
    noisy.write_text(text.replace("edges:\n", "edges:\n" + unused), encoding="utf-8")
    plain = CliRunner().invoke(app, ["validate", str(noisy)])
    assert plain.exit_code == 0 and ": warning: " in plain.stderr, plain.stderr
    quiet = CliRunner().invoke(app, ["validate", str(noisy), "-q"])
    assert quiet.exit_code == 0 and quiet.stderr == ""
    strict = CliRunner().invoke(app, ["validate", str(noisy), "-q", "--strict"])
    assert strict.exit_code == 1 and ": warning: " in strict.stderr


def test_run_campaign_draws_its_own_bar_with_progress_true(tmp_path, capsys) -> None:
    """The notebook's way: ``run_campaign(..., progress=True)`` (rich draws in the cell)."""
    from archself.campaign.driver import plan_campaign, run_campaign

    jobs, meta = plan_campaign(ROOT / "tests" / "fixtures" / "valid" / "minimal.yaml",
                               ["calm"], 2)
    outcome = run_campaign(jobs, meta, tmp_path / "r.parquet", executor="inline",
                           progress=True)
    assert outcome.ran == len(jobs) == 4 and outcome.failed == 0
    err = capsys.readouterr().err
    assert "4 runs" in err and "4/4" in err and "runs/s" in err
