"""Paths to a configuration (issue 35, point 3): detours around an unavailable target."""

from __future__ import annotations

import pytest

from archself import load
from archself.resources import data_dir
from archself.runtime import MapeK, explain
from archself.runtime.planner import Detours
from archself.sim.run import simulate


@pytest.fixture(scope="module")
def robot():
    return load(data_dir("architectures") / "diffdrive.yaml")


def _action(arch, action_id):
    return next(a for a in arch.actions if a.id == action_id)


def _ekf_needs_gps(configuration):
    return {"ekf": {"gps", "encoders", "imu"}, "asym_lqr": {"planner", "encoders"}}


def test_a_detour_keeps_the_part_of_the_target_that_can_run(robot):
    found = Detours(robot).find(
        _action(robot, "compensate_left_wheel"), "a1", {"gps"}, _ekf_needs_gps
    )
    # a3 = EKF + asymmetric LQR; the EKF needs the dead GPS, a4 keeps the asymmetric LQR
    assert [(d.id, d.to, d.applies_in, d.module) for d in found] == [
        ("compensate_left_wheel@a4", "a4", None, "wheel_left")
    ]
    assert found[0].cost == _action(robot, "compensate_left_wheel").cost


def test_no_detour_when_nothing_of_the_remedy_can_run(robot):
    # a1 -> a2 brings the EKF and lqr_fused; no other configuration has lqr_fused without the EKF
    assert Detours(robot).find(_action(robot, "use_ekf_gps"), "a1", {"gps"}, _ekf_needs_gps) == []
    # without a dependency map only the down module itself is dead: a down EKF leaves
    # lqr_fused, which no configuration but a2 holds
    found = Detours(robot).find(_action(robot, "use_ekf_gps"), "a1", {"ekf"}, lambda c: None)
    assert found == []


def test_detours_can_be_switched_off(robot):
    arch = robot.model_copy(deep=True)
    arch.runtime.ablation.paths = False
    assert Detours(arch).find(
        _action(arch, "compensate_left_wheel"), "a1", {"gps"}, _ekf_needs_gps
    ) == []


def test_wheel_loss_during_a_gps_dropout_takes_the_detour(robot):
    loop = MapeK(robot)
    run = simulate(robot, "wheel_during_dropout", adapt=loop)
    assert [(s["from"], s["to"], s["action"]) for s in run.switches] == [
        ("a1", "a4", "compensate_left_wheel@a4")
    ]
    # the wheel fails at 80 s; the first cycle whose residual shows it acts
    assert 80.0 < run.switches[0]["t_s"] <= 82.0
    # 0.28 m with seed 1 (20 seeds: worst 0.40 m); 3.2 m without the detour
    assert run.metrics["max_error"] < 1.0
    text = explain(loop.decisions)
    assert ("compensate_left_wheel (substitute on wheel_left → a3)  "
            "rejected (unavailable: gps") in text
    assert "compensate_left_wheel@a4 (substitute on wheel_left → a4)" in text


def test_an_unstable_target_gives_way_to_a_stable_configuration_holding_the_remedy():
    """The declared target fails the stability filter: the planner evaluates the other
    configurations that hold the action's remedy (same checks) and takes a stable one."""
    from test_runtime_fakes import FakeSystem, high, make_arch, run_loop

    from archself.model.architecture import Configuration

    stable, unstable = [[-1.0, 0.0], [0.0, -2.0]], [[0.5, 0.0], [0.0, -2.0]]
    arch = make_arch()
    # alt_ctl (declared target of swap_ctl, act's remedy ctl_b) is unstable here;
    # alt_ctl_m holds the same remedy and what alt_ctl keeps of base, and is stable
    arch.configurations["alt_ctl_m"] = Configuration(modules=["src", "est_a", "ctl_b", "act",
                                                              "model"])
    lin = {"base": stable, "alt_est": stable, "alt_ctl": unstable, "alt_ctl_m": stable,
           "bad": unstable, "heavy": stable}
    loop = MapeK(arch)
    switches = run_loop(loop, FakeSystem(arch, high("act", "cmd_err"), linearizations=lin), 2.0)
    assert [(s["t_s"], s["to"], s["action"]) for s in switches] == [
        (1.0, "alt_ctl_m", "swap_ctl@alt_ctl_m")]
    evs = {e.action: e for e in loop.decisions[0].evaluations}
    assert evs["swap_ctl"].rejected == "unstable"
    assert evs["swap_ctl@alt_ctl_m"].rejected is None
    # with paths off the unstable target leaves the fault alone
    arch.runtime.ablation.paths = False
    loop = MapeK(arch)
    assert run_loop(loop, FakeSystem(arch, high("act", "cmd_err"), linearizations=lin),
                    2.0) == []
