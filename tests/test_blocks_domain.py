"""A new domain in YAML alone (issue 40): the expression block, sensor silence, actuator units.

The thermal zone of docs/blocks.md (``architectures/thermal_zone.yaml``: two heaters, a
damper loss term damper × (T − T_out) as a ``generic.expression``, two sensors with
``max_silence_s``, an observer each, a PI) adapts right on a heater fault and on a
sensor dropout, and its lanes equal its per-run runs.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from numpy.testing import assert_allclose
from typer.testing import CliRunner

from archself.cli import app
from archself.model.loader import load_text
from archself.resources import data_dir
from archself.runtime import MapeK
from archself.sim.run import simulate
from archself.system.live import FaultInjector
from archself.testing import check_pack
from archself_blocks.actuators import Actuator
from archself_blocks.signals import Expression, parse_expression

ZONE = data_dir("architectures") / "thermal_zone.yaml"


def rng():
    return np.random.default_rng(0)


# --------------------------------------------------------------------------- expression
def test_expression_computes_every_allowed_operation_by_hand() -> None:
    f, names = parse_expression("-a + b ** 2 / 4 - abs(c) * exp(0) + log(1) + sqrt(b) "
                                "+ min(a, b, c) + max(a, 0) + clip(c, -1, 1)")
    assert names == ("a", "b", "c")
    env = {"a": np.array([2.0]), "b": np.array([4.0]), "c": np.array([-3.0])}
    want = -2.0 + 16.0 / 4 - 3.0 + 0.0 + 2.0 + (-3.0) + 2.0 + (-1.0)
    assert_allclose(f(env), [want], rtol=1e-15)


def test_expression_of_components_and_of_a_missing_input() -> None:
    e = Expression("loss", {"expression": "-(0.2 + 0.3 * d[0]) * (T[0] - out[0])"}, rng())
    got = e.step(0.0, 0.1, {"d": np.array([0.5, 0.0]), "T": [20.0], "out": np.array([5.0, 0.0])})
    assert got["u"] == pytest.approx(-(0.2 + 0.15) * 15.0, rel=1e-15)
    assert set(got) >= {"u", "measurement", "signal"}
    assert e.step(0.0, 0.1, {"d": 0.5, "T": [20.0]})["u"] is None  # no out: no output
    placed = Expression("loss", {"expression": "2 * x", "width": 3, "channel": 2}, rng())
    assert_allclose(placed.step(0.0, 0.1, {"x": 1.5})["u"], [0.0, 0.0, 3.0])


@pytest.mark.parametrize(("text", "said"), [
    ("__import__('os').system('true')", "column 1: '__import__('os').system' is no allowed"),
    ("a.real", "'a.real' (Attribute) is not allowed"),
    ("a if a else 1", "(IfExp) is not allowed"),
    ("a < 1", "(Compare) is not allowed"),
    ("a + 'x'", "column 5: 'x' is not a number"),
    ("a[-1]", "only an input's component name[k]"),
    ("a[b]", "only an input's component name[k]"),
    ("sqrt(a, 2)", "sqrt() takes 1 arguments, not 2"),
    ("exp + 1", "'exp' is a function, not an input"),
    ("lambda: 1", "(Lambda) is not allowed"),
    ("(", "not an arithmetic expression"),
    ("2 * 3", "names no input"),
])
def test_expression_refuses_what_is_not_arithmetic(text, said) -> None:
    with pytest.raises(ValueError, match="^expression: ") as err:
        parse_expression(text)
    assert said in str(err.value)


def test_expression_jacobian_is_the_analytic_one() -> None:
    from archself.modules.base import Port

    e = Expression("e", {"expression": "a * exp(b[1]) - a ** 2"}, rng())
    e.step(0.0, 0.1, {"a": 3.0, "b": np.array([0.0, 0.5])})
    model = e.linear_model(0.1, {"a": [Port("src", 1)], "b": [Port("src", 2)]})
    d_a, d_b1 = np.exp(0.5) - 2 * 3.0, 3.0 * np.exp(0.5)
    assert_allclose(model.D[0], [d_a, 0.0, d_b1], rtol=1e-6, atol=1e-9)


def test_validate_locates_a_bad_expression_at_its_parameter(tmp_path) -> None:
    text = ZONE.read_text(encoding="utf-8").replace(
        '"-(0.2 + 0.3 * damper[0]) * (T[0] - T_out[0])"', '"open(T)"')
    bad = tmp_path / "zone.yaml"
    bad.write_text(text, encoding="utf-8")
    line = next(i for i, ln in enumerate(text.splitlines(), 1) if "open(T)" in ln)
    result = CliRunner().invoke(app, ["validate", str(bad)])
    assert result.exit_code == 1
    assert re.search(rf"zone\.yaml:{line}:\d+: error: .*'envelope'.*'open' is no allowed "
                     r"function call", result.output), result.output
    assert "Traceback" not in result.output


# --------------------------------------------------------------------------- actuator units
def test_actuator_command_error_is_in_the_output_units_with_a_scale() -> None:
    fault = FaultInjector("effectiveness_loss", onset_s=1.0, magnitude=0.6)
    a = Actuator("heater", {"scale": 0.1}, rng())  # % in, kW out
    errors = []
    delivered = None
    for k in range(30):
        t = 0.1 * k
        a.step(t, 0.1, {"command": 50.0, "measurement": delivered})
        delivered = fault.apply(t, a.x)
        errors.append(a.signals["command_error"])
    assert a.x == pytest.approx(5.0)  # 50 % of 10 kW
    assert errors[5] == pytest.approx(0.0, abs=1e-12)  # healthy: meter = command, in kW
    assert errors[-1] == pytest.approx(0.6 * 5.0, rel=1e-12)  # 60 % of 5 kW lost


# --------------------------------------------------------------------------- the zone
@pytest.fixture(scope="module")
def zone():
    return load_text(ZONE.read_text(encoding="utf-8"), str(ZONE)).arch


@pytest.mark.parametrize(("scenario", "switch", "to"), [
    ("nominal", None, "z1"),
    ("heater_loss", "use_heater_b", "z3"),
    ("sensor_dropout", "drop_sensor_a", "z2"),
])
def test_thermal_zone_adapts_right(zone, scenario, switch, to) -> None:
    fixed = simulate(zone, scenario)
    adaptive = simulate(zone, scenario, adapt=MapeK(zone))
    assert adaptive.final_configuration == to
    assert [s["action"] for s in adaptive.switches] == ([switch] if switch else [])
    if switch:
        assert 100.0 < adaptive.switches[0]["t_s"] <= 105.0  # within 5 s of the onset
        assert fixed.metrics["max_error"] > 2.0  # the fault matters to the fixed zone
    assert adaptive.metrics["max_error"] < 1.0  # a 2 K setpoint step, the damper opened
    assert adaptive.metrics["final_error"] < 0.1


def test_without_max_silence_a_dropout_goes_unseen(zone) -> None:
    deaf = zone.model_copy(deep=True)
    del deaf.modules["sensor_a"].params["max_silence_s"]
    run = simulate(deaf, "sensor_dropout", adapt=MapeK(deaf))
    assert run.switches == [] and run.metrics["final_error"] > 1.0


def test_thermal_zone_lanes_are_its_per_run_runs() -> None:
    report = check_pack(ZONE, scenarios=["heater_loss", "sensor_dropout"], seeds=(1, 2),
                        duration_s=120.0)
    assert report.ok, report.problems
    assert report.types["generic.expression"] == "ExpressionLanes"


def test_validate_warns_of_a_unit_conversion_given_as_gain(tmp_path) -> None:
    text = ZONE.read_text(encoding="utf-8").replace(
        "      scale: {value: 0.1, unit: kW/%}\n      gain: {value: 1.0, min: 0.5, max: 2.0}",
        "      gain: {value: 0.1, min: 0.05, max: 2.0}", 1)
    path = tmp_path / "zone.yaml"
    path.write_text(text, encoding="utf-8")
    line = text.splitlines().index("      gain: {value: 0.1, min: 0.05, max: 2.0}") + 1
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 0
    assert re.search(rf"zone\.yaml:{line}:\d+: warning: modules\.heater_a\.params\.gain: gain 0\.1 "
                     r"with the residual command_error .* belongs in 'scale'", result.stderr)
    assert "heater_b" not in result.stderr  # its scale is given: no warning


@pytest.mark.parametrize(("scenario", "switches"), [
    ("nominal", []), ("wheel_dropout", [("drop_wheel_speed", "gps")]),
])
def test_the_vehicle_recipe_runs_and_sees_a_silent_wheel_sensor(scenario, switches) -> None:
    from conftest import FIXTURES

    path = FIXTURES / "valid" / "vehicle_speed.yaml"
    car = load_text(path.read_text(encoding="utf-8"), str(path)).arch
    run = simulate(car, scenario, adapt=MapeK(car))
    assert [(s["action"], s["to"]) for s in run.switches] == switches
    if switches:
        assert 40.0 < run.switches[0]["t_s"] <= 41.5  # max_silence_s 0.5 s + one period
    assert run.metrics["final_error"] < 0.1
