"""CLI conventions (issue 15 item 4): stdin/stdout as '-', one JSON shape, choices, colour."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from archself.campaign.driver import RunProgress
from archself.cli import app
from archself.cli.base import colorize
from archself.io.jsondata import ValidateList

from conftest import DIFFDRIVE, FIXTURES

MINIMAL = FIXTURES / "valid" / "minimal.yaml"
BAD = FIXTURES / "invalid" / "bad_kind.yaml"


def test_validate_dash_reads_stdin() -> None:
    ok = CliRunner().invoke(app, ["validate", "-"], input=MINIMAL.read_text())
    assert ok.exit_code == 0 and ok.stdout == "<stdin>: ok\n"
    bad = CliRunner().invoke(app, ["validate", "-", str(MINIMAL)], input=BAD.read_text())
    assert bad.exit_code == 1
    assert bad.stderr.startswith("<stdin>:5:11: error: modules.level_sensor.kind")
    assert f"{MINIMAL}: ok" in bad.stdout
    twice = CliRunner().invoke(app, ["validate", "-", "-"], input="")
    assert twice.exit_code == 2 and "once" in twice.stderr
    binary = CliRunner().invoke(app, ["validate", "-"], input=b"\xff\xfe\x00")
    assert binary.exit_code == 1 and "not UTF-8" in binary.stderr


@pytest.mark.parametrize("files", [[MINIMAL], [MINIMAL, BAD]])
def test_validate_json_is_always_a_list(files) -> None:
    res = CliRunner().invoke(app, ["validate", "--json", *map(str, files)])
    data = json.loads(res.stdout)
    assert isinstance(data, list) and len(data) == len(files)
    ValidateList.model_validate(data, strict=True)  # the shape docs/json.md gives
    assert [d["file"] for d in data] == [str(f) for f in files]


def test_json_option_says_its_shape() -> None:
    """Every command's --json help names the one shape it prints."""
    shapes = {"validate": "JSON list", "simulate": "one JSON object", "explain": "{run, cycles",
              "campaign": "one JSON object", "campaign-report": "one JSON object",
              "calibrate": "one JSON object", "identify": "one JSON object",
              "info": "one JSON object"}
    for command, shape in shapes.items():
        res = CliRunner().invoke(app, [command, "-h"], terminal_width=200)
        text = " ".join(res.stdout.split())
        assert res.exit_code == 0 and "--json" in text, command
        assert shape in text, command


def test_enumerations_are_choices() -> None:
    res = CliRunner().invoke(app, ["campaign", "-h"], terminal_width=200)
    assert "<both|fixed|adaptive>" in res.stdout and "<local|dask>" in res.stdout
    assert "<local|dask|inline>" in CliRunner().invoke(app, ["identify", "-h"],
                                                       terminal_width=200).stdout
    bad = CliRunner().invoke(app, ["campaign", str(MINIMAL), "-s", "calm", "--seeds", "1",
                                   "--mode", "both-ish", "-o", "x.parquet"])
    assert bad.exit_code == 2 and "'both-ish' is not one of 'both', 'fixed', 'adaptive'" in (
        bad.stderr)
    bad = CliRunner().invoke(app, ["calibrate", str(MINIMAL), "--executor", "ray"])
    assert bad.exit_code == 2 and "'ray' is not one of 'local', 'dask'" in bad.stderr


@pytest.mark.parametrize(("sweep", "hint"), [
    ("runtime.treshold=0.4,0.5", "sweep PATH runtime.treshold: no such key; did you mean "
                                 "'threshold'?"),
    ("runtime.stability.marginn=0.01", "sweep PATH runtime.stability.marginn: no such key; "
                                       "did you mean 'margin'?"),
])
def test_a_sweep_path_typo_is_one_line_with_a_suggestion(tmp_path, sweep, hint) -> None:
    res = CliRunner().invoke(app, ["campaign", str(DIFFDRIVE), "-s", "nominal", "--seeds", "1",
                                   "--sweep", sweep, "-o", str(tmp_path / "c.parquet")])
    assert res.exit_code == 1
    assert res.stderr.strip().splitlines() == [f"{DIFFDRIVE}: {hint}"]
    assert "Extra inputs" not in res.stderr and not (tmp_path / "c.parquet").exists()


def test_colour_only_on_a_terminal_and_never_with_no_color(monkeypatch) -> None:
    line = "a.yaml:1:2: error: something"

    class Tty:
        def isatty(self) -> bool:
            return True

    monkeypatch.delenv("NO_COLOR", raising=False)
    monkeypatch.delenv("FORCE_COLOR", raising=False)
    assert colorize(line, Tty()) != line and "\x1b[" in colorize(line, Tty())
    assert colorize(line, Tty()).endswith(": something")
    assert colorize(line, object()) == line  # not a terminal
    monkeypatch.setenv("NO_COLOR", "1")
    assert colorize(line, Tty()) == line
    monkeypatch.setenv("FORCE_COLOR", "1")
    assert colorize(line, Tty()) == line  # NO_COLOR wins
    monkeypatch.delenv("NO_COLOR")
    assert "\x1b[" in colorize("error: x", object())  # FORCE_COLOR off a terminal
    # through the CLI (not a terminal): plain text
    monkeypatch.delenv("FORCE_COLOR")
    res = CliRunner().invoke(app, ["validate", str(BAD)])
    assert "\x1b[" not in res.stderr and ": error: " in res.stderr


def test_completion_is_offered() -> None:
    res = CliRunner().invoke(app, ["-h"])
    assert "--install-completion" in res.stdout and "--show-completion" in res.stdout


def test_run_progress_counts_and_restarts(capsys) -> None:
    bar = RunProgress("{total} runs")
    bar.update(0, 4)
    bar.update(3, 4)
    assert bar.done == 3 and bar.rate().endswith("runs/s")
    bar.update(1, 2)  # a new phase: a new bar
    assert bar.done == 1 and bar.total == 2
    bar.close()
    assert bar.bar is None
    assert "4 runs" in capsys.readouterr().err


def test_run_progress_rate_is_the_throughput_since_the_start() -> None:
    """Issue 40: two runs finishing 0.3 ms apart after 30 s showed "6660.87 runs/s" at 2/4."""
    import io

    clock = iter([0.0, 0.0, 30.0, 30.0003, 60.0]).__next__
    bar = RunProgress("{total} runs", file=io.StringIO(), clock=clock)
    bar.update(0, 4)
    assert bar.rate() == ""  # nothing done yet
    bar.update(1, 4)
    bar.update(2, 4)
    assert bar.rate() == f"{2 / 30.0003:.2f} runs/s" == "0.07 runs/s"
    bar.update(4, 4)
    assert bar.rate() == "0.07 runs/s"  # 4 runs in 60 s
    bar.close()
    assert "4/4" in bar.file.getvalue()


def test_dash_is_stdin_for_architectures_and_traces(tmp_path) -> None:
    text = MINIMAL.read_text()
    run = CliRunner().invoke(app, ["simulate", "-", "-s", "calm", "--trace", "-"], input=text)
    assert run.exit_code == 0, run.stderr
    said = CliRunner().invoke(app, ["explain", "-"], input=run.stdout)
    assert said.exit_code == 0 and said.stdout.startswith("minimal cart · scenario calm")
    info = CliRunner().invoke(app, ["info", "-", "--json"], input=text)
    assert info.exit_code == 0 and json.loads(info.stdout)
    import archself

    archself.simulate(MINIMAL, "calm").write_trace(tmp_path / "t.parquet")
    said = CliRunner().invoke(app, ["explain", "-"], input=(tmp_path / "t.parquet").read_bytes())
    assert said.exit_code == 0 and "· fixed ·" in said.stdout
    bad = CliRunner().invoke(app, ["info", "-"], input="x: 1\n")
    assert bad.exit_code == 1 and bad.stderr.startswith("<stdin>:")
    junk = CliRunner().invoke(app, ["explain", "-"], input="[1, 2]")
    assert junk.exit_code == 1 and "<stdin>: error: not an archself trace" in junk.stderr
