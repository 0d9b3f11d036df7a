"""Traces (issue 15 item 2): Parquet beside JSON, read back, run reports rebuilt from them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import archself
from archself.cli import app
from archself.io.trace import TraceError
from archself.sim.result import read_trace

from conftest import DIFFDRIVE, FIXTURES

pd = pytest.importorskip("pandas")

MINIMAL = FIXTURES / "valid" / "minimal.yaml"


@pytest.fixture(scope="module")
def switching_run() -> tuple[object, object]:
    """A short diffdrive run with one switch (a1 → a3), and its architecture."""
    arch = archself.load(DIFFDRIVE)
    arch.scenarios["actuator_fault"].duration_s = 40
    res = archself.simulate(arch, "actuator_fault", adapt=archself.MapeK(arch))
    assert [(s["from"], s["to"]) for s in res.switches] == [("a1", "a3")]
    return arch, res


def test_parquet_trace_is_the_frame_of_to_pandas(switching_run, tmp_path: Path) -> None:
    _, res = switching_run
    path = tmp_path / "run.parquet"
    res.write_trace(path)
    assert path.read_bytes()[:4] == b"PAR1"
    df = pd.read_parquet(path)
    ref = res.to_pandas()
    assert list(df.columns) == list(ref.columns)
    assert len(df) == len(ref)
    assert str(df["configuration"].dtype) == "category"
    assert df["configuration"].tolist() == ref["configuration"].tolist()
    assert set(df["configuration"]) == {"a1", "a3"}
    assert df["t"].dtype == np.float64 and np.array_equal(df["t"], ref["t"])
    # float32: 7 significant digits
    np.testing.assert_allclose(df["J"], ref["J"], rtol=1e-6, atol=1e-7)


def test_traces_read_back_the_same_run(switching_run, tmp_path: Path) -> None:
    _, res = switching_run
    for name in ("run.parquet", "run.json"):
        res.write_trace(tmp_path / name)
        back = read_trace(tmp_path / name)
        assert (back.scenario, back.seed, back.mode) == (res.scenario, res.seed, res.mode)
        assert back.final_configuration == "a3" and back.switches == res.switches
        assert back.metrics == res.metrics and back.configurations == res.configurations
        assert back.trace_decisions() == json.loads(json.dumps(res.trace_decisions()))
        assert set(back.series) == set(res.series)
        for key, arr in res.series.items():
            assert back.series[key].shape == np.shape(arr), key
            np.testing.assert_allclose(back.series[key], arr, rtol=1e-6, atol=1e-5,
                                       err_msg=key)
        assert back.decisions_frame().shape == res.decisions_frame().shape


def test_parquet_trace_is_deterministic_and_five_times_smaller(tmp_path: Path) -> None:
    arch = archself.load(MINIMAL)
    arch.scenarios["calm"].duration_s = 400  # the 400 s run
    res = archself.simulate(arch, "calm", adapt=archself.MapeK(arch))
    res.write_trace(tmp_path / "a.parquet")
    res.write_trace(tmp_path / "b.parquet")
    res.write_trace(tmp_path / "a.json")
    pq_bytes = (tmp_path / "a.parquet").read_bytes()
    assert pq_bytes == (tmp_path / "b.parquet").read_bytes()
    assert len((tmp_path / "a.json").read_bytes()) >= 5 * len(pq_bytes)


def test_polars_reads_the_parquet_trace(switching_run, tmp_path: Path) -> None:
    pl = pytest.importorskip("polars")
    _, res = switching_run
    res.write_trace(tmp_path / "run.parquet")
    df = pl.read_parquet(tmp_path / "run.parquet")
    assert df.columns == list(res.to_pandas().columns)


def test_report_from_a_trace_equals_the_report_of_the_run(switching_run, tmp_path: Path):
    from archself.reports.run import build_run_report

    arch, res = switching_run
    res.write_trace(tmp_path / "run.parquet")
    res.write_trace(tmp_path / "run.json")
    expected = build_run_report(arch, [res]).summary()
    for name in ("run.parquet", "run.json"):
        assert build_run_report(None, [read_trace(tmp_path / name)]).summary() == expected


def test_cli_report_from_traces(tmp_path: Path) -> None:
    trace = tmp_path / "run.parquet"
    ran = CliRunner().invoke(app, ["simulate", str(MINIMAL), "-s", "calm", "--compare",
                                   "--trace", str(trace), "--report", str(tmp_path / "a")])
    assert ran.exit_code == 0, ran.stderr
    fixed = tmp_path / "run.fixed.parquet"
    assert fixed.is_file()
    out = CliRunner().invoke(app, ["report", "--trace", str(trace), "--trace", str(fixed),
                                   "-o", str(tmp_path / "b"), "--format", "svg",
                                   "--format", "pdf"])
    assert out.exit_code == 0, out.stderr
    assert out.stdout.strip() == str(tmp_path / "b" / "index.html")
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert summary == json.loads((tmp_path / "a" / "summary.json").read_text())
    assert [r["mode"] for r in summary["runs"]] == ["fixed", "adaptive"]
    assert (tmp_path / "b" / "error.pdf").read_bytes()[:5] == b"%PDF-"
    assert b"<svg" in (tmp_path / "b" / "error.svg").read_bytes()[:500]
    assert not (tmp_path / "b" / "error.png").exists()  # the HTML shows the SVG
    assert 'src="error.svg"' in (tmp_path / "b" / "index.html").read_text()
    # explain reads the Parquet trace
    said = CliRunner().invoke(app, ["explain", str(trace)])
    assert said.exit_code == 0 and "minimal cart · scenario calm" in said.stdout


def test_cli_report_trace_errors(tmp_path: Path) -> None:
    old = tmp_path / "old.json"
    res = archself.simulate(MINIMAL, "calm")
    doc = res.trace()
    del doc["meta"]["report"]  # a trace of an older archself
    old.write_text(json.dumps(doc))
    out = CliRunner().invoke(app, ["report", "--trace", str(old), "-o", str(tmp_path / "r")])
    assert out.exit_code == 1 and "pass the architecture file" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    with_arch = CliRunner().invoke(
        app, ["report", str(MINIMAL), "--trace", str(old), "-o", str(tmp_path / "r")])
    assert with_arch.exit_code == 0, with_arch.stderr
    assert (tmp_path / "r" / "trajectory.png").is_file()
    bogus = tmp_path / "x.parquet"
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({"a": [1, 2]}), bogus)
    out = CliRunner().invoke(app, ["report", "--trace", str(bogus), "-o", str(tmp_path / "s")])
    assert out.exit_code == 1 and "not an archself trace" in out.stderr
    with pytest.raises(TraceError, match="not an archself trace"):
        read_trace(MINIMAL)
    same = CliRunner().invoke(app, ["report", "--trace", str(old), "--trace", str(old),
                                    "-o", str(tmp_path / "t"), str(MINIMAL)])
    assert same.exit_code == 1 and "a fixed and an adaptive run" in same.stderr
    none = CliRunner().invoke(app, ["report", "-o", str(tmp_path / "u")])
    assert none.exit_code == 2 and "missing argument ARCH" in none.stderr


def test_trace_dash_writes_json_to_stdout(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    out = CliRunner().invoke(app, ["simulate", str(MINIMAL), "-s", "calm", "--trace", "-"])
    assert out.exit_code == 0, out.stderr
    doc = json.loads(out.stdout)
    assert set(doc) == {"meta", "series", "decisions"} and doc["meta"]["mode"] == "adaptive"
    assert "max error" in out.stderr  # the summary moves to stderr
    assert not (tmp_path / "-").exists()
    for extra in (["--compare"], ["--json"]):
        bad = CliRunner().invoke(app, ["simulate", str(MINIMAL), "-s", "calm", "--trace", "-",
                                       *extra])
        assert bad.exit_code == 2 and "stdout" in bad.stderr


def test_campaign_writes_parquet_traces(tmp_path: Path) -> None:
    out = CliRunner().invoke(app, ["campaign", str(MINIMAL), "-s", "calm", "--seeds", "1",
                                   "--mode", "adaptive", "--workers", "1", "-o",
                                   str(tmp_path / "c.parquet"), "--traces", str(tmp_path / "t"),
                                   "--trace-format", "parquet"])
    assert out.exit_code == 0, out.stderr
    (trace,) = (tmp_path / "t").iterdir()
    assert trace.suffix == ".parquet" and read_trace(trace).mode == "adaptive"
    table = pd.read_parquet(tmp_path / "c.parquet")
    assert table["trace"].tolist() == [str(trace)]


def test_cli_report_names_the_old_trace_whatever_the_order(tmp_path: Path) -> None:
    """Adaptive first, an old fixed trace second: the message names the old file."""
    new = tmp_path / "new.json"
    ran = CliRunner().invoke(app, ["simulate", str(MINIMAL), "-s", "calm", "--compare",
                                   "--trace", str(new)])
    assert ran.exit_code == 0, ran.stderr
    old = tmp_path / "old.json"
    doc = json.loads((tmp_path / "new.fixed.json").read_text())
    del doc["meta"]["report"]
    old.write_text(json.dumps(doc))
    out = CliRunner().invoke(app, ["report", "--trace", str(new), "--trace", str(old),
                                   "-o", str(tmp_path / "r")])
    assert out.exit_code == 1
    assert out.stderr.startswith(f"{old}: error: the trace does not hold"), out.stderr


@pytest.mark.parametrize(("where", "value", "message"), [
    (("decisions",), {"a": 1}, "decisions: expected a list of decision records"),
    (("decisions", 0), 5, "decisions[0]: expected a decision record"),
    (("decisions", 0, "candidates"), 5, "decisions[0].candidates: expected a list"),
    (("decisions", 0, "chosen"), "x", "decisions[0].chosen: expected an object"),
    (("decisions", 0, "z"), [1], "decisions[0].z: expected an object of modules"),
    (("decisions", 0, "z", "imu"), "x", "decisions[0].z.imu: expected a number"),
    (("decisions", 0, "evaluations"), [5], "decisions[0].evaluations[0]: expected an object"),
    (("meta", "report"), {}, "meta.report: expected a threshold"),
    (("meta", "report", "faults"), 5, "meta.report.faults: expected a list"),
    (("meta", "objective", "components"), "ab", "meta.objective.components"),
    (("meta", "switches"), [{}], "meta.switches[0].t_s: expected a number"),
    (("meta", "seed"), "x", "meta.seed: expected an integer, got a string"),
    (("series", "J"), [0.0] * 3, "series.J: 3 rows, but series.t has"),
    (("series", "J"), 5, "series.J: expected a list"),
    (("series", "configuration"), None, "series.configuration: expected a list"),
])
def test_edited_traces_are_one_line_errors(switching_run, tmp_path: Path, where, value,
                                           message) -> None:
    """A trace edited by hand: a located one-line error from explain and report --trace."""
    _, res = switching_run
    doc = json.loads(json.dumps(res.trace()))  # a copy: the run's meta is shared
    parent = doc
    for key in where[:-1]:
        parent = parent[key]
    parent[where[-1]] = value
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(doc))
    for args in (["explain", str(path)], ["explain", "--json", str(path)],
                 ["report", "--trace", str(path), "-o", str(tmp_path / "r")]):
        out = CliRunner().invoke(app, args)
        assert out.exit_code == 1, (args, out.stderr, out.exception)
        assert out.stderr.startswith(f"{path}: error: not an archself trace: ")
        assert message in out.stderr and len(out.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize(("key", "value", "message"), [
    ("series", [["t", "wide"]], "series[0][1]: expected an integer, got a string"),
    ("meta", None, "meta: expected an object, got null"),
    ("format", 9, "trace format 9 is newer than this archself reads (1)"),
])
def test_a_damaged_parquet_head_is_a_located_error(switching_run, tmp_path: Path, key, value,
                                                   message) -> None:
    """The ``archself.trace`` metadata of a Parquet trace is read with its model."""
    import pyarrow.parquet as pq

    from archself.io.trace import TRACE_KEY, trace_parts_from_bytes

    _, res = switching_run
    good = tmp_path / "good.parquet"
    res.write_trace(good)
    pf = pq.ParquetFile(good)
    md = dict(pf.metadata.metadata)
    head = {**json.loads(md[TRACE_KEY]), key: value}
    bad = tmp_path / "bad.parquet"
    with pq.ParquetWriter(bad, pf.schema_arrow) as writer:
        writer.write_table(pf.read())
        writer.add_key_value_metadata({**md, TRACE_KEY: json.dumps(head).encode()})
    assert len(trace_parts_from_bytes(good.read_bytes()).decisions) == len(res.decisions)
    with pytest.raises(TraceError) as err:
        trace_parts_from_bytes(bad.read_bytes(), "bad.parquet")
    assert str(err.value).startswith("bad.parquet: error: ") and message in str(err.value)


def test_broken_traces_are_one_line_errors(switching_run, tmp_path: Path) -> None:
    """Truncated JSON is located; nesting deeper than Python's stack is not a crash."""
    _, res = switching_run
    cut = tmp_path / "cut.json"
    cut.write_text(json.dumps(res.trace())[:5000])
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    no_series = tmp_path / "no_series.json"
    doc = json.loads(json.dumps(res.trace()))
    doc["series"] = {}  # a live run's decision log has no series
    no_series.write_text(json.dumps(doc))
    for path, message in ((cut, f"{cut}:1:5001: error: not an archself trace: invalid JSON"),
                          (deep, f"{deep}: error: not an archself trace")):
        out = CliRunner().invoke(app, ["explain", str(path)])
        assert out.exit_code == 1 and out.stderr.startswith(message), out.stderr
    out = CliRunner().invoke(app, ["report", "--trace", str(no_series), "-o",
                                   str(tmp_path / "r")])
    assert out.exit_code == 1 and "has no series t and J" in out.stderr, out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("decisions", [None, 5, "abc", {"a": 1}, [1, 2], [{"z": [1]}],
                                       [{"candidates": 5}], [{"chosen": "x"}]])
def test_explain_api_refuses_what_is_not_a_log(decisions) -> None:
    with pytest.raises(archself.ArchselfError, match="not a decision log: decisions"):
        archself.explain(decisions)
