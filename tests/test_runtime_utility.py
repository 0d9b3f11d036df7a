"""Quality attributes and preferences (issue 35, point 2): U(C) ranks the configurations
that hold the same remedy; a preference change changes the chosen configuration."""

from __future__ import annotations

import pytest
from numpy.testing import assert_allclose

from archself import load
from archself.check import check
from archself.model.loader import load_text
from archself.resources import data_dir
from archself.runtime import MapeK, explain
from archself.runtime.planner import Utility
from archself.sim.run import simulate

ROBOT = data_dir("architectures") / "diffdrive.yaml"


@pytest.fixture(scope="module")
def robot():
    return load(ROBOT)


def test_utility_of_a_configuration_is_the_weighted_sum_of_its_curves(robot):
    u = Utility(robot)
    a3, a4 = u.of("a3"), u.of("a4")
    # energy = Σ power_w: a3 has the EKF (1.5 W), a4 odometry (0.5 W); curve 1 at 30 W, 0 at 33
    assert_allclose([a3["attributes"]["energy"]["value"], a4["attributes"]["energy"]["value"]],
                    [32.1, 31.1], rtol=1e-12)
    assert_allclose(a3["attributes"]["energy"]["utility"], (33 - 32.1) / 3, rtol=1e-9)
    assert_allclose(a3["U"], 0.6 * 1.0 + 0.4 * 0.3, rtol=1e-9)
    assert_allclose(a4["U"], 0.6 * 0.0 + 0.4 * (33 - 31.1) / 3, rtol=1e-9)
    assert_allclose(u.bonus("a4", "a3"), a4["U"] - a3["U"], rtol=1e-12)
    assert u.bonus("a3", "a3") == 0.0


def _short_actuator_fault(arch):
    arch.scenarios["actuator_fault"].duration_s = 25.0  # wheel −20 % from 20 s
    loop = MapeK(arch)
    run = simulate(arch, "actuator_fault", adapt=loop)
    return run, explain(loop.decisions)


def test_a_preference_change_changes_the_chosen_configuration(robot):
    run, text = _short_actuator_fault(robot.model_copy(deep=True))
    assert [(s["to"], s["action"]) for s in run.switches] == [("a3", "compensate_left_wheel")]
    assert "compensate_left_wheel@a4 (substitute on wheel_left → a4)" in text
    assert "U=0.720 (energy 32.1 → 0.30, accuracy 0.2 → 1.00)" in text

    energy_first = robot.model_copy(deep=True)
    energy_first.qualities.preferences = {"energy": 0.9, "accuracy": 0.1}
    run, text = _short_actuator_fault(energy_first)
    assert [(s["to"], s["action"]) for s in run.switches] == [("a4", "compensate_left_wheel@a4")]
    assert "U=0.570 (energy 31.1 → 0.63, accuracy 1 → 0.00)" in text
    assert "⇒ switched a1 → a4 by compensate_left_wheel@a4" in text


BAD_QUALITIES = [
    ("a4: 1.0}", "a4: 1.0, a5: 0.2}",
     "qualities.attributes.accuracy.values.a5: unknown configuration 'a5'"),
    ("preferences: {accuracy", "preferences: {acuracy",
     "qualities: preferences name unknown attribute(s): acuracy"),
    ("[[0.2, 1.0], [1.0, 0.0]]", "[[1.0, 1.0], [0.2, 0.0]]",
     "the utility points' values must increase"),
]


@pytest.mark.parametrize(("old", "new", "message"), BAD_QUALITIES)
def test_bad_qualities_are_located_errors(old, new, message):
    from archself.model.loader import SchemaError

    text = ROBOT.read_text()
    assert text.count(old) == 1
    try:
        findings = check(load_text(text.replace(old, new), "robot.yaml"))
    except SchemaError as exc:
        findings = exc.findings
    errors = [f for f in findings if f.severity == "error"]
    assert any(message in f"{f.path}: {f.message}" for f in errors), errors
    assert all(f.line for f in errors)  # file:line:col
