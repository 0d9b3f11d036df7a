"""Strategies (issue 35, point 1): trees of tactics with settle times, post-checks and
branches, run one tactic per cycle by the MAPE-K loop; validated with located errors."""

from __future__ import annotations

import pytest
from test_runtime_fakes import FakeSystem, high, make_arch, run_loop

from archself.check import check
from archself.model.architecture import Strategy
from archself.model.loader import load_text
from archself.resources import data_dir
from archself.runtime import MapeK, explain

LIN = {"base": [[-1.0, 0.0], [0.0, -2.0]], "alt_ctl": [[-1.0, 0.0], [0.0, -2.0]]}


def _with_strategy(switch_post):
    arch = make_arch()
    arch.strategies = {
        "actuator": Strategy.model_validate({
            "module": "act",
            "start": "tune",
            "steps": {
                # a cheap parameter update first; J = |x| ≈ e^{−t/2} never gets below 1e-9
                "tune": {"tactic": "tune", "settle_s": 2.0, "post": {"objective_below": 1e-9},
                         "success": "done", "failure": "switch"},
                "switch": {"tactic": "swap_ctl", "settle_s": 1.0, "post": switch_post,
                           "success": "done", "failure": "rollback"},
            },
        })
    }
    loop = MapeK(arch)
    system = FakeSystem(arch, high("act", "cmd_err"), linearizations=LIN)
    switches = run_loop(loop, system, 6.0)
    return loop, system, switches


def test_a_failed_post_check_takes_the_fallback_branch():
    loop, system, switches = _with_strategy({"configuration": ["alt_ctl"]})
    # t = 1 s: act is a candidate, the strategy starts and executes its first tactic
    assert system.param_log == [(1.0, "ctl_a", {"gain": 2.0})]
    # t = 3 s: settled 2 s, post-check fails (J ≈ 0.22) → the fallback step's tactic
    assert [(s["t_s"], s["from"], s["to"], s["action"]) for s in switches] == [
        (3.0, "base", "alt_ctl", "swap_ctl")
    ]
    notes = {d.t: d.note for d in loop.decisions if d.note}
    assert notes[1.0] == "strategy actuator, step tune: executes tune"
    assert notes[2.0] == "strategy actuator, step tune: settling (1 of 2 s)"
    assert notes[3.0] == ("strategy actuator, step tune: post-check FAILED → switch; "
                          "strategy actuator, step switch: executes swap_ctl")
    assert notes[4.0] == "strategy actuator, step switch: post-check passed → done"
    assert loop.strategies.running is None
    text = explain(loop.decisions)
    assert "note: strategy actuator, step tune: post-check FAILED → switch" in text


def test_a_failed_last_post_check_rolls_back():
    loop, system, switches = _with_strategy({"objective_below": 1e-9})
    assert [(s["t_s"], s["to"], s["action"]) for s in switches] == [
        (3.0, "alt_ctl", "swap_ctl"), (4.0, "base", "actuator:rollback")
    ]
    assert "strategy actuator: rollback to base" in loop.decisions[3].note


BAD = """
strategies:
  recover:
    module: wheel_left
    start: first
    steps:
      first: {tactic: compensate_left_whel, success: loop, failure: done}
      loop: {tactic: stiffen_lateral_gain, success: loop, failure: loop}
      orphan: {tactic: stiffen_lateral_gain, failure: nowhere}
"""


def test_strategies_are_validated_with_located_errors():
    text = (data_dir("architectures") / "diffdrive.yaml").read_text()
    assert text.count("\nstrategies:\n") == 1  # the shipped one, then these
    text = text.replace("\nstrategies:\n", BAD, 1)
    found = [(f.path, f.message) for f in check(load_text(text, "robot.yaml"))
             if f.severity == "error" and f.line]
    assert ("strategies.recover.steps.first.tactic",
            "unknown tactic 'compensate_left_whel' (not an action id); "
            "did you mean 'compensate_left_wheel'?") in found
    assert ("strategies.recover.steps.loop",
            "step 'loop' is on a cycle without exit: no branch leads to 'done' or "
            "'rollback'") in found
    assert ("strategies.recover.steps.orphan",
            "step 'orphan' is unreachable from start 'first'") in found
    assert any(p == "strategies.recover.steps.orphan.failure" and "unknown step 'nowhere'" in m
               for p, m in found)


def test_a_condition_needs_a_part():
    with pytest.raises(ValueError, match="a condition needs at least one"):
        Strategy.model_validate({"module": "m", "start": "a",
                                 "steps": {"a": {"tactic": "t", "post": {}}}})


def _dropout_run(arch, duration_s):
    from archself.sim.run import simulate

    arch.scenarios["drift_then_dropout"].duration_s = duration_s
    loop = MapeK(arch)
    run = simulate(arch, "drift_then_dropout", adapt=loop)
    notes = {d.t: d.note for d in loop.decisions if d.note}
    return run, loop, notes


@pytest.mark.slow
def test_the_shipped_strategy_returns_to_the_ekf_when_the_gps_is_back():
    """diffdrive's gps_outage: IMU drift puts the robot on a2; GPS out 90–120 s: dead
    reckoning (tactic 1), post-check on a1, then back to the EKF as soon as the GPS is
    back (tactic 2) instead of when the odometry's drift test finds the drift again."""
    from archself import load

    run, loop, notes = _dropout_run(load(data_dir("architectures") / "diffdrive.yaml"), 125.0)
    got = [(s["from"], s["to"], s["action"]) for s in run.switches]
    assert got == [("a1", "a2", "use_ekf_gps"), ("a2", "a1", "fallback_odometry"),
                   ("a1", "a2", "use_ekf_gps")]
    assert 90.0 < run.switches[1]["t_s"] <= 95.0 and 120.0 < run.switches[2]["t_s"] <= 122.0
    t1 = run.switches[1]["t_s"]
    assert notes[t1] == "strategy gps_outage, step dead_reckon: executes fallback_odometry"
    assert notes[t1 + 1.0].startswith("strategy gps_outage, step dead_reckon: post-check "
                                      "passed → back_to_ekf; strategy gps_outage, step "
                                      "back_to_ekf: waiting for use_ekf_gps (unavailable")
    assert notes[run.switches[2]["t_s"]] == ("strategy gps_outage, step back_to_ekf: "
                                             "executes use_ekf_gps")
    assert loop.strategies.running is None  # done


@pytest.mark.slow
def test_a_failed_post_check_on_the_robot_takes_the_failure_branch():
    """The same strategy with a post-check that cannot pass (J below 0.1 mm) and a
    failure branch to a parameter update: the branch's tactic runs after the check."""
    from archself import load

    arch = load(data_dir("architectures") / "diffdrive.yaml")
    st = arch.strategies["gps_outage"]
    st.steps["dead_reckon"].post = Strategy.model_validate({
        "module": "gps", "start": "x", "steps": {"x": {"tactic": "t", "post": {
            "objective_below": 1e-4}}}}).steps["x"].post
    st.steps["dead_reckon"].failure = "stiffen"
    st.steps["stiffen"] = type(st.steps["dead_reckon"]).model_validate(
        {"tactic": "stiffen_lateral_gain", "success": "done", "failure": "done"})
    run, loop, notes = _dropout_run(arch, 96.0)
    t1 = run.switches[1]["t_s"]
    assert run.switches[1]["action"] == "fallback_odometry"
    assert notes[t1 + 1.0] == ("strategy gps_outage, step dead_reckon: post-check FAILED → "
                               "stiffen; strategy gps_outage, step stiffen: executes "
                               "stiffen_lateral_gain")
    chosen = [d.chosen for d in loop.decisions if d.t == t1 + 1.0]
    assert chosen[0]["action"] == "stiffen_lateral_gain"
    assert notes[t1 + 1.5] == "strategy gps_outage, step stiffen: post-check passed → done"
    assert loop.strategies.running is None
