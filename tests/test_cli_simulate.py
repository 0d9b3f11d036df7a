"""`archself simulate` and `archself explain` from the command line."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from archself.cli import app
from archself.io.jsondata import SimulateDoc

from conftest import FIXTURES

MINIMAL = FIXTURES / "valid" / "minimal.yaml"
METRICS = {"max_error", "final_error", "rms_error", "peak_time_s"}
METRE_ALIASES = {"max_error_m", "final_error_m", "rms_error_m"}  # deprecated, unit m only


def _json(args: list[str]) -> Any:
    """The runs of ``simulate --json``: always one object ``{runs: [...]}``."""
    result = CliRunner().invoke(app, ["simulate", *args, "--json"])
    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    SimulateDoc.model_validate(data, strict=True)  # the shape docs/json.md gives
    return data["runs"]


def test_fixed_json_shape() -> None:
    out = _json([str(MINIMAL), "--scenario", "calm", "--fixed", "--seed", "3"])[0]
    assert set(out["metrics"]) == METRICS and out["unit"] is None  # minimal.yaml: no unit
    assert out["mode"] == "fixed" and out["seed"] == 3 and out["switches"] == []
    assert out["final_configuration"] == "only"
    assert 0 <= out["metrics"]["rms_error"] <= out["metrics"]["max_error"]


def _with_unit(tmp_path: Path, unit: str) -> Path:
    text = MINIMAL.read_text(encoding="utf-8").replace(
        "components: [0, 1]}", f"components: [0, 1], unit: {unit}}}", 1
    )
    assert f"unit: {unit}" in text
    path = tmp_path / f"minimal_{unit}.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def test_metric_names_and_units_come_from_the_objective(tmp_path: Path) -> None:
    plain = _json([str(MINIMAL), "--scenario", "calm", "--fixed", "--seed", "3"])[0]
    metres = _json([str(_with_unit(tmp_path, "m")), "-s", "calm", "--fixed", "--seed", "3"])[0]
    kelvin = _json([str(_with_unit(tmp_path, "K")), "-s", "calm", "--fixed", "--seed", "3"])[0]
    assert metres["unit"] == "m" and kelvin["unit"] == "K"
    assert set(kelvin["metrics"]) == METRICS
    # unit m: the pre-unit names stay for one release, with the same values
    assert set(metres["metrics"]) == METRICS | METRE_ALIASES
    for alias in METRE_ALIASES:
        assert metres["metrics"][alias] == metres["metrics"][alias.removesuffix("_m")]
    assert {k: metres["metrics"][k] for k in METRICS} == plain["metrics"] == kelvin["metrics"]
    result = CliRunner().invoke(app, ["simulate", str(_with_unit(tmp_path, "K")), "-s", "calm"])
    assert result.exit_code == 0, result.stderr
    assert "max error [K]" in result.stdout and "RMS error [K]" in result.stdout


def test_same_seed_same_result_different_seed_differs() -> None:
    a = _json([str(MINIMAL), "--scenario", "calm", "--fixed", "--seed", "5"])[0]
    b = _json([str(MINIMAL), "--scenario", "calm", "--fixed", "--seed", "5"])[0]
    c = _json([str(MINIMAL), "--scenario", "calm", "--fixed", "--seed", "6"])[0]
    assert a == b
    assert a["metrics"] != c["metrics"]


def test_compare_prints_both_modes() -> None:
    out = _json([str(MINIMAL), "--scenario", "calm", "--compare"])
    assert [o["mode"] for o in out] == ["fixed", "adaptive"]


def test_readable_summary() -> None:
    result = CliRunner().invoke(app, ["simulate", str(MINIMAL), "-s", "calm", "--compare"])
    assert result.exit_code == 0, result.stderr
    assert "switches (adaptive): none" in result.stdout
    assert "max error   " in result.stdout and "[m]" not in result.stdout  # no unit declared


def test_trace_and_explain(tmp_path: Path) -> None:
    trace = tmp_path / "run.json"
    result = CliRunner().invoke(
        app, ["simulate", str(MINIMAL), "-s", "calm", "--compare", "--trace", str(trace)]
    )
    assert result.exit_code == 0, result.stderr
    doc = json.loads(trace.read_text())
    assert {"meta", "series", "decisions"} <= set(doc)
    assert len(doc["series"]["t"]) == len(doc["series"]["J"]) > 0
    assert doc["decisions"], "the adaptive run logs every MAPE-K cycle"
    assert (tmp_path / "run.fixed.json").exists()
    out = CliRunner().invoke(app, ["explain", str(trace)])
    assert out.exit_code == 0, out.stderr
    assert "MAPE-K decision log" in out.stdout


def test_explain_json_holds_what_the_text_shows(tmp_path: Path) -> None:
    from archself.runtime.explanation import explain

    trace = tmp_path / "run.json"
    CliRunner().invoke(app, ["simulate", str(MINIMAL), "-s", "calm", "--trace", str(trace)])
    decisions = json.loads(trace.read_text())["decisions"]
    out = CliRunner().invoke(app, ["explain", str(trace), "--json"])
    assert out.exit_code == 0, out.stderr
    doc = json.loads(out.stdout)
    assert set(doc) == {"run", "cycles", "switches", "updates", "segments"}
    assert doc["cycles"] == len(decisions)
    # every cycle is in exactly one segment, in order
    counted = [1 if s["kind"] == "cycle" else s["cycles"] for s in doc["segments"]]
    assert sum(counted) == len(decisions)
    full = [s["record"]["cycle"] for s in doc["segments"] if s["kind"] == "cycle"]
    assert full == sorted(full) and full[0] == decisions[0]["cycle"]
    # the text shows one block per notable cycle and one line per repeat
    text = explain(decisions)
    repeats = [s for s in doc["segments"] if s["kind"] == "repeat"]
    assert text.count("more cycle(s)") == len(repeats)
    assert len(doc["switches"]) == text.count("  switch at t =")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["-s", "storm"], "unknown scenario 'storm'"),
        (["-s", "calm", "--config", "nope"], "unknown configuration 'nope'"),
        (["-s", "calm", "--trace", "/nonexistent/dir/t.json"], "does not exist"),
    ],
)
def test_user_errors_are_one_line(args: list[str], message: str) -> None:
    result = CliRunner().invoke(app, ["simulate", str(MINIMAL), *args])
    assert result.exit_code == 1
    assert message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert "Traceback" not in result.stderr


def test_invalid_file_is_refused_before_running() -> None:
    result = CliRunner().invoke(
        app, ["simulate", str(FIXTURES / "invalid" / "self_loop.yaml"), "-s", "calm"]
    )
    assert result.exit_code == 1
    assert "edge from 'control' to itself" in result.stderr


def test_explain_rejects_a_non_trace(tmp_path: Path) -> None:
    bad = tmp_path / "x.json"
    bad.write_text("[1, 2]")
    result = CliRunner().invoke(app, ["explain", str(bad)])
    assert result.exit_code == 1 and "not an archself trace" in result.stderr


def test_plugin_type_runs_in_a_simulation(tmp_path: Path) -> None:
    """A module type from the in-repo plugin package (entry point) runs like a built-in."""
    from archself import registry

    assert "example.magnetometer" in registry.known_types(), (
        "install the example plugin: pip install ./plugins/archself-example"
    )
    text = MINIMAL.read_text().replace("type: sensor.imu", "type: example.magnetometer")
    arch = tmp_path / "magnetometer.yaml"
    arch.write_text(text)
    assert CliRunner().invoke(app, ["validate", str(arch)]).exit_code == 0
    out = _json([str(arch), "--scenario", "calm", "--fixed"])[0]
    assert out["metrics"]["max_error"] < 0.5


@pytest.mark.parametrize("command", [["simulate", "-s", "calm"], ["report", "-o", "out"]])
def test_missing_architecture_is_one_located_error(command: list[str], tmp_path: Path) -> None:
    missing = str(tmp_path / "nope.yaml")
    result = CliRunner().invoke(app, [command[0], missing, *command[1:]])
    assert result.exit_code == 1
    assert result.stderr == f"{missing}: error: no such file\n"


def test_progress_bar_starts_with_the_first_step(monkeypatch) -> None:
    """The bar is created after the build, so its time estimate is the simulation's."""
    import contextlib

    import typer

    import archself.cli.runs as cli
    import archself.sim.run as run
    from archself.model.loader import load_architecture

    events: list[str] = []
    real_compile = run.compile_system

    def compile_system(*args, **kwargs):
        events.append("build")
        return real_compile(*args, **kwargs)

    @contextlib.contextmanager
    def progressbar(**kwargs):
        events.append("bar")

        class Bar:
            def update(self, n: int) -> None:
                events.append(f"+{n}")

        yield Bar()

    monkeypatch.setattr(run, "compile_system", compile_system)
    monkeypatch.setattr(typer, "progressbar", progressbar)
    arch = load_architecture(MINIMAL).arch
    cli._run(arch, "calm", None, 1, False, True)
    assert events[:2] == ["build", "bar"]
    assert sum(int(e[1:]) for e in events if e.startswith("+")) == 100


@pytest.mark.parametrize("name", ["", "."])
def test_trace_without_a_file_name_is_a_one_line_error(name: str) -> None:
    """--trace '' (Path('.'), no name for the '.fixed' twin) was an internal error."""
    out = CliRunner().invoke(app, ["simulate", str(MINIMAL), "-s", "calm", "--compare",
                                   "--trace", name])
    assert out.exit_code == 1, (out.stderr, out.exception)
    assert out.stderr == ".: cannot write: is a folder; --trace takes a file name\n"
