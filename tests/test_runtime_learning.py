"""Issue 36: decisions that learn from outcomes (runtime.learning) and know their spread.

runtime.learning (archself/runtime/knowledge.py) and runtime.risk (archself/runtime/planner.py).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose
from typer.testing import CliRunner

from archself.cli import app
from archself.errors import ArchselfError
from archself.model.architecture import Architecture
from archself.model.architecture import Learning as LearningSettings
from archself.model.loader import load_architecture
from archself.resources import data_dir
from archself.runtime import MapeK
from archself.runtime import planner as risk_module
from archself.runtime.knowledge import Learning, OutcomeTable, load_table
from archself.runtime.planner import risk_value
from archself.sim.run import simulate

PLANT = data_dir("architectures") / "process_plant.yaml"


@pytest.fixture(scope="module")
def plant() -> Architecture:
    return load_architecture(PLANT).arch


def _actions(loop: MapeK) -> list[str]:
    return [d.chosen["action"] for d in loop.decisions if d.chosen]


# ---------------------------------------------------------------- A: learning from outcomes
def test_off_by_default_changes_nothing(plant):
    loop = MapeK(plant)
    assert loop.learning is None and loop.knowledge.learned is None
    simulate(plant, "valve_loss", seed=1, adapt=loop)
    evs = [e.to_dict() for d in loop.decisions for e in d.evaluations]
    assert evs and not any({"learned", "spread", "mean", "draws", "rule"} & e.keys() for e in evs)


def test_failed_action_is_measured_held_back_and_remembered(plant):
    """level_b_drift: the first-ranked action (hand over to B) fails; learned, not repeated."""
    off = MapeK(plant)
    simulate(plant, "level_b_drift", seed=2, adapt=off)
    assert _actions(off)[:3] == ["use_transmitter_b", "use_transmitter_a", "use_transmitter_b"]

    first = MapeK(plant, learned=OutcomeTable())
    res1 = simulate(plant, "level_b_drift", seed=2, adapt=first)
    # tried once, measured as a failure, the right action within one more decision
    assert _actions(first)[:2] == ["use_transmitter_b", "use_transmitter_a"]
    assert "use_transmitter_b" not in _actions(first)[2:]
    ev = first.learning.events[0]
    assert (ev["action"], ev["configuration"], ev["outcome"]) == ("use_transmitter_b", "p1",
                                                                 "failure")
    assert ev["j_after"] > ev["j_before"] and ev["realized"] < 0
    held = [e for d in first.decisions for e in d.evaluations if e.rejected == "held back"]
    assert held and held[0].learned["trials"] == 1 and held[0].learned["successes"] == 0

    saved = OutcomeTable.from_dict(json.loads(json.dumps(first.learning.table.to_dict())))
    nxt = MapeK(plant, learned=saved)
    res2 = simulate(plant, "level_b_drift", seed=2, adapt=nxt)
    assert res2.switches == []  # the right action (stay on A) first
    assert res2.metrics["max_error"] < res1.metrics["max_error"]
    off_res = simulate(plant, "level_b_drift", seed=2, adapt=MapeK(plant))
    assert res1.metrics["max_error"] < 0.2 * off_res.metrics["max_error"]


def test_outcome_measurement_and_hold():
    s = LearningSettings(enabled=True, settle_s=10.0, hold_s=50.0)
    learn = Learning(s)

    class A:
        id, module = "act", "m"

    for t in range(0, 11):
        learn.observe(float(t), 1.0 + 0.01 * (t % 2), "c1")
    learn.started(A, "c1", "c2", 10.0, 0.5)
    events = []
    for t in range(11, 21):
        events += learn.observe(float(t), 2.0, "c2")
    assert len(events) == 1 and events[0]["outcome"] == "failure"
    assert_allclose(events[0]["realized"], -0.995, atol=0.01)
    factor, held, info = learn.review("act", "m", "c1", 30.0)
    assert held and factor == pytest.approx(0.5) and info["held_until"] == pytest.approx(70.0)
    assert learn.review("act", "m", "c1", 71.0)[1] == ""
    assert learn.review("act", "m", "c2", 30.0) == (1.0, "", None)  # another context


def test_rollback_is_a_failure():
    learn = Learning(LearningSettings(enabled=True, settle_s=10.0))

    class A:
        id, module = "act", "m"

    for t in range(0, 6):
        learn.observe(float(t), 1.0, "c1")
    learn.started(A, "c1", "c2", 5.0, None)
    learn.observe(6.0, 0.5, "c2")
    (ev,) = learn.observe(7.0, 0.5, "c1")
    assert ev["outcome"] == "failure" and ev["detail"] == "rolled back"


def test_bad_knowledge_tables_are_one_line_errors(tmp_path):
    with pytest.raises(ArchselfError, match="format: archself-knowledge/1"):
        OutcomeTable.from_dict({"format": "other"})
    bad = {"format": "archself-knowledge/1", "entries": [
        {"action": "a", "module": "m", "configuration": "c", "trials": 1, "successes": 2,
         "realized": 0.0, "last": "success"}]}
    with pytest.raises(ArchselfError, match=r"entries\.0: expected"):
        OutcomeTable.from_dict(bad)
    f = tmp_path / "k.json"
    f.write_text('{"format": ')
    with pytest.raises(ArchselfError, match=r"k\.json:1:\d+: not a knowledge table"):
        load_table(f)


def test_cli_saves_and_loads_knowledge(tmp_path):
    k1 = tmp_path / "k1.json"
    args = ["simulate", str(PLANT), "-s", "level_b_drift", "--json"]
    r1 = CliRunner().invoke(app, [*args, "--save-knowledge", str(k1)])
    assert r1.exit_code == 0, r1.output
    table = load_table(k1)
    entry = table.get("use_transmitter_b", "observer_a", "p1")
    assert entry is not None and entry.last == "failure" and entry.realized < 0
    r2 = CliRunner().invoke(app, [*args, "--knowledge", str(k1)])
    assert r2.exit_code == 0, r2.output
    assert json.loads(r2.output)["runs"][0]["switches"] == []
    same = CliRunner().invoke(app, [*args, "--knowledge", str(k1), "--save-knowledge", str(k1)])
    assert same.exit_code == 1 and "refusing to write over it" in same.output
    fixed = CliRunner().invoke(app, [*args, "--fixed", "--knowledge", str(k1)])
    assert fixed.exit_code == 2


# ---------------------------------------------------------------- B: Δ with its spread
def test_risk_rules():
    d = np.array([-1.0, 3.0, -1.0, 3.0])
    assert risk_value(d, "mean") == pytest.approx(1.0)
    assert risk_value(d, "mean_std", kappa=0.5) == pytest.approx(0.0)
    assert risk_value(d, "cvar", alpha=0.25) == pytest.approx(-1.0)
    assert risk_value(np.arange(8.0), "cvar", alpha=0.5) == pytest.approx(1.5)


def _two_rollout_actions(plant: Architecture, rule: str, draws: int = 4) -> Architecture:
    data = plant.model_dump(by_alias=True, exclude_none=True)
    rollout = {"method": "rollout", "horizon_s": 4.0}
    risky = {"id": "risky_to_p4", "module": "valve", "kind": "substitute", "to": "p4",
             "applies_in": ["p1"], "cost": 0.3, "improvement": rollout}
    safe = {"id": "safe_to_p3", "module": "valve", "kind": "substitute", "to": "p3",
            "applies_in": ["p1"], "cost": 0.3, "improvement": rollout}
    data["actions"] = [risky, safe]  # equal cost: a tie goes to the first declared
    data["runtime"]["risk"] = {"draws": draws, "rule": rule, "kappa": 1.0}
    data["scenarios"]["valve_loss"]["duration_s"] = 160.0  # the fault at 150 s: a few cycles
    return Architecture.model_validate(data)


def test_risk_averse_ranking_changes_the_decision(plant, monkeypatch):
    """Equal mean Δ, different spreads: mean takes the first declared, mean − κ·std the safe."""
    draws = {"p4": np.array([-1.0, 3.0, -1.0, 3.0]), "p3": np.full(4, 1.0)}
    monkeypatch.setattr(risk_module, "sampled_rollouts",
                        lambda system, action, horizon, k: (draws[action.to], 3))
    chosen = {}
    for rule in ("mean", "mean_std"):
        loop = MapeK(_two_rollout_actions(plant, rule))
        simulate(plant, "valve_loss", seed=1, adapt=loop)
        rec = next(d for d in loop.decisions if d.chosen)
        chosen[rule] = rec.chosen["action"]
        logged = {e.action: e.to_dict() for e in rec.evaluations}
        assert_allclose([logged[a]["mean"] for a in ("risky_to_p4", "safe_to_p3")], [1.0, 1.0])
        assert_allclose(logged["risky_to_p4"]["spread"], 2.0)
        assert logged["safe_to_p3"]["spread"] == 0.0
        assert logged["risky_to_p4"]["rule"].startswith("mean")
    assert chosen == {"mean": "risky_to_p4", "mean_std": "safe_to_p3"}


def test_sampled_rollouts_spread_and_determinism(plant):
    arch = _two_rollout_actions(plant, "mean", draws=3)
    runs = []
    for _ in range(2):
        loop = MapeK(arch)
        simulate(arch, "valve_loss", seed=1, adapt=loop)
        runs.append([(e.mean, e.spread) for d in loop.decisions for e in d.evaluations
                     if e.spread is not None][:4])
    assert runs[0] == runs[1] and runs[0]  # same seed, same draws
    assert all(spread > 0 for _, spread in runs[0])  # the draws differ: the noise was resampled


@pytest.mark.parametrize(("risk", "rollout", "expected"), [
    ({"draws": 4}, False, "runtime.risk.draws: draws 4: no action estimates its improvement "
                          "by rollout"),
    ({"draws": 1, "rule": "cvar"}, True, "runtime.risk.rule: rule cvar over one draw"),
    ({"draws": 4, "rule": "cvar"}, True, None),
    ({}, False, None),
])
def test_validate_warns_of_a_risk_setting_that_changes_nothing(plant, risk, rollout, expected):
    """`runtime.risk` with draws but no rollout estimate, or a rule over one draw, cannot
    change a decision: validate says so (a warning at the setting), and is quiet when the
    setting can act."""
    from archself.check import check
    from archself.model.loader import load_text

    data = plant.model_dump(mode="json", by_alias=True, exclude_none=True)
    data["runtime"]["risk"] = risk
    if rollout:
        data["actions"][0]["improvement"] = {"method": "rollout", "horizon_s": 4.0}
    else:
        for a in data["actions"]:
            if a["improvement"]["method"] == "rollout":
                a["improvement"] = {"method": "table", "value": 1.0}
    found = [f"{f.path}: {f.message}" for f in check(load_text(json.dumps(data), "t.json"))
             if f.path.startswith("runtime.risk")]
    if expected is None:
        assert found == []
    else:
        assert len(found) == 1 and found[0].startswith(expected), found
