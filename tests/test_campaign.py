"""Campaigns: sweep PATHs, seeds, determinism across workers, resume, Ctrl-C, Parquet, report, Dask.

Tiny campaigns only: the minimal fixture's 20 s ``calm`` scenario and a 30 s
copy of the diffdrive ``actuator_fault`` scenario (the adaptive run switches at
20.5 s). No timing assertions.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from archself.campaign.driver import (
    CampaignInterrupted,
    plan_campaign,
    run_campaign,
    run_seeds,
)
from archself.campaign.executors import LocalExecutor
from archself.campaign.results import read_results
from archself.campaign.sweep import (
    CampaignError,
    apply_values,
    get_path,
    parse_path,
    parse_sweep,
    set_path,
    sweep_points,
)
from archself.cli import app
from archself.resources import BLAS_THREAD_VARIABLES, single_thread_blas

from conftest import DIFFDRIVE, FIXTURES

pa = pytest.importorskip("pyarrow")

MINIMAL = FIXTURES / "valid" / "minimal.yaml"


@pytest.fixture(scope="module")
def short_diffdrive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """diffdrive with 30 s scenarios (same faults) so that a campaign takes seconds."""
    text = DIFFDRIVE.read_text(encoding="utf-8").replace("duration_s: 400", "duration_s: 30")
    path = tmp_path_factory.mktemp("arch") / "diffdrive30.yaml"
    path.write_text(text, encoding="utf-8")
    return path


# --------------------------------------------------------------------------- PATHs and sweeps
@pytest.mark.parametrize(
    ("text", "keys"),
    [
        ("runtime.threshold", ("runtime", "threshold")),
        (
            "scenarios.imu_drift.faults[0].magnitude",
            ("scenarios", "imu_drift", "faults", 0, "magnitude"),
        ),
        (
            'modules["left wheel"].params.side.value',
            ("modules", "left wheel", "params", "side", "value"),
        ),
        ("a[1][2].b", ("a", 1, 2, "b")),
        ("edges[-1].weight", ("edges", -1, "weight")),
    ],
)
def test_parse_path(text: str, keys: tuple) -> None:
    assert parse_path(text) == keys


@pytest.mark.parametrize("text", ["", ".a", "a.", "a..b", "[0].a", "a b", "a[x]", "a]", "a.[0]"])
def test_parse_path_rejects(text: str) -> None:
    with pytest.raises(CampaignError, match="sweep PATH"):
        parse_path(text)


def test_set_path_copies_and_coerces() -> None:
    data = {"runtime": {"threshold": 0.5, "warmup_steps": 35}, "edges": [{"weight": 0.1}]}
    out = set_path(data, parse_path("runtime.warmup_steps"), 10.0)
    assert out["runtime"]["warmup_steps"] == 10 and isinstance(out["runtime"]["warmup_steps"], int)
    assert data["runtime"]["warmup_steps"] == 35
    out = set_path(data, parse_path("edges[0].weight"), 0.3)
    assert get_path(out, parse_path("edges[0].weight")) == 0.3
    with pytest.raises(CampaignError, match="did you mean 'threshold'"):
        get_path(data, parse_path("runtime.treshold.x"))
    with pytest.raises(CampaignError, match="index out of range"):
        set_path(data, parse_path("edges[3].weight"), 1.0)
    with pytest.raises(CampaignError, match="not a list"):
        set_path(data, parse_path("runtime[0]"), 1.0)
    with pytest.raises(CampaignError, match="single value"):
        set_path(data, parse_path("runtime"), 1.0)


@pytest.mark.parametrize(
    ("spec", "values"),
    [
        ("runtime.threshold=0.4:0.6:3", (0.4, 0.5, 0.6)),
        ("runtime.threshold=0.5:0.5:1", (0.5,)),
        ("x.y=1e-4,7e-4", (1e-4, 7e-4)),
        ("x.y=0.3:0.9:7", (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)),
    ],
)
def test_parse_sweep(spec: str, values: tuple) -> None:
    assert parse_sweep(spec).values == values


@pytest.mark.parametrize(
    ("spec", "msg"),
    [
        ("runtime.threshold", "expected PATH="),
        ("runtime.threshold=1:2", "START:STOP:NUM"),
        ("runtime.threshold=1:2:0", "at least 1"),
        ("runtime.threshold=a:2:3", "not a number"),
        ("runtime.threshold=1:2:x", "not an integer"),
        ("runtime.threshold=1,1", "repeated"),
        ("runtime.threshold=nan,1", "finite"),
        ("=1,2", "empty"),
    ],
)
def test_parse_sweep_rejects(spec: str, msg: str) -> None:
    with pytest.raises(CampaignError, match=msg):
        parse_sweep(spec)


def test_sweep_points_product_and_duplicates() -> None:
    a, b = parse_sweep("a.b=1,2"), parse_sweep("c.d=3,4,5")
    assert sweep_points([a, b]) == [(1, 3), (1, 4), (1, 5), (2, 3), (2, 4), (2, 5)]
    assert sweep_points([]) == [()]
    with pytest.raises(CampaignError, match="twice"):
        sweep_points([a, a])


def test_apply_values_revalidates() -> None:
    from archself.model.loader import load_architecture

    data = load_architecture(DIFFDRIVE).data
    sw = [
        parse_sweep("scenarios.imu_drift.faults[0].magnitude=1e-3"),
        parse_sweep("runtime.threshold=0.4"),
    ]
    arch = apply_values(data, sw, (1e-3, 0.4))
    assert arch.scenarios["imu_drift"].faults[0].magnitude == 1e-3
    assert arch.runtime.threshold == 0.4
    with pytest.raises(CampaignError, match=r"runtime.threshold=-1: runtime.threshold: .*greater"):
        apply_values(data, [parse_sweep("runtime.threshold=-1")], (-1.0,), "f.yaml")
    with pytest.raises(CampaignError, match=r"sweep PATH runtime.tau: no such key; known: "):
        apply_values(data, [parse_sweep("runtime.tau=1")], (1.0,))


def test_run_seeds_spawned_and_stable() -> None:
    import numpy as np

    seeds = run_seeds(7, 4)
    assert seeds[:2] == run_seeds(7, 2)
    assert len(set(seeds)) == 4
    child = np.random.SeedSequence(7).spawn(4)[3]
    assert seeds[3] == int(child.generate_state(1, dtype=np.uint32)[0])


def test_plan_rejects_user_errors(tmp_path: Path) -> None:
    with pytest.raises(CampaignError, match="unknown scenario 'storm'; known: calm"):
        plan_campaign(MINIMAL, ["storm"], 1)
    with pytest.raises(CampaignError, match="at least 1"):
        plan_campaign(MINIMAL, ["calm"], 0)
    with pytest.raises(CampaignError, match="no such key"):
        plan_campaign(MINIMAL, ["calm"], 1, [parse_sweep("scenarios.storm.duration_s=1,2")])
    jobs, meta = plan_campaign(
        MINIMAL, ["calm"], 2, [parse_sweep("runtime.threshold=0.4,0.6")], traces=tmp_path / "tr"
    )
    assert len(jobs) == 8 and len({j.run_id for j in jobs}) == 8
    assert meta["sweeps"] == ["runtime.threshold"] and meta["thresholds"] == ["runtime.threshold"]
    assert meta["fault_free"] == ["calm"]
    # common random numbers: a replicate has the same seed in every mode and sweep point
    assert len({j.seed for j in jobs if j.replicate == 0}) == 1


@pytest.mark.parametrize(
    ("spec", "msg"),
    [  # located at the swept value in the file, worded as `validate` words it
        ("runtime.threshold=-1", "minimal.yaml:43:14: error: runtime.threshold: expected a "
         "number > 0.0, got number -1"),
        ("modules.path.params.waypoints.value[1][0]=1e300", "minimal.yaml:16:36: error: "
         "modules.path.params.waypoints.value[1][0]: expected a number ≤ 1e+09"),
        ("runtime.objective.components[0]=5", "minimal.yaml:42:74: error: "
         "runtime.objective.components[0]: component 5 is out of range"),
    ],
)
def test_plan_locates_a_refused_sweep_value(spec: str, msg: str) -> None:
    with pytest.raises(CampaignError) as info:
        plan_campaign(MINIMAL, ["calm"], 1, [parse_sweep(spec)])
    assert msg in str(info.value) and ":1:1:" not in str(info.value)
    assert "bool" not in str(info.value) and "1000000000000000" not in str(info.value)


# --------------------------------------------------------------------------- running
SCHEMA = {
    "run_id": "string",
    "scenario": "string",
    "runtime.threshold": "double",
    "replicate": "int32",
    "seed": "int64",
    "mode": "string",
    "start_configuration": "string",
    "final_configuration": "string",
    "configuration_path": "string",
    "switch_times_s": "list<element: double>",
    "n_switches": "int32",
    "first_fault_onset_s": "double",
    "detection_delay_s": "double",
    "false_switches": "int32",
    "n_updates": "int32",
    "updates": "string",
    "module_faults": "string",
    "max_error": "double",
    "final_error": "double",
    "rms_error": "double",
    "peak_time_s": "double",
    "unit": "string",
    "trace": "string",
    "error": "string",
}


@pytest.fixture(scope="module")
def local_results(short_diffdrive: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real local campaign on 2 processes through the CLI (the determinism reference)."""
    out = tmp_path_factory.mktemp("local") / "results.parquet"
    res = CliRunner().invoke(
        app,
        [
            "campaign",
            str(short_diffdrive),
            "-s",
            "actuator_fault",
            "-s",
            "nominal",
            "--seeds",
            "2",
            "--sweep",
            "runtime.threshold=0.45,0.65",
            "--workers",
            "2",
            "-o",
            str(out),
            "--traces",
            str(out.parent / "traces"),
        ],
    )
    assert res.exit_code == 0, res.output
    assert "16 runs (16 new, 0 already there, 0 failed)" in res.stdout
    return out


def test_parquet_schema_and_rows(local_results: Path) -> None:
    table, meta = read_results(local_results)
    assert {f.name: str(f.type) for f in table.schema} == SCHEMA
    assert list(table.schema.names) == list(SCHEMA)
    assert meta["architecture"] == "diffdrive" and meta["root_seed"] == 0
    rows = table.to_pylist()
    assert len(rows) == 16 and all(r["error"] is None for r in rows)
    ada = [r for r in rows if r["scenario"] == "actuator_fault" and r["mode"] == "adaptive"]
    for r in ada:  # the weak wheel is compensated right after the warm-up
        assert r["configuration_path"] == "a1>a3"
        assert r["first_fault_onset_s"] == 20.0
        assert r["detection_delay_s"] == pytest.approx(r["switch_times_s"][0] - 20.0)
        assert r["false_switches"] == 0
    fixed = [r for r in rows if r["mode"] == "fixed"]
    assert all(r["n_switches"] == 0 and r["configuration_path"] == "a1" for r in fixed)
    nominal = [r for r in rows if r["scenario"] == "nominal"]
    assert all(r["first_fault_onset_s"] is None and r["detection_delay_s"] is None for r in nominal)
    assert all(r["false_switches"] == r["n_switches"] for r in nominal)
    traces = [Path(r["trace"]) for r in rows]
    assert all(p.is_file() for p in traces) and len(set(traces)) == 16
    doc = json.loads(traces[0].read_text(encoding="utf-8"))
    assert set(doc) == {"meta", "series", "decisions"}


def test_same_table_whatever_the_workers(
    local_results: Path, short_diffdrive: Path, tmp_path: Path
) -> None:
    """1 worker (in-process) and 2 worker processes give the same table."""
    jobs, meta = plan_campaign(
        short_diffdrive,
        ["actuator_fault", "nominal"],
        2,
        [parse_sweep("runtime.threshold=0.45,0.65")],
        traces=local_results.parent / "traces",
    )
    out = tmp_path / "one.parquet"
    outcome = run_campaign(jobs, meta, out, executor="inline")
    assert outcome.ran == 16 and outcome.failed == 0
    a, _ = read_results(local_results)
    b, _ = read_results(out)
    assert a.equals(b)


def test_local_executor_one_worker_matches(short_diffdrive: Path, tmp_path: Path) -> None:
    jobs, meta = plan_campaign(short_diffdrive, ["actuator_fault"], 2, modes=("adaptive",))
    one = run_campaign(jobs, meta, tmp_path / "w1.parquet", workers=1)
    assert one.workers == 1 and one.executor == "local"
    run_campaign(jobs, meta, tmp_path / "inline.parquet", executor="inline")
    assert read_results(tmp_path / "w1.parquet")[0].equals(
        read_results(tmp_path / "inline.parquet")[0]
    )


def test_resume_skips_finished_runs(tmp_path: Path) -> None:
    jobs, meta = plan_campaign(MINIMAL, ["calm"], 3)
    out = tmp_path / "r.parquet"
    first = run_campaign(jobs[:2], meta, out, executor="inline")
    assert (first.ran, first.rows) == (2, 2)
    with pytest.raises(CampaignError, match="exists; --resume"):
        run_campaign(jobs, meta, out, executor="inline")
    calls: list[tuple[int, int]] = []
    second = run_campaign(
        jobs, meta, out, executor="inline", resume=True, progress=lambda d, t: calls.append((d, t))
    )
    assert (second.skipped, second.ran, second.rows) == (2, 4, 6)
    assert calls[0] == (0, 4) and calls[-1] == (4, 4)
    third = run_campaign(jobs, meta, out, executor="inline", resume=True)
    assert (third.skipped, third.ran, third.rows) == (6, 0, 6)
    full = tmp_path / "full.parquet"
    run_campaign(jobs, meta, full, executor="inline")
    assert read_results(out)[0].equals(read_results(full)[0])
    # another campaign's file is not resumed
    jobs2, meta2 = plan_campaign(MINIMAL, ["calm"], 3, root_seed=1)
    with pytest.raises(CampaignError, match="different --root-seed"):
        run_campaign(jobs2, meta2, out, executor="inline", resume=True)


def test_interrupt_keeps_finished_runs(tmp_path: Path) -> None:
    jobs, meta = plan_campaign(MINIMAL, ["calm"], 3)
    out = tmp_path / "r.parquet"

    def progress(done: int, total: int) -> None:
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(CampaignInterrupted, match="2 runs saved") as info:
        run_campaign(jobs, meta, out, executor="inline", progress=progress)
    assert info.value.exit_code == 130
    assert read_results(out)[0].num_rows == 2
    again = run_campaign(jobs, meta, out, executor="inline", resume=True)
    assert (again.skipped, again.ran) == (2, 4)


def test_failed_run_is_a_row(tmp_path: Path) -> None:
    from archself.campaign.worker import run_job

    jobs, _ = plan_campaign(MINIMAL, ["calm"], 1)
    bad = jobs[0].__class__(**{**jobs[0].__dict__, "scenario": "storm"})
    row = run_job(bad)
    assert row["error"].startswith("SimulationError: unknown scenario 'storm'")
    assert row["max_error"] != row["max_error"]  # NaN


def test_worker_imports_stay_light() -> None:
    code = (
        "import sys, archself.campaign.worker, archself.campaign.driver; "
        "print(sorted(m for m in ('matplotlib', 'jinja2', 'pyarrow', 'dask') "
        "if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


# --------------------------------------------------------------------------- CLI
def test_cli_campaign_errors(tmp_path: Path) -> None:
    runner = CliRunner()
    res = runner.invoke(
        app,
        [
            "campaign",
            str(MINIMAL),
            "-s",
            "calm",
            "--seeds",
            "1",
            "--sweep",
            "runtime.treshold=1,2",
            "-o",
            str(tmp_path / "x.pq"),
        ],
    )
    assert res.exit_code == 1
    assert res.stderr.strip().count("\n") == 0
    assert "sweep PATH runtime.treshold: no such key; did you mean 'threshold'?" in res.stderr
    res = runner.invoke(
        app, ["campaign", str(MINIMAL), "-s", "calm", "--seeds", "1", "--executor", "ray"]
    )
    assert res.exit_code == 2
    res = runner.invoke(
        app,
        [
            "campaign",
            str(MINIMAL),
            "-s",
            "calm",
            "--seeds",
            "1",
            "--address",
            "tcp://127.0.0.1:1",
            "-o",
            str(tmp_path / "x.pq"),
        ],
    )
    assert res.exit_code == 1 and "--address needs --executor dask" in res.stderr
    res = runner.invoke(app, ["campaign", "--help"])
    assert res.exit_code == 0 and "--resume" in res.stdout and "--traces" in res.stdout


def test_campaign_report_renders(local_results: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    res = CliRunner().invoke(
        app,
        [
            "campaign-report",
            str(local_results),
            "-o",
            str(out),
            "--expect",
            "actuator_fault=a3",
            "--expect",
            "nominal=a1",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "actuator_fault: correct 100 % (4/4)" in res.stdout
    assert "τ sweep (runtime.threshold)" in res.stdout
    html = (out / "index.html").read_text(encoding="utf-8")
    assert "<h2>τ sweep</h2>" in html and 'src="tau.svg"' in html
    for name in ("tau.svg", "rms.svg", "max.svg", "final.svg", "delays.svg"):
        assert (out / name).read_text(encoding="utf-8").lstrip().startswith("<?xml")
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    blocks = {b["scenario"]: b for b in summary["scenarios"]}
    assert blocks["actuator_fault"]["faulted"] and not blocks["nominal"]["faulted"]
    assert blocks["actuator_fault"]["detected"]["rate"] == 1.0
    assert [p["value"] for p in summary["tau"]["points"]] == [0.45, 0.65]
    res = CliRunner().invoke(
        app, ["campaign-report", str(local_results), "-o", str(out), "--expect", "storm=a2"]
    )
    assert res.exit_code == 1 and "storm: no such scenario" in res.stderr
    res = CliRunner().invoke(
        app, ["campaign-report", str(tmp_path / "none.parquet"), "-o", str(out)]
    )
    assert res.exit_code == 1 and "no such file" in res.stderr


def test_report_escapes_hostile_names(tmp_path: Path) -> None:
    from archself.campaign.report import campaign_report
    from archself.campaign.results import write_results

    row = {
        "run_id": "x",
        "scenario": "<script>alert(1)</script>",
        "replicate": 0,
        "seed": 1,
        "mode": "adaptive",
        "start_configuration": "a",
        "final_configuration": "<b>",
        "configuration_path": "a><b>",
        "switch_times_s": [1.0],
        "n_switches": 1,
        "first_fault_onset_s": None,
        "detection_delay_s": None,
        "false_switches": 1,
        "max_error": 1.0,
        "final_error": 1.0,
        "rms_error": 1.0,
        "peak_time_s": 1.0,
        "unit": "<u>",
        "trace": None,
        "error": None,
    }
    meta = {
        "architecture": "<i>x</i>",
        "file": "f",
        "sha256": "0" * 64,
        "root_seed": 0,
        "sweeps": [],
    }
    write_results(tmp_path / "r.parquet", [row], [], meta)
    campaign_report(tmp_path / "r.parquet", tmp_path / "rep")
    html = (tmp_path / "rep" / "index.html").read_text(encoding="utf-8")
    assert "<script>alert" not in html and "&lt;script&gt;" in html
    assert "<i>x</i>" not in html
    assert "RMS [&lt;u&gt;]" in html and "<u>" not in html


def _as_old_table(path: Path) -> None:
    """Rewrite a results file as archself wrote it before the metrics had a unit."""
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    old = {"max_error": "max_error_m", "final_error": "final_error_m", "rms_error": "rms_error_m"}
    metadata = table.schema.metadata
    table = table.drop_columns(["unit"]).rename_columns(
        [old.get(n, n) for n in table.column_names if n != "unit"]
    )
    pq.write_table(table.replace_schema_metadata(metadata), path)


def test_old_results_are_read_reported_and_resumed(tmp_path: Path) -> None:
    """A table with max_error_m ... (no unit column) reads as max_error ... in m, and resumes."""
    jobs, meta = plan_campaign(MINIMAL, ["calm"], 2, modes=("fixed",))
    out = tmp_path / "r.parquet"
    run_campaign(jobs[:1], meta, out, executor="inline")
    new_row = read_results(out)[0].to_pylist()[0]
    _as_old_table(out)
    table, _ = read_results(out)
    assert "max_error_m" not in table.column_names
    (row,) = table.to_pylist()
    assert row["unit"] == "m"
    assert {k: row[k] for k in ("max_error", "final_error", "rms_error", "peak_time_s")} == {
        k: new_row[k] for k in ("max_error", "final_error", "rms_error", "peak_time_s")
    }
    again = run_campaign(jobs, meta, out, executor="inline", resume=True)
    assert (again.skipped, again.ran, again.rows) == (1, 1, 2)
    rows = read_results(out)[0].to_pylist()
    assert all(r["max_error"] == r["max_error"] for r in rows)  # no metric lost (NaN)
    assert [r["unit"] for r in rows] == ["m", None]  # minimal.yaml declares no unit
    res = CliRunner().invoke(app, ["campaign-report", str(out), "-o", str(tmp_path / "rep")])
    assert res.exit_code == 0, res.output
    assert "median RMS fixed" in res.stdout


def test_damaged_results_are_one_line_errors(tmp_path: Path) -> None:
    """A results table with the metadata but odd columns or metadata: exit 1, not exit 3."""
    import pyarrow.parquet as pq

    jobs, meta = plan_campaign(MINIMAL, ["calm"], 2, modes=("fixed",))
    good = tmp_path / "r.parquet"
    run_campaign(jobs[:1], meta, good, executor="inline")
    table = pq.read_table(good)
    md = table.schema.metadata
    rep = table.column_names.index("replicate")
    cases = {
        "no_replicate": (table.drop_columns(["replicate"]), md, "no column 'replicate'"),
        "seed_text": (table.set_column(table.column_names.index("seed"), "seed",
                                       pa.array(["a"])), md, "column 'seed' holds string"),
        "null_replicate": (table.set_column(rep, "replicate", pa.array([None], pa.int32())),
                           md, "column 'replicate' has 1 empty value"),
        "meta_list": (table, {b"archself.campaign": b"[1]"}, "damaged campaign metadata"),
        "sweeps_text": (table, {b"archself.campaign": json.dumps(
            {**meta, "sweeps": "runtime.threshold"}).encode()}, "damaged campaign metadata"),
    }
    for name, (t, metadata, msg) in cases.items():
        bad = tmp_path / f"{name}.parquet"
        pq.write_table(t.replace_schema_metadata(metadata), bad)
        before = bad.read_bytes()
        res = CliRunner().invoke(app, ["campaign-report", str(bad), "-o", str(tmp_path / name)])
        assert res.exit_code == 1 and msg in res.output, (name, res.output)
        with pytest.raises(CampaignError, match=msg):
            run_campaign(jobs, meta, bad, executor="inline", resume=True)
        assert bad.read_bytes() == before  # the user's table is left as it was
    # a column rewritten in a type that converts (int64 replicates) is read as before
    wide = tmp_path / "int64.parquet"
    pq.write_table(table.set_column(rep, "replicate", table.column("replicate").cast(pa.int64()))
                   .replace_schema_metadata(md), wide)
    assert read_results(wide)[0].equals(read_results(good)[0])


# --------------------------------------------------------------------------- Dask
def test_dask_local_cluster_address(
    short_diffdrive: Path, local_results: Path, tmp_path: Path
) -> None:
    """The same command through a scheduler address gives the same table."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        out = tmp_path / "dask.parquet"
        res = CliRunner().invoke(
            app,
            [
                "campaign",
                str(short_diffdrive),
                "-s",
                "actuator_fault",
                "-s",
                "nominal",
                "--seeds",
                "2",
                "--sweep",
                "runtime.threshold=0.45,0.65",
                "--executor",
                "dask",
                "--address",
                cluster.scheduler_address,
                "-o",
                str(out),
                "--traces",
                str(local_results.parent / "traces"),
                "--json",
            ],
        )
        assert res.exit_code == 0, res.output
        data = json.loads(res.stdout)
        assert data["executor"] == "dask" and data["ran"] == 16 and data["workers"] == 2
    assert read_results(out)[0].equals(read_results(local_results)[0])


def test_worker_parses_the_file_once_per_process(monkeypatch: pytest.MonkeyPatch) -> None:
    import archself.model.loader
    from archself.campaign import worker

    calls = []
    real = archself.model.loader.load_text

    def counting(text: str, file: str = "<input>"):
        calls.append(file)
        return real(text, file)

    monkeypatch.setattr(archself.model.loader, "load_text", counting)
    monkeypatch.setattr(worker, "_TEXTS", {})
    monkeypatch.setattr(worker, "_ARCHS", worker.OrderedDict())
    jobs, _ = plan_campaign(MINIMAL, ["calm"], 2, [parse_sweep("runtime.threshold=0.4,0.6")])
    calls.clear()  # planning loads the file too (in the driver process)
    rows = [worker.run_job(j) for j in jobs]
    assert all(r["error"] is None for r in rows)
    assert len(calls) == 1  # 8 runs, 2 sweep points: parsed once, validated once per point
    assert len(worker._ARCHS) == 2


def test_single_thread_blas_keeps_a_users_choice() -> None:
    env = {"OMP_NUM_THREADS": "4", "MKL_NUM_THREADS": ""}
    single_thread_blas(env)
    assert env == {"OMP_NUM_THREADS": "4", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def test_local_workers_run_single_threaded_blas() -> None:
    # idle OpenBLAS threads spin: two workers with two threads each slowed each other
    # by 16 %; the workers inherit the setting from the process that starts them
    with LocalExecutor(workers=1) as ex:
        seen = {v: ex.submit(os.getenv, v).result() for v in BLAS_THREAD_VARIABLES}
    assert seen == {v: os.environ[v] for v in BLAS_THREAD_VARIABLES}
    assert "1" in seen.values()



def _finish_spread(units, real) -> float:
    """Units taken in order by whichever of 2 workers is free: (last − first) / last finish."""
    import heapq

    free = [(0.0, 0), (0.0, 1)]
    for u in units:
        t, w = heapq.heappop(free)
        heapq.heappush(free, (t + len(u) * real[u[0].scenario], w))
    first, last = sorted(t for t, _ in free)
    return (last - first) / last


@pytest.mark.parametrize("runs", [500, 1000])  # 200: 8.5 % (a last unit of 8
# runs is ~1/10 of a worker's share)
def test_lane_units_balance_workers_whatever_the_scenarios_cost(runs: int) -> None:
    """Units for 2 workers: every run once, one (scenario, mode) per unit, largest first;
    taken in order by whichever worker is free, the workers finish within 5 % of each
    other even when one scenario's runs cost 1.6× the other's (the estimate says equal)."""
    from archself.campaign.plan import MIN_LANES, default_lanes, lane_units
    from archself.campaign.worker import Job

    jobs = [Job(arch_text="", arch_digest="d", file="f", scenario=("imu", "act")[i % 2],
                replicate=i // 2, seed=i, run_id=str(i), mode="adaptive") for i in range(runs)]
    width = default_lanes(jobs, 2)
    units = lane_units(jobs, width, 2, cost=lambda j: 1.0)
    assert sorted(j.run_id for u in units for j in u) == sorted(j.run_id for j in jobs)
    assert all(len({(j.scenario, j.mode) for j in u}) == 1 for u in units)
    sizes = [len(u) for u in units]
    assert sizes == sorted(sizes, reverse=True) and min(sizes) >= MIN_LANES
    assert {units[0][0].scenario, units[1][0].scenario} == {"imu", "act"}  # interleaved
    real = {"imu": 1.6, "act": 1.0}
    assert _finish_spread(units, real) < 0.05
    if runs <= 2 * width:  # without workers: one unit per scenario, one per worker
        assert _finish_spread(lane_units(jobs, width), real) > 0.3


def test_rows_name_the_module_faults(tmp_path: Path) -> None:
    """``module_faults``: the run's faults as ``module: reason``, the same as lanes and
    per run (thermal_zone's sensor A drops out at 100 s: its observer loses its input,
    then the sensor is silent)."""
    text = (DIFFDRIVE.parent / "thermal_zone.yaml").read_text(encoding="utf-8")
    arch = tmp_path / "thermal.yaml"
    arch.write_text(text.replace("duration_s: 300", "duration_s: 110"), encoding="utf-8")
    jobs, meta = plan_campaign(arch, ["sensor_dropout", "nominal"], 2)
    rows = {}
    for lanes in (1, None):
        out = tmp_path / f"lanes{lanes}.parquet"
        run_campaign(jobs, meta, out, executor="inline", lanes=lanes)
        rows[lanes] = {r["run_id"]: r["module_faults"] for r in read_results(out)[0].to_pylist()}
    assert rows[1] == rows[None]
    faults = {k.split("|")[0] + "|" + k.split("|")[-1]: v for k, v in rows[1].items()}
    assert faults["sensor_dropout|fixed"] == "obs_a: lost input measurement;sensor_a: silent"
    assert faults["nominal|fixed"] == "" and faults["nominal|adaptive"] == ""
    assert "sensor_a: silent" in faults["sensor_dropout|adaptive"]
