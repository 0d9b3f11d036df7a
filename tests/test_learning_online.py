"""Issue 36, the rest: online W and bands (runtime.online), the learned table inside the
trace, and a strategy's tactics through the learning review.

archself/runtime/knowledge.py, MapeK.saved_knowledge, runtime/knowledge.py load_table,
runtime/strategies.py; docs/learning.md.
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from numpy.testing import assert_allclose
from test_runtime_fakes import FakeSystem, make_arch, run_loop
from typer.testing import CliRunner

from archself.check import check
from archself.cli import app
from archself.errors import ArchselfError
from archself.model.architecture import Architecture, Online, Strategy
from archself.model.loader import load_architecture
from archself.resources import data_dir
from archself.runtime import MapeK, explain
from archself.runtime.influence import spectral_radius, weight_matrix
from archself.runtime.knowledge import OutcomeTable, load_table
from archself.sim.run import simulate

PLANT = data_dir("architectures") / "process_plant.yaml"
SIGNALS = {"src": "err", "est_a": "innov", "ctl_a": "track", "act": "cmd_err"}
# the world of the fake: est_a → ctl_a is 0.8 (declared 0.5); no act → src feedback
# (declared 0.3): the fit assumes none inside the window (docs/learning.md)
TRUE_W = {("src", "est_a"): 0.5, ("est_a", "ctl_a"): 0.8, ("ctl_a", "act"): 0.4}


@pytest.fixture(scope="module")
def plant() -> Architecture:
    return load_architecture(PLANT).arch


def _variant(arch: Architecture, factor: float = 1.0, **online) -> Architecture:
    """A deep copy (a model_dump round trip loses the edges' named ports)."""
    out = copy.deepcopy(arch)
    for m in out.modules.values():
        if m.residual is not None:
            m.residual.nominal *= factor
    out.runtime.online = Online.model_validate(online)
    return out


def _residual_world(t: float, conf: str) -> dict[str, dict[str, float]]:
    """Signals of the fake's base modules: r = (I − W_trueᵀ)⁻¹ e, e random, s = n·r/σ."""
    names = list(SIGNALS)
    W = np.zeros((4, 4))
    for (a, b), w in TRUE_W.items():
        W[names.index(a), names.index(b)] = w
    # the source varies most; the others' own noise is small beside what reaches them
    e = 1.0 + np.array([0.5, 0.05, 0.05, 0.05]) * np.random.default_rng(
        int(round(t * 10))).standard_normal(4)
    r = np.linalg.solve(np.eye(4) - W.T, e)
    return {m: {SIGNALS[m]: 0.1 * float(v)} for m, v in zip(names, r, strict=True)}


def _online_fake(feedback: bool = False, **runtime) -> MapeK:
    """The fake's loop with online W over :func:`_residual_world`; without its act → src
    edge unless ``feedback``."""
    weights = {"enabled": True, "every_s": 10.0, "window_s": 40.0, "max_change": 0.2,
               "min_excitation": 0.0}
    arch = make_arch(threshold=1e6, online={"weights": weights}, **runtime)
    if not feedback:
        data = arch.model_dump(by_alias=True, exclude_none=True)
        data["edges"] = [e for e in data["edges"] if (e["from"], e["to"]) != ("act", "src")]
        arch = Architecture.model_validate(data)
    loop = MapeK(arch)
    run_loop(loop, FakeSystem(arch, _residual_world), 160.0)
    return loop


# ---------------------------------------------------------------- off by default
def test_online_is_off_by_default_and_the_trace_unchanged(plant):
    loop = MapeK(plant)
    assert loop.online is None and loop.saved_knowledge() is None
    res = simulate(plant, "valve_loss", seed=1, adapt=loop)
    assert "knowledge" not in res.meta
    assert not any("online" in d.note for d in loop.decisions)


# ---------------------------------------------------------------- online W
def test_a_mis_declared_weight_is_refitted_within_its_bounds():
    """est_a → ctl_a declared 0.5, the world's 0.8: it climbs by ≤ 20 % per update to 0.8."""
    loop = _online_fake()
    moves = [e for e in loop.online.events if e["what"] == "est_a→ctl_a"]
    accepted = [e for e in moves if e["outcome"] == "accepted"]
    assert len(accepted) >= 3
    for e in accepted:
        assert e["new"] <= e["old"] * 1.2 + 1e-12 and e["new"] >= e["old"] * 0.8 - 1e-12
        assert e["window"][1] - e["window"][0] <= 40.0 + 1e-9 and e["samples"] >= 10
    assert [e["new"] for e in accepted[:2]] == pytest.approx([0.6, 0.72])
    final = loop.knowledge.arch_weight("est_a", "ctl_a", "xhat")
    assert_allclose(final, 0.8, atol=0.06)
    assert_allclose(loop.knowledge.arch_weight("src", "est_a", "y"), 0.5, atol=0.06)
    # the influence the loop uses is the new W's (the factorization was refreshed)
    e = np.zeros(len(loop.knowledge.names))
    e[loop.knowledge.index["est_a"]] = 1.0
    z = loop.knowledge.influence(e)
    assert_allclose(z[loop.knowledge.index["ctl_a"]], final, rtol=0.1)
    assert any(d.note.startswith("online W:") for d in loop.decisions)
    assert loop.knowledge.online is loop.online.events  # the record is Knowledge's
    saved = loop.saved_knowledge()["online"]
    assert {"edge": "est_a→ctl_a", "declared": 0.5, "now": final} in saved["weights"]


def test_edges_on_a_cycle_are_not_fitted():
    """With act → src declared, every edge of the loop is on a cycle: W is kept as declared.

    (Fitted, src on act would find act's copy of src: the reverse direction, 1/0.16.)
    """
    loop = _online_fake(feedback=True)
    loop_edges = {"src→est_a", "est_a→ctl_a", "ctl_a→act", "act→src"}
    events = [e for e in loop.online.events if e["what"] in loop_edges]
    assert {e["what"] for e in events} == loop_edges
    assert all(e["outcome"] == "rejected" and e["reason"].startswith("on a cycle")
               for e in events)
    assert loop.knowledge.arch_weight("act", "src", "force") == 0.3
    assert loop.online.to_dict()["weights"] == []


def test_an_update_that_breaks_the_spectral_rule_is_rejected_whole():
    """The guard behind every update (only a cycle's weights move ρ, and those are not
    fitted): a W with ρ ≥ runtime.max_spectral_radius is rejected, every change of it."""
    loop = _online_fake(feedback=True)
    k, online = loop.knowledge, loop.online
    pairs = online._pairs()
    notes: list[str] = []
    proposed = {("act", "src"): (5.0, 5.0, "fitted"), ("src", "est_b"): (0.6, 0.6, "fitted")}
    assert not online._apply_weights(200.0, pairs, proposed, [160.0, 200.0], 40, notes)
    events = online.events[-2:]
    assert [e["what"] for e in events] == ["act→src", "src→est_b"]
    for e in events:
        assert e["outcome"] == "rejected" and e["new"] == e["old"]
        assert e["reason"].startswith("rejected: ρ(W) = ")
        assert "≥ max_spectral_radius" in e["reason"]
    assert k.arch_weight("act", "src", "force") == 0.3
    assert k.arch_weight("src", "est_b", "y") == 0.5
    assert "0 weight(s) updated" in notes[0]
    full = [(s, t, k.arch_weight(s, t, c)) for s, t, c in k._edge_keys]
    assert spectral_radius(weight_matrix(k.names, full)) < k.arch.runtime.max_spectral_radius


# ---------------------------------------------------------------- online bands
def test_tight_bands_widen_within_their_bounds_and_false_alarms_drop(plant):
    """Every band at 0.4 of the file's: the nominal run false-alarms; online it does less."""
    bands = {"enabled": True, "window_s": 20.0, "every_s": 20.0, "max_step": 1.5,
             "max_factor": 4.0}
    tight, online = _variant(plant, 0.4), _variant(plant, 0.4, bands=bands)
    alarms = {}
    for name, arch in (("off", tight), ("on", online)):
        loop = MapeK(arch)
        res = simulate(arch, "nominal", seed=1, adapt=loop)
        alarms[name] = sum(1 for d in loop.decisions if d.candidates)
    assert alarms["on"] < 0.8 * alarms["off"]
    declared = {n: m.residual.nominal for n, m in online.modules.items() if m.residual}
    events = [e for e in loop.online.events if e["kind"] == "bands"]
    accepted = [e for e in events if e["outcome"] == "accepted"]
    assert accepted and any(e["new"] > e["old"] for e in accepted)
    for e in accepted:
        assert e["old"] / 1.5 - 1e-12 <= e["new"] <= e["old"] * 1.5 + 1e-12
        assert declared[e["what"]] - 1e-12 <= e["new"] <= 4.0 * declared[e["what"]] + 1e-12
        assert e["window"][0] < e["window"][1] <= e["t_s"] and e["samples"] == 10
    moved = {b["module"]: b for b in res.meta["knowledge"]["online"]["bands"]}
    now = loop.monitor.bands(sorted(moved))
    assert_allclose([moved[n]["now"] for n in sorted(moved)], now)
    assert "note: online bands:" in explain(loop.decisions)


# ---------------------------------------------------------------- C: the table in the trace
def test_the_learned_table_is_in_the_trace_and_loads_from_it(plant, tmp_path):
    loop = MapeK(plant, learned=OutcomeTable())
    res = simulate(plant, "level_b_drift", seed=1, adapt=loop)
    known = res.meta["knowledge"]
    assert known["learned"] == loop.learning.table.to_dict()
    assert known["outcomes"][0]["action"] == "use_transmitter_b"
    for name in ("run.json", "run.parquet"):
        res.write_trace(tmp_path / name)
        table = load_table(tmp_path / name)
        assert table.to_dict() == loop.learning.table.to_dict()
    out = CliRunner().invoke(app, ["simulate", str(PLANT), "-s", "level_b_drift", "--json",
                                   "--knowledge", str(tmp_path / "run.parquet")])
    assert out.exit_code == 0, out.output
    assert json.loads(out.output)["runs"][0]["switches"] == []
    plain = simulate(plant, "nominal", seed=1, adapt=MapeK(plant))
    plain.write_trace(tmp_path / "plain.json")
    with pytest.raises(ArchselfError, match=r"plain\.json: meta\.knowledge\.learned: expected"):
        load_table(tmp_path / "plain.json")


# ---------------------------------------------------------------- D: tactics reviewed
def test_a_tactic_that_failed_here_is_held_back_like_a_single_action():
    arch = make_arch(learning={"enabled": True, "hold_s": 100.0, "settle_s": 2.0})
    arch.strategies = {"actuator": Strategy.model_validate({
        "module": "act", "start": "tune",
        "steps": {
            "tune": {"tactic": "tune", "settle_s": 2.0, "success": "done", "failure": "switch"},
            "switch": {"tactic": "swap_ctl", "settle_s": 1.0, "success": "done",
                       "failure": "done"},
        },
    })}
    signals = lambda t, c: {"act": {"cmd_err": 1.0}}  # noqa: E731 - act is a candidate

    def run(table: OutcomeTable) -> tuple[MapeK, FakeSystem]:
        loop = MapeK(arch, learned=table)
        system = FakeSystem(arch, signals, linearizations={
            "base": [[-1.0, 0.0], [0.0, -2.0]], "alt_ctl": [[-1.0, 0.0], [0.0, -2.0]]})
        run_loop(loop, system, 4.0)
        return loop, system

    loop, system = run(OutcomeTable())  # nothing learned: the first tactic runs
    assert system.param_log == [(1.0, "ctl_a", {"gain": 2.0})]
    # its outcome is measured in the context the review asks: (tactic, its module, conf)
    (ev,) = [e for e in loop.learning.events if e["action"] == "tune"]
    assert (ev["module"], ev["configuration"], ev["outcome"]) == ("ctl_a", "base", "success")
    failed = OutcomeTable()
    failed.add("tune", "ctl_a", "base", -0.5, ok=False)
    loop, system = run(failed)
    assert system.param_log == [] and system.applied == [(1.0, "alt_ctl")]
    (held,) = [e for e in loop.decisions[0].evaluations if e.action == "tune"]
    assert held.rejected == "held back" and held.learned["trials"] == 1
    assert "tune not admissible (held back) → switch" in loop.decisions[0].note


# ---------------------------------------------------------------- validate and the CLI
def test_validate_says_when_online_cannot_update():
    loaded = load_architecture(PLANT)
    loaded.arch.runtime.online = Online.model_validate(
        {"weights": {"enabled": True}, "bands": {"enabled": True}})
    found = [f for f in check(loaded) if f.code == "online"]
    assert [(f.severity, f.path) for f in found] == [
        ("warning", "runtime.online.weights.enabled")]
    assert "on a cycle" in found[0].message
    loaded.arch.runtime.online = Online.model_validate({})
    assert not [f for f in check(loaded) if f.code == "online"]


def test_cli_online_switches_both_updates_on(tmp_path):
    trace = tmp_path / "t.json"
    out = CliRunner().invoke(app, ["simulate", str(PLANT), "-s", "nominal", "--online",
                                   "--trace", str(trace)])
    assert out.exit_code == 0, out.output
    meta = json.loads(trace.read_text())["meta"]
    events = meta["knowledge"]["online"]["events"]
    assert {e["kind"] for e in events} == {"weights", "bands"}
    assert all(e["outcome"] == "rejected" for e in events if e["kind"] == "weights")
    assert "learned" not in meta["knowledge"]
    shown = CliRunner().invoke(app, ["explain", str(trace)])
    assert shown.exit_code == 0 and "online W:" in shown.output
    taken = sum(e["outcome"] == "accepted" for e in events)
    assert f"online: {taken} of {len(events)} update(s) accepted" in shown.output
