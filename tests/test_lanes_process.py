"""The process pack's batched classes against their per-run twins.

Each batched class (:mod:`archself_process.lanes_tank`, :mod:`archself_process.lanes_control`)
steps N = 5 lanes built from per-run instances with other parameters (sweep points) and
seeds; per-run twins (the same parameters and seeds) step lane by lane with the same
inputs — absent lanes (NaN rows), absent signals (None), per-lane model objects — and
every output, residual signal and stored state must be the twins', bit for bit (the
batched code does the per-run float operations in the per-run order). Some steps advance
a lane subset only; mid-run some lanes go through the per-run bridge (store, a
hand-over's ``import_state`` or a ``set_params``, load). End to end, ``simulate_lanes``
makes the per-run decisions on every scenario of ``architectures/process_plant.yaml``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose

from archself.lanes import ALL, PerLane, lane_module, row, simulate_lanes, stack
from archself.lanes.batching import batched_types
from archself.model.loader import load_architecture
from archself.resources import data_dir
from archself.runtime import MapeK
from archself.sim.run import simulate
from archself.system.live import module_rng
from archself_process.control import (
    LevelObserver,
    PiController,
    PiFeedforwardController,
    SetpointPlanner,
)
from archself_process.lanes_windows import LaneMeans
from archself_process.tank import (
    ControlValve,
    FlowMeter,
    LevelSensor,
    MeanWindow,
    TankModel,
    TankModelNode,
    TankPlant,
)

DT = 0.2
STEPS = 150
SEEDS = (31, 32, 33, 34, 35)
SUBSET = np.array([0, 3])
SUBSET_STEPS = frozenset({4, 9, 10, 57, 101})  # steps that advance lanes 0 and 3 only
BRIDGE_STEP = 60  # lanes 1 and 4 go through store, a change, load
BRIDGE = np.array([1, 4])
EXACT = {"rtol": 0, "atol": 0}
MODELS = [TankModel(area_m2=0.4), None, TankModel(), TankModel(max_level_m=1.1),
          TankModel(outflow_coeff=0.012, max_flow_m3_s=0.03)]

Inputs = Callable[[np.random.Generator, int, np.ndarray], dict[str, Any]]


def _twins(kind: type, name: str, params: list[dict]) -> tuple[list, list]:
    """Two sets of per-run instances with the same parameters and seeds."""

    def build() -> list:
        return [kind(name, p, module_rng(s, name)) for p, s in zip(params, SEEDS, strict=True)]

    return build(), build()


def _same(got: Any, want: Any, what: str) -> None:
    """Two lane values (or states) agree; None and an all-NaN array both mean absent."""
    if isinstance(want, dict):
        assert isinstance(got, dict) and got.keys() == want.keys(), what
        for k in want:
            _same(got[k], want[k], f"{what}.{k}")
        return
    if got is None and want is None:
        return
    if type(want) is list and want and not isinstance(want[0], (float, int)):
        assert got == want, what
        return
    if isinstance(want, TankModel) or isinstance(got, TankModel):
        assert got == want, what
        return
    ref = np.asarray(want if want is not None else got, dtype=float)
    g = np.full(ref.shape, math.nan) if got is None else np.asarray(got, dtype=float)
    w = np.full(ref.shape, math.nan) if want is None else ref
    assert_allclose(g, w, err_msg=what, **EXACT)


def _close(a: Any, b: Any, path: str) -> None:
    """Records alike: the same structure and words, numbers within 1e-9."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), path
        for k in a:
            _close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), path
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _close(x, y, f"{path}[{k}]")
    elif isinstance(a, float):
        assert_allclose(a, b, rtol=0, atol=1e-9, err_msg=path)
    else:
        assert a == b, path


def _absent(rng: np.random.Generator, value: np.ndarray, p: float = 0.2) -> np.ndarray:
    """``value`` with random lanes absent (NaN rows)."""
    out = value.copy()
    out[rng.random(len(out)) < p] = math.nan
    return out


def _models(rng: np.random.Generator, k: int, idx: np.ndarray) -> list | None:
    """Per-lane model objects (None in some lanes), or None (no model input) now and then."""
    return None if k % 17 == 3 else [MODELS[i] for i in idx]


def _run(
    kind: type,
    name: str,
    params: list[dict],
    inputs: Inputs,
    state: Callable[[Any], dict[str, Any]],
    change: Callable[[Any, int], None] | None = None,
    steps: int = STEPS,
    dt: float = DT,
) -> tuple[Any, list]:
    """Step the batched class and the per-run twins with the same inputs; compare all.

    At :data:`BRIDGE_STEP` every lane's state makes a round trip through the per-run
    instances (store, load), and lanes :data:`BRIDGE` are changed in between by
    ``change(module, lane)`` (a hand-over, a parameter update), twins alike.
    """
    twins, mods = _twins(kind, name, params)
    batched = lane_module(mods)
    assert type(batched).__module__.startswith("archself_process.lanes_")  # batched
    rng = np.random.default_rng(99)
    for k in range(steps):
        t = k * dt
        if k == BRIDGE_STEP:
            batched.store(ALL)
            if change is not None:
                for i in BRIDGE.tolist():
                    change(mods[i], i)
                    change(twins[i], i)
            batched.load(ALL if change is None else BRIDGE)
        lanes = SUBSET if k in SUBSET_STEPS else ALL
        idx = np.arange(len(mods))[lanes]
        vals = inputs(rng, k, idx)
        if not kind.direct_feedthrough:
            want = [twins[i].output(t) for i in idx]
            got = batched.output(t, lanes)
            for key in want[0]:
                _same(got.get(key), stack([w.get(key) for w in want]), f"{key} at step {k}")
        want = [twins[i].step(t, dt, {s: row(v, j) for s, v in vals.items()})
                for j, i in enumerate(idx)]
        got = batched.step(t, dt, vals, lanes)
        for key in {*got, *(key for w in want for key in w)}:
            _same(got.get(key), stack([(w or {}).get(key) for w in want]), f"{key} at step {k}")
        sig = batched.local_signals(lanes)
        for key in kind.residual_signals:
            _same(sig[key], np.array([twins[i].local_signals()[key] for i in idx]),
                  f"{key} at step {k}")
        assert not batched.failed
    batched.store(ALL)
    for i, (m, twin) in enumerate(zip(mods, twins, strict=True)):
        _same(state(m), state(twin), f"stored state of {name} in lane {i}")
    return batched, twins


# ---------------------------------------------------------------------- the tank
TANKS = {
    "mixed": [
        {"supply_variation": 0.01, "outflow_variation": 0.005},
        {"substeps": 1, "area_m2": 0.3, "initial_level_m": 0.0},  # undisturbed, starts empty
        {"substeps": 7, "supply_variation": 0.05, "disturbance_time_s": 5.0,
         "max_level_m": 1.05},  # overflows
        {"outflow_variation": 0.02, "initial_level_m": 2.0},
        {},
    ],
    "uniform": [
        {"supply_variation": 0.01 * (j + 1), "outflow_variation": 0.005,
         "disturbance_time_s": 10.0 * (j + 1), "area_m2": 0.3 + 0.1 * j}
        for j in range(5)
    ],
}


def _inflow(rng: np.random.Generator, k: int, idx: np.ndarray) -> dict[str, Any]:
    if k == 5:
        return {"inflow": None}
    return {"inflow": _absent(rng, rng.uniform(-0.005, 0.03, len(idx)))}


def _tank_state(m: TankPlant) -> dict[str, Any]:
    return {"h": m.h, "q_in": m.q_in, "d": [m.d_in, m.d_out], **m.export_state()}


@pytest.mark.parametrize("case", TANKS)
def test_tank_lanes_are_the_per_run_tanks(case: str) -> None:
    def refill(m: TankPlant, i: int) -> None:
        m.import_state({"level": 0.5 + 0.25 * i})

    _run(TankPlant, "tank", TANKS[case], _inflow, _tank_state, change=refill)


# ---------------------------------------------------------------------- valve and instruments
VALVES = [{"error_smoothing_s": 1.0}, {"max_flow_m3_s": 0.05}, {"error_smoothing_s": 0.3},
          {"error_smoothing_s": 0.0}, {"error_smoothing_s": 5.0, "max_flow_m3_s": 0.01}]


def _valve_inputs(rng: np.random.Generator, k: int, idx: np.ndarray) -> dict[str, Any]:
    n = len(idx)
    cmd = None if k in (3, 4, 40) else _absent(rng, rng.uniform(-0.2, 1.2, n))
    flow = None if k in (10, 40) else _absent(rng, rng.uniform(0.0, 0.03, n))
    return {"valve_cmd": cmd, "flow_measured": flow}


def _valve_state(m: ControlValve) -> dict[str, Any]:
    return {"prev": m.prev_flow, "signals": m.signals}


def test_valve_lanes_are_the_per_run_valves() -> None:
    def forget(m: ControlValve, i: int) -> None:
        m.prev_flow = None if i == 1 else 0.02

    _run(ControlValve, "valve", VALVES, _valve_inputs, _valve_state, change=forget)


def test_flow_meter_lanes_draw_only_where_the_inflow_is_present() -> None:
    params = [{"noise_m3_s": s} for s in (2e-4, 0.0, 1e-3, 5e-5, 2e-4)]
    _run(FlowMeter, "flow_meter", params, _inflow, lambda m: {})


def test_level_sensor_lanes_are_the_per_run_sensors() -> None:
    params = [{"noise_m": s, "bias_m": b}
              for s, b in ((0.005, 0.0), (0.0, 0.1), (0.02, -0.05), (0.008, 0.0), (0.1, 1.0))]

    def level(rng, k, idx):
        h = rng.uniform(0.0, 2.5, (len(idx), 1))
        return {"level": None if k == 7 else _absent(rng, h)}

    _run(LevelSensor, "level_a", params, level, lambda m: {})


def test_a_non_finite_reading_fails_its_lane_as_per_run() -> None:
    params = [{"noise_m": 0.005}] * 3
    twins, mods = _twins(LevelSensor, "level_a", params + [{}, {}])
    batched, one_by_one = lane_module(mods), PerLane(twins)
    batched.bias[2] = twins[2].bias = math.inf
    level = np.array([[1.0], [1.1], [1.2], [math.nan], [0.9]])
    got = batched.step(0.0, DT, {"level": level}, ALL)["level_measured"]
    want = one_by_one.step(0.0, DT, {"level": level}, ALL)["level_measured"]
    assert_allclose(got, want, **EXACT)
    assert batched.failed == one_by_one.failed == {2: "non-finite output"}


def test_model_node_lanes_publish_each_lanes_model() -> None:
    params = [{"area_m2": 0.3 + 0.1 * j, "max_flow_m3_s": 0.02 + 0.001 * j} for j in range(5)]
    batched, twins = _run(TankModelNode, "tank_model", params, lambda rng, k, idx: {},
                          lambda m: {"model": m.output(0.0)["tank_model"]}, steps=5)
    assert batched.output(0.0, ALL)["tank_model"] == [m.output(0.0)["tank_model"] for m in twins]
    assert [o.area_m2 for o in batched.output(0.0, SUBSET)["tank_model"]] == [0.3, 0.3 + 0.1 * 3]


# ---------------------------------------------------------------------- the observer
OBSERVERS = [
    {},  # starts from its first reading
    {"initial_level_m": 1.2, "correction_gain": 0.05, "innovation_window_s": 50.0},
    {"handover_gain": 0.5, "handover_s": 0.0, "innovation_window_s": 2.0},
    {"initial_level_m": 0.8, "handover_s": 5.0, "correction_gain": 0.0},
    {"correction_gain": 6.0, "innovation_window_s": 10.0},  # L·dt clipped to 1
]


def _observer_inputs(rng: np.random.Generator, k: int, idx: np.ndarray) -> dict[str, Any]:
    n = len(idx)
    level = 1.0 + 0.05 * rng.standard_normal(n) + 0.002 * k  # a drifting reading
    if k < 3:  # lane 0 (no start level) gets its first reading late
        level[idx == 0] = math.nan
    return {
        "level_measured": None if k in (6, 80) else _absent(rng, level),
        "flow_measured": None if k in (7, 80) else _absent(rng, rng.uniform(0.005, 0.015, n)),
        "tank_model": _models(rng, k, idx),
        # a second transmitter: absent in some steps and lanes, offset in lane 2
        "level_check": None if k in (5, 40) else _absent(
            rng, level + 0.01 * rng.standard_normal(n) + 0.02 * (idx == 2)),
    }


def _window(w: MeanWindow) -> dict[str, Any]:
    return {"items": [list(x) for x in w.items], "total": w.total, "steps": w.steps,
            "start": w.start, "last": w.last, "window": w.window_s}


def _observer_state(m: LevelObserver) -> dict[str, Any]:
    return {"h": m.h, "boost": [m.boost_until, float(m._boost_pending)],
            "signals": m.signals, "monitor": _window(m.monitor), "check": _window(m.check),
            **m.export_state()}


def test_observer_lanes_are_the_per_run_observers() -> None:
    def hand_over(m: LevelObserver, i: int) -> None:
        m.import_state({"level": 1.1 + 0.01 * i})  # a boost pending, the window cleared

    batched, _ = _run(LevelObserver, "observer_a", OBSERVERS, _observer_inputs,
                      _observer_state, change=hand_over, steps=2 * STEPS)
    assert batched.monitor.t.shape[1] > 64  # the 50 s window made the ring buffers grow
    assert np.isfinite(batched.disagreement).sum() >= 3  # the second transmitter was read
    assert batched.disagreement[2] > 3.0  # lane 2's transmitters differ by 2 cm


def test_lane_means_are_mean_windows_in_any_order_of_lanes() -> None:
    rng = np.random.default_rng(3)
    windows = [MeanWindow(w) for w in (1.0, 4.0, 0.5)]
    means = LaneMeans(3, capacity=2)
    means.window[:] = [w.window_s for w in windows]
    for k in range(40):
        idx = np.flatnonzero(rng.random(3) < 0.7)
        v = rng.standard_normal(len(idx))
        for i, x in zip(idx.tolist(), v.tolist(), strict=True):
            windows[i].add(0.1 * k, x)
        if len(idx):
            means.add(0.1 * k, idx, v)
        assert_allclose(means.value(np.arange(3)), [w.value() for w in windows], **EXACT)
        assert_allclose(means.t_values(np.arange(3)), [w.t_value() for w in windows], **EXACT)
    twin = MeanWindow(0.0)
    means.store(1, twin)
    assert _window(twin) == _window(windows[1]) | {"window": 0.0}


# ---------------------------------------------------------------------- the controllers
PIS = [
    {"kp": 3.0, "ki": 0.128},
    {"kp": 1.0, "ki": 0.0},  # no integrator
    {"kp": 10.0, "ki": 0.5, "initial_output": 0.1},  # saturates: the anti-windup
    {},
    {"kp": 0.5, "ki": 0.05, "initial_output": 1.0},
]
FEEDFORWARDS = [
    {**p, "adaptation_time_s": tau, "min_effectiveness": low}
    for p, tau, low in zip(PIS, (5.0, 0.5, 20.0, 5.0, 1.0), (0.3, 0.8, 0.05, 0.3, 1.0),
                           strict=True)
]


def _controller_inputs(rng: np.random.Generator, k: int, idx: np.ndarray) -> dict[str, Any]:
    n = len(idx)
    ref = np.column_stack([rng.uniform(0.8, 1.5, n), rng.uniform(-0.005, 0.005, n)])
    est = rng.uniform(0.5, 1.6, n)
    return {
        "setpoint": None if k in (2, 3) else _absent(rng, ref),
        "level_estimate": None if k in (3, 30) else _absent(rng, est),
        "flow_measured": None if k == 12 else _absent(rng, rng.uniform(0.0, 0.025, n)),
        "tank_model": _models(rng, k, idx),
    }


def _pi_state(m: PiController) -> dict[str, Any]:
    return {"integral": m.integral, "cmd": m.last_cmd, "signals": m.signals,
            **m.export_state()}


def _ff_state(m: PiFeedforwardController) -> dict[str, Any]:
    return {**_pi_state(m), "adapt": [m._num, m._den, m._ff], "sent": m._sent}


def _switch(m: PiController, i: int) -> None:
    """A hand-over into lane 1, a parameter update (raise_pi_gain) in lane 4."""
    if i == 1:
        m.import_state({"opening": 0.5, "model": TankModel(area_m2=0.6), "level_op": 1.2,
                        "effectiveness": 0.7})
    else:
        m.set_params({"kp": 5.0, "ki": 0.213})


def test_pi_lanes_are_the_per_run_controllers() -> None:
    _run(PiController, "pi", PIS, _controller_inputs, _pi_state, change=_switch)


def test_feedforward_lanes_estimate_the_effectiveness_as_per_run() -> None:
    batched, twins = _run(PiFeedforwardController, "ff_pi", FEEDFORWARDS, _controller_inputs,
                          _ff_state, change=_switch)
    assert len({m.eta for m in twins}) > 2  # lanes with their own estimates


# ---------------------------------------------------------------------- the setpoint
RECIPE = [[0, 1.0], [200, 1.3], [420, 1.1]]
SETPOINTS = {
    "by-group": [{"steps": RECIPE, "max_rate_m_s": r} for r in (0.005, 0.005, 0.0, 0.005, 0.0)],
    "by-lane": [{"steps": RECIPE, "max_rate_m_s": 0.005}, {"steps": [[0, 0.5]]},
                {"steps": [[50, 2.0], [0, 1.0], [60, 0.2]], "max_rate_m_s": 0.01},
                {"steps": RECIPE, "max_rate_m_s": 0.002}, {"steps": RECIPE}],
}


@pytest.mark.parametrize("case", SETPOINTS)
def test_setpoint_lanes_are_the_per_run_setpoints(case: str) -> None:
    batched, _ = _run(SetpointPlanner, "setpoint", SETPOINTS[case], lambda rng, k, idx: {},
                      lambda m: {}, dt=4.5)
    assert len(batched.first) == (2 if case == "by-group" else 5)


# ---------------------------------------------------------------------- whole runs
@pytest.fixture(scope="module")
def plant():
    return load_architecture(data_dir("architectures") / "process_plant.yaml").arch


def test_every_type_of_the_process_plant_is_batched(plant) -> None:
    from archself.system.live import compile_system

    assert batched_types(plant)
    system = compile_system(plant, "p1", seed=1)
    for name in plant.modules:
        assert not isinstance(lane_module([system._module(name)]), PerLane), name


def test_adaptive_lanes_make_the_per_run_decisions_in_every_scenario(plant) -> None:
    """MAPE-K per lane on the batched classes: the switches (times and configurations),
    the decisions and the series of the per-run runs."""
    seeds = [1, 2, 3]
    switched = 0
    for scenario in plant.scenarios:
        lanes = simulate_lanes(plant, scenario, seeds, adapt=True)
        for got, seed in zip(lanes, seeds, strict=True):
            want = simulate(plant, scenario, seed=seed, adapt=MapeK(plant))
            assert got.switches == want.switches, (scenario, seed)
            assert got.final_configuration == want.final_configuration
            assert len(got.decisions) == len(want.decisions)
            for mine, theirs in zip(got.decisions, want.decisions, strict=True):
                _close(mine.to_dict(), theirs.to_dict(), f"{scenario}, seed {seed}")
            assert_allclose(got.metrics["max_error"], want.metrics["max_error"], rtol=0,
                            atol=1e-9, err_msg=f"{scenario}, seed {seed}")
            for key in ("J", "estimate", "command", *(k for k in want.series if "." in k)):
                assert_allclose(got.series[key], want.series[key], rtol=0, atol=1e-9,
                                err_msg=f"{key} of {scenario}, seed {seed}")
            switched += bool(want.switches)
    assert switched >= 9  # level_drift, valve_loss, drift_then_valve, valve_flicker


def test_fixed_lanes_of_sweep_points_are_the_per_run_runs(plant) -> None:
    """One architecture per lane (other noise, sub-steps, gains) in the compensating p4."""
    archs = []
    for j in range(3):
        raw = plant.model_dump(by_alias=True)
        mods = raw["modules"]
        mods["level_b"]["params"]["noise_m"]["value"] = 0.004 * (j + 1)
        mods["ff_pi"]["params"]["kp"]["value"] = 2.0 + j
        mods["tank"]["params"]["substeps"] = {"value": 2 + 3 * j}
        archs.append(type(plant).model_validate(raw))
    lanes = simulate_lanes(archs, "drift_then_valve", [7, 8, 9], configuration="p4")
    for got, a, seed in zip(lanes, archs, (7, 8, 9), strict=True):
        want = simulate(a, "drift_then_valve", seed=seed, configuration="p4")
        for key, val in want.series.items():
            assert_allclose(got.series[key], val, rtol=0, atol=1e-9, err_msg=key)
    assert lanes[0].metrics["max_error"] != lanes[2].metrics["max_error"]
