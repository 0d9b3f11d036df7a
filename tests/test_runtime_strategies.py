"""Strategies (issue 35, point 1): trees of tactics with settle times, post-checks and
branches, run one tactic per cycle by the MAPE-K loop; validated with located errors."""

from __future__ import annotations

import pytest
from test_runtime_fakes import FakeSystem, high, make_arch, run_loop

from archself.check import check
from archself.model.loader import load_text
from archself.model.strategies import Strategy
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
    text = (data_dir("architectures") / "diffdrive.yaml").read_text() + BAD
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
