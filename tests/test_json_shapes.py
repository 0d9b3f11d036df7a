"""Every command's ``--json`` has one shape, the model docs/json.md gives (issues 15, 41).

docs/json.md is the specification: each ``## command`` section holds the JSON Schema of
the pydantic model the command's output is built from (tools/json_docs.py). Every command
with a ``--json`` option is run here with its option variants (one file or several, one
run or a comparison, a fixed or an adaptive trace, a threshold or a top-k selector, with
or without a τ sweep, ...) and each output is validated with its model: no other key,
JSON types as they are (no conversion).
"""

from __future__ import annotations

import json
import re
import runpy
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import typer.main
from pydantic import TypeAdapter
from typer.testing import CliRunner

from archself.calibration.identify_results import IdentificationDoc
from archself.calibration.result import CalibrationDoc
from archself.cli import app
from archself.errors import ArchselfError
from archself.io.jsondata import (
    CampaignDoc,
    DecisionLog,
    DecisionRecordDoc,
    JobDoc,
    SimulateDoc,
    TraceMeta,
    document,
    jsonable,
)
from archself.runtime.knowledge import ActionEvaluation, DecisionRecord

from conftest import DIFFDRIVE, FIXTURES, ROOT

PAGE = ROOT / "docs" / "json.md"
MINIMAL = FIXTURES / "valid" / "minimal.yaml"
BAD = FIXTURES / "invalid" / "bad_kind.yaml"
PLANT = ROOT / "architectures" / "process_plant.yaml"
CAMPAIGN = ROOT / "docs" / "campaign" / "campaign.parquet"
JSON_DOCS = runpy.run_path(str(ROOT / "tools" / "json_docs.py"))


# ------------------------------------------------------------------ the specification
def documented_shapes() -> dict[str, Any]:
    """Command → the model of its section (``<!-- schema: module:Model -->``)."""
    shapes: dict[str, Any] = {}
    commands = PAGE.read_text(encoding="utf-8").split("\n# Documents archself reads back")[0]
    for section in re.split(r"^## ", commands, flags=re.M)[1:]:
        name = section.split("\n", 1)[0].strip()
        generated = re.search(r"<!-- schema: ([\w.]+):(\w+) -->", section)
        assert generated, f"docs/json.md: section {name} has no generated schema"
        shapes[name] = JSON_DOCS["model"](*generated.groups())
    return shapes


SHAPES = documented_shapes()


def test_every_json_command_is_documented_once() -> None:
    group = typer.main.get_command(app)
    ctx = group.make_context("archself", [], resilient_parsing=True)
    with_json = {
        name for name in group.list_commands(ctx)
        if any("--json" in p.opts for p in group.get_command(ctx, name).params)
    }
    assert set(SHAPES) == with_json
    assert "[json.md](json.md)" in (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")


def test_the_schemas_are_the_models() -> None:
    """docs/json.md's JSON Schemas are generated from the models (tools/json_docs.py)."""
    text = PAGE.read_text(encoding="utf-8")
    assert JSON_DOCS["render"](text) == text, "docs/json.md is out of date: " \
        "python tools/json_docs.py"
    names = [m[3] for m in JSON_DOCS["BLOCK"].finditer(text)]
    assert names == ["ValidateList", "SimulateDoc", "ExplainDoc", "LiveDoc", "Ros2Doc",
                     "CampaignDoc", "CampaignReportDoc", "InfoDoc", "CalibrationDoc",
                     "IdentificationDoc", "TraceDocument", "ParquetHead", "SavedRunsMeta",
                     "CampaignMeta", "RunReportSummary"]
    schema = json.loads(text.split("<!-- schema: archself.io.jsondata:TraceDocument -->\n")[1]
                        .split("```json\n")[1].split("```")[0])
    assert schema["required"] == ["meta", "series", "decisions"] and "TraceMeta" in schema["$defs"]


# ------------------------------------------------------------------ the runs
def _cli(args: list[str], stdin: str | bytes | None = None) -> Any:
    res = CliRunner().invoke(app, args, input=stdin)
    assert res.exit_code in (0, 1), (args, res.stderr)
    return json.loads(res.stdout)


def _short_plant(folder: Path, scenario: str | None = None, duration: int = 120) -> Path:
    """process_plant.yaml with the scenarios (or one) shortened (a text edit)."""
    text = PLANT.read_text(encoding="utf-8")
    if scenario is None:
        text = text.replace("duration_s: 600", f"duration_s: {duration}")
    else:
        head, sep, tail = text.partition(f"  {scenario}:\n")
        text = head + sep + tail.replace("duration_s: 600", f"duration_s: {duration}", 1)
    path = folder / f"plant_{scenario or 'all'}.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def _variant(minimal_text: str, old: str, new: str, folder: Path, name: str) -> Path:
    assert old in minimal_text
    path = folder / f"{name}.yaml"
    path.write_text(minimal_text.replace(old, new), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("json")


def _check(command: str, outputs: list[Any]) -> None:
    """Each output validates with its command's model: no other key, no conversion."""
    for out in outputs:
        SHAPES[command].model_validate(out, strict=True)


def test_validate(work: Path) -> None:
    outs = [
        _cli(["validate", "--json", str(MINIMAL)]),
        _cli(["validate", "--json", str(MINIMAL), str(BAD)]),
        _cli(["validate", "--json", "--strict", "-"], stdin=BAD.read_text(encoding="utf-8")),
        _cli(["validate", "--json", str(work / "missing.yaml")]),
    ]
    _check("validate", outs)
    assert [len(o) for o in outs] == [1, 2, 1, 1]
    assert outs[1][1]["findings"] and outs[1][1]["findings"][0]["line"] == 5


def test_simulate_and_explain(work: Path) -> None:
    plant = _short_plant(work, "drift_then_valve", 240)
    # the paper's z takes the PI-gain update during the dwell time (the source fit, the
    # default, does not: the PI's residual is the valve's echo); the update's shape is
    # what is checked here
    text = plant.read_text(encoding="utf-8")
    head, sep, tail = text.rpartition("\nruntime:\n")
    plant.write_text(f"{head}{sep}  localization: influence\n{tail}", encoding="utf-8")
    sims = [
        _cli(["simulate", str(MINIMAL), "-s", "calm", "--json"]),
        _cli(["simulate", str(MINIMAL), "-s", "calm", "--fixed", "--seed", "3", "--json"]),
        _cli(["simulate", str(MINIMAL), "-s", "calm", "--compare", "--json", "--trace",
              str(work / "calm.json")]),
        _cli(["simulate", "-", "-s", "calm", "-c", "only", "--json"],
             stdin=MINIMAL.read_text(encoding="utf-8")),
        # two switches and a parameter update between them (seed 3)
        _cli(["simulate", str(plant), "-s", "drift_then_valve", "--seed", "3", "--json",
              "--trace", str(work / "plant.parquet")]),
    ]
    _check("simulate", sims)
    assert [len(s["runs"]) for s in sims] == [1, 1, 2, 1, 1]
    assert [r["mode"] for r in sims[2]["runs"]] == ["fixed", "adaptive"]
    assert len(sims[4]["runs"][0]["switches"]) == 2 and sims[4]["runs"][0]["unit"] == "m"

    explained = [
        _cli(["explain", str(work / "plant.parquet"), "--json"]),
        _cli(["explain", str(work / "calm.fixed.json"), "--json"]),
        _cli(["explain", str(work / "calm.json"), "--json"]),
        _cli(["explain", "-", "--json"], stdin=(work / "plant.parquet").read_bytes()),
        _cli(["explain", "-", "--json"], stdin=_without_source(work / "calm.json")),
    ]
    _check("explain", explained)
    plant_ex = explained[0]
    assert len(plant_ex["switches"]) == 2 and len(plant_ex["updates"]) == 1
    kinds = {s["kind"] for e in explained for s in e["segments"]}
    assert kinds == {"cycle", "repeat"}
    assert all(s["source"] is None for s in explained[4]["switches"])


def _without_source(trace: Path) -> str:
    """A JSON trace as an older archself wrote it: no source estimate ê in the log."""
    doc = json.loads(trace.read_text(encoding="utf-8"))
    for d in doc["decisions"]:
        d.pop("source", None)
        if isinstance(d.get("chosen"), dict):
            d["chosen"].pop("source", None)
    return json.dumps(doc)


def test_live(work: Path) -> None:
    plant = _short_plant(work, "drift_then_valve", 240)
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "examples" / "live" / "plant_process.py"), str(plant),
         "--scenario", "drift_then_valve", "--seed", "3", "--port", "0", "--timeout", "60"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        first = proc.stdout.readline()  # type: ignore[union-attr]
        m = re.fullmatch(r"listening on 127\.0\.0\.1:(\d+) token (\w+)\n", first)
        assert m, first
        loop = subprocess.run(
            [sys.executable, "-m", "archself", "live", str(plant), "--connect",
             f"127.0.0.1:{m.group(1)}", "--json", "--log", str(work / "live.json"),
             "--timeout", "60", "--token", m.group(2)],
            capture_output=True, text=True, timeout=120,
        )
        proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert loop.returncode == 0, loop.stderr
    out = json.loads(loop.stdout)
    _check("live", [out])
    assert len(out["switches"]) == 2
    _check("explain", [_cli(["explain", str(work / "live.json"), "--json"])])


def test_campaign_and_campaign_report(work: Path) -> None:
    both, swept = work / "both.parquet", work / "swept.parquet"
    runs = [
        _cli(["campaign", str(MINIMAL), "-s", "calm", "--seeds", "2", "-o", str(both),
              "--workers", "1", "--json"]),
        _cli(["campaign", str(MINIMAL), "-s", "calm", "--seeds", "3", "-o", str(both),
              "--workers", "1", "--resume", "--json"]),
        _cli(["campaign", str(MINIMAL), "-s", "calm", "--seeds", "1", "--mode", "adaptive",
              "--sweep", "runtime.threshold=0.4,0.6", "-o", str(swept), "--workers", "1",
              "--json"]),
    ]
    _check("campaign", runs)
    assert [(r["ran"], r["skipped"]) for r in runs] == [(4, 0), (2, 4), (2, 0)]
    # the job record's leading fields (io.jsondata.JobDoc), as calibrate and identify have them
    assert [(r["file"], r["seeds"], r["root_seed"]) for r in runs] == [
        ("minimal.yaml", 2, 0), ("minimal.yaml", 3, 0), ("minimal.yaml", 1, 0)]
    reports = [
        _cli(["campaign-report", str(both), "-o", str(work / "r1"), "--json"]),
        _cli(["campaign-report", str(both), "-o", str(work / "r2"), "--expect", "calm=only",
              "--json"]),
        _cli(["campaign-report", str(swept), "-o", str(work / "r3"), "--json"]),
        # 1,008 runs: faulted scenarios, a τ sweep, expectations
        _cli(["campaign-report", str(CAMPAIGN), "-o", str(work / "r4"), "--expect",
              "imu_drift=a2", "--json"]),
    ]
    _check("campaign-report", reports)
    assert reports[2]["tau"] is not None and reports[2]["scenarios"][0]["adaptive_better_rms"] \
        is None
    big = {b["scenario"]: b for b in reports[3]["scenarios"]}
    assert big["nominal"]["detected"] is None and big["imu_drift"]["detected"]["n"] > 0
    for r in reports:  # summary.json is the same document
        assert json.loads((work / f"r{reports.index(r) + 1}" / "summary.json").read_text(
            encoding="utf-8")) == r


def test_info(work: Path) -> None:
    text = MINIMAL.read_text(encoding="utf-8")
    files = [
        MINIMAL,
        _variant(text, "threshold: 0.5", "top_k: 2", work, "top_k"),
        _variant(text, "threshold: 0.5", "hysteresis: {on: 0.6, off: 0.3}", work, "hyst"),
        PLANT,
        DIFFDRIVE,
    ]
    outs = [_cli(["info", str(f), "--json"]) for f in files]
    _check("info", outs)
    assert [o["runtime"]["selector"] for o in outs[:3]] == ["threshold", "top_k", "hysteresis"]
    assert [o["runtime"]["top_k"] for o in outs[:3]] == [None, 2, None]
    assert any(a["set"] for a in outs[3]["actions"])


def test_calibrate_and_identify(work: Path) -> None:
    plant = _short_plant(work, None, 60)
    runs = work / "runs.npz"
    cals = [
        _cli(["calibrate", str(plant), "--seeds", "2", "-c", "p1", "--workers", "1", "--json",
              "--save-runs", str(runs)]),
        _cli(["calibrate", str(plant), "--from-runs", str(runs), "--false-switch", "0.2",
              "--json"]),
    ]
    _check("calibrate", cals)
    assert {b["calibrated"] for b in cals[0]["bands"].values()} == {True, False}
    assert (cals[0]["seeds"], cals[0]["root_seed"], cals[0]["runs"]) == (2, 0, 2)
    idents = [
        _cli(["identify", str(plant), "--seeds", "1", "-c", "p1", "--executor", "inline",
              "--json"]),
        _cli(["identify", str(plant), "--seeds", "1", "-c", "p2", "--executor", "inline",
              "--all", "--json"]),
    ]
    _check("identify", idents)
    assert any(e["identifiable"] for e in idents[0]["edges"])


# ------------------------------------------------------------------ the models as writers
def test_one_job_record() -> None:
    """campaign, calibrate and identify lead with the same seven fields (io.jsondata.JobDoc)."""
    lead = list(JobDoc.model_fields)
    assert lead == ["architecture", "file", "seeds", "root_seed", "executor", "elapsed_s",
                    "archself_version"]
    for doc in (CampaignDoc, CalibrationDoc, IdentificationDoc):
        assert issubclass(doc, JobDoc) and list(doc.model_fields)[:7] == lead


def test_a_decision_record_is_written_by_its_model() -> None:
    """Field order, numbers as they are (numpy cleaned, NaN null, an int stays an int),
    the optional keys only when set, a key the model does not name kept (H1's records)."""
    chosen = {"to": "b", "from": "a", "action": "sw", "kind": "switch", "module": "m",
              "z": 2.0, "source": 1.0, "delta": 0.5, "score": 0.25}
    rec = DecisionRecord(
        cycle=3, t=0.5, configuration="a", phase="adapt", j_obs=np.float64(0.25), j_ref=0.1,
        r_global=float("nan"), r={"m": np.float32(1.5)}, z={"m": 2}, candidates=["m"],
        selector="threshold", chosen=chosen,
        evaluations=[ActionEvaluation("sw", "m", "switch", "b", z=2.0, cost=1)])
    d = document(DecisionRecordDoc, rec)
    assert list(d) == ["cycle", "t", "configuration", "phase", "j_obs", "j_ref", "r_global",
                       "r", "z", "localization", "candidates", "selector", "kappa",
                       "evaluations", "chosen", "note"]
    assert d["r_global"] is None and d["r"] == {"m": 1.5} and d["z"] == {"m": 2}
    assert type(d["z"]["m"]) is int and type(d["j_obs"]) is float
    assert list(d["chosen"]) == ["action", "kind", "module", "z", "source", "delta", "score",
                                 "from", "to"]
    ev = d["evaluations"][0]
    assert ev["cost"] == 1 and "utility" not in ev and "learned" not in ev
    rec.source, rec.compensated = {"m": 0.5}, ["m"]
    d = document(DecisionRecordDoc, rec)
    assert list(d)[9] == "source" and list(d)[-1] == "compensated"
    assert document(DecisionRecordDoc, {"cycle": 1, "update": {"w": 0.5}}) == {
        "cycle": 1, "update": {"w": 0.5}}


def test_the_one_pass_writer_equals_the_models_dump() -> None:
    """document() writes a read-back document in one pass; the validated model's own dump
    gives the same data, in the same order (an int of a float field becomes a float)."""
    rec = DecisionRecord(
        cycle=3, t=0.5, configuration="a", phase="adapt", j_obs=np.float64(0.25), j_ref=0.1,
        r_global=float("nan"), r={"m": np.float32(1.5)}, z={"m": 2}, candidates=["m"],
        selector="threshold", chosen={"from": "a", "to": "b", "action": "sw", "x": 1},
        evaluations=[ActionEvaluation("sw", "m", "switch", "b", z=2.0, cost=1, rule="mean")],
        equivalent=[["m", "n"]])
    meta = {"scenario": "s", "seed": 1, "mode": "adaptive", "configuration": "a",
            "final_configuration": "b", "metrics": {"rmse": np.float64(0.5)}, "extra": (1, 2),
            "switches": [{"t_s": 2, "from": "a", "to": "b"}], "report": {"threshold": 1}}
    for tp, data in ((DecisionLog, [rec, {"cycle": 1, "update": {"w": 0.5}}]),
                     (TraceMeta, meta)):
        adapter = TypeAdapter(tp)
        dumped = adapter.dump_python(adapter.validate_python(jsonable(data)), mode="json",
                                     by_alias=True, exclude_unset=True)
        assert json.dumps(document(tp, data)) == json.dumps(dumped)
    assert document(TraceMeta, meta)["switches"] == [{"t_s": 2.0, "from": "a", "to": "b"}]


def test_a_writer_bug_is_one_located_line() -> None:
    with pytest.raises(ArchselfError) as err:
        document(DecisionLog, [{"t": 1.0}, {"z": {"a": "x"}}], "decisions")
    assert str(err.value) == ("error: the document would not read back: decisions[1].z.a: "
                              "expected a number, got a string")
    with pytest.raises(ArchselfError, match=r"runs\[0\]\.seed: expected an integer"):
        document(SimulateDoc, {"runs": [{"scenario": "s", "seed": 1.5}]})


def test_explain_of_a_sparse_log_keeps_its_shape(tmp_path: Path) -> None:
    """A log whose records lack most fields (the reader allows it) explains in one shape."""
    meta = {"scenario": "s", "seed": 1, "mode": "adaptive", "configuration": "a",
            "final_configuration": "b", "metrics": {}}
    log = [{"t": 1.0}, {"t": 2.0}, {"t": 3.0, "chosen": {"action": "x", "to": "b"}},
           {"chosen": {"action": "y", "kind": "parameter_update"}}]
    path = tmp_path / "sparse.json"
    path.write_text(json.dumps({"meta": meta, "series": {}, "decisions": log}), "utf-8")
    out = _cli(["explain", str(path), "--json"])
    _check("explain", [out])
    assert [(s["from"], s["to"], s["equivalent"]) for s in out["switches"]] == [(None, "b", [])]
    assert [(u["t"], u["action"], u["set"]) for u in out["updates"]] == [(None, "y", None)]
    assert out["run"]["architecture"] is None and out["cycles"] == 4
