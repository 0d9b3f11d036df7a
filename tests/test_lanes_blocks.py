"""The block library's batched classes against their per-run twins, and motor_drive end to end.

Each batched class (``packs/archself_blocks/lanes_*.py``) steps N = 4 lanes built
from per-run instances with other parameters and seeds (sweep points); per-run twins
step lane by lane with the same plausible inputs — absent lanes (NaN rows), absent
signals (None), several edges, per-lane model objects — and every output, residual
signal and random stream must agree. Some steps advance a lane subset only; a
hand-over or a parameter update goes through the per-run bridge (store, the per-run
API on the instance, load). End to end, ``simulate_lanes`` gives the per-run adaptive
runs of ``architectures/motor_drive.yaml`` in every scenario.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose

from archself.lanes import ALL, LaneNormals, lane_module, simulate_lanes, stack
from archself.model.loader import load_architecture
from archself.resources import data_dir
from archself.sim.run import simulate
from archself.system.live import module_rng
from archself_blocks.actuators import Actuator
from archself_blocks.estimators import AugmentedEkf, KalmanFilter, Luenberger
from archself_blocks.lti import LtiModel, LtiModelNode, StateSpacePlant, TransferFunctionPlant
from archself_blocks.pid import Pid
from archself_blocks.relay import Relay
from archself_blocks.sensors import Sensor
from archself_blocks.signals import Gain, Reference, Select, Sum

DT = 0.1
STEPS = 120
SEEDS = (11, 12, 13, 14)
SUBSET = np.array([1, 3])
SUBSET_STEPS = frozenset({7, 8, 33, 61, 62})  # steps that advance lanes 1 and 3 only
TOL = {"rtol": 1e-9, "atol": 1e-12}
MOTOR = {"A": [[-10.0, -5.0], [1.0, -0.1]], "B": [[10.0], [0.0]], "C": [[0.0, 1.0]]}

Hook = Callable[[int, list, list], None]  # (step, batched instances, twins)


def _same(got: Any, want: Any, what: str) -> None:
    """Two lane values agree (None and an all-NaN array both mean absent everywhere)."""
    if type(want) is list or type(got) is list:
        assert got is not None and want is not None and len(got) == len(want), what
        assert all(a is b for a, b in zip(got, want, strict=True)), what
        return
    if got is None and want is None:
        return
    ref = np.asarray(want if want is not None else got, dtype=float)
    g = np.full(ref.shape, math.nan) if got is None else np.asarray(got, dtype=float)
    w = np.full(ref.shape, math.nan) if want is None else ref
    assert_allclose(g, w, err_msg=what, **TOL)


def _maybe(rng: np.random.Generator, value: Any, p: float) -> Any:
    """``value``, or None with probability ``p`` (a lane without it this step)."""
    return None if rng.random() < p else value


def _lane_inputs(per_run: list[dict[str, Any]]) -> dict[str, Any]:
    """The lane values of the lanes' per-run inputs (a list per run: one value per edge)."""
    out: dict[str, Any] = {}
    for key in per_run[0]:
        vals = [p[key] for p in per_run]
        if isinstance(vals[0], list) and key != "model":
            out[key] = tuple(stack([v[e] for v in vals]) for e in range(len(vals[0])))
        else:
            out[key] = stack(vals)
    return out


def _streams_agree(batched: Any, twins: list) -> None:
    """Each lane's stream stands where its twin's does (the per-run position)."""
    for normals in (v for v in vars(batched).values() if isinstance(v, LaneNormals)):
        for i, twin in enumerate(twins):
            normals.pin(i)
            assert normals.rngs[i].bit_generator.state == twin.rng.bit_generator.state
        normals.unpin()


def _run(kind: type, params: list[dict], inputs: Callable[..., dict[str, Any]],
         hooks: dict[int, Hook] | None = None, steps: int = STEPS,
         prepare: Callable[[list], None] = lambda mods: None) -> tuple[Any, list]:
    """Step the batched class and the twins with the same inputs; compare every step.

    ``inputs(rng, k, lane)`` gives lane ``lane``'s per-run inputs at step ``k``;
    ``hooks[k](k, mods, twins)`` acts on the per-run instances before step ``k``
    (after a store; the changed lanes are loaded back); ``prepare`` sets both sets of
    instances up before the batched module is built.
    """
    name = kind.__name__.lower()
    twins = [kind(name, p, module_rng(s, name)) for p, s in zip(params, SEEDS, strict=True)]
    mods = [kind(name, p, module_rng(s, name)) for p, s in zip(params, SEEDS, strict=True)]
    prepare(twins)
    prepare(mods)
    batched = lane_module(mods)
    assert type(batched).__module__.startswith("archself_blocks.lanes_")
    rng = np.random.default_rng(5)
    published: list[tuple[np.ndarray, np.ndarray]] = []  # (a published array, its copy)
    for k in range(steps):
        t = k * DT
        if hooks and k in hooks:
            batched.store(ALL)
            hooks[k](k, mods, twins)
            batched.load(ALL)
        lanes = SUBSET if k in SUBSET_STEPS else ALL
        idx = np.arange(len(SEEDS))[lanes]
        if not kind.direct_feedthrough:
            got = batched.output(t, lanes)
            want = [twins[i].output(t) for i in idx]
            for key in want[0]:
                _same(got.get(key), stack([w[key] for w in want]), f"output {k} {key}")
        per_run = [inputs(rng, k, int(i)) for i in idx]
        got = batched.step(t, DT, _lane_inputs(per_run) if per_run[0] else {}, lanes)
        want = [twins[i].step(t, DT, p) for i, p in zip(idx, per_run, strict=True)]
        for key in want[0] or ():
            _same(got.get(key), stack([w[key] for w in want]), f"step {k} {key}")
        for arr, copy in published:  # what a lane module publishes is no view of its state
            assert np.array_equal(arr, copy, equal_nan=True), f"step {k}: a published value moved"
        published = [(v, v.copy()) for v in got.values() if isinstance(v, np.ndarray)]
        sigs = batched.local_signals(lanes)
        for key in kind.residual_signals:
            expect = [twins[i].local_signals().get(key, math.nan) for i in idx]
            assert_allclose(sigs[key], expect, err_msg=f"step {k} {key}", **TOL)
        assert not batched.failed
    _streams_agree(batched, twins)
    return batched, twins


def _hand_over(lanes: tuple[int, ...], state: dict) -> Hook:
    def hook(k, mods, twins):
        for i in lanes:
            mods[i].import_state(state)
            twins[i].import_state(state)
    return hook


def _update(lane: int, values: dict) -> Hook:
    def hook(k, mods, twins):
        mods[lane].set_params(values)
        twins[lane].set_params(values)
    return hook


# ---------------------------------------------------------------------- plants
PLANTS = [
    {**MOTOR, "x0": [5.0, 50.0], "process_noise": [0.0, 0.2]},
    {**MOTOR, "x0": [5.0, 50.0]},
    {"A": [[-8.0, -5.0], [1.0, -0.2]], "B": [[9.0], [0.0]], "C": [[0.0, 1.0]],
     "process_noise": 0.1},
    {"A": [[0.9, 0.05], [0.0, 0.95]], "B": [[0.1], [0.05]], "C": [[0.0, 1.0]],
     "sample_time_s": 0.3, "process_noise": [0.01, 0.02]},  # discrete: updates every 3 steps
]


def _plant_inputs(rng, k, lane) -> dict[str, Any]:
    drive = _maybe(rng, 30.0 + 5.0 * math.sin(0.1 * k) + lane, 0.1)
    return {"u": [drive, None if k % 3 else float(rng.normal())]}  # two edges, summed


def test_state_space_lanes_are_the_per_run_plants() -> None:
    hooks = {50: _hand_over((0, 3), {"state": [1.0, 40.0]}),
             80: _update(1, {"process_noise": [0.0, 0.3]})}
    batched, twins = _run(StateSpacePlant, PLANTS, _plant_inputs, hooks)
    assert type(batched).__name__ == "StateSpacePlantLanes"
    batched.store(ALL)
    for mod, twin in zip(batched.modules, twins, strict=True):
        assert_allclose(mod.export_state()["state"], twin.export_state()["state"], **TOL)
        assert mod._acc == pytest.approx(twin._acc) and np.array_equal(mod.u, twin.u)


def test_transfer_function_lanes_are_the_per_run_plants() -> None:
    params = [{"num": [1.0], "den": [1.0, 2.0 + 0.5 * i, 1.0], "process_noise": 0.05 * (i % 2)}
              for i in range(4)]
    _run(TransferFunctionPlant, params, lambda rng, k, lane: {"u": [_maybe(rng, 1.0, 0.2)]})


def test_a_plant_lane_given_an_input_of_another_width_fails_alone() -> None:
    mods = [StateSpacePlant("p", PLANTS[1], module_rng(s, "p")) for s in SEEDS]
    batched = lane_module(mods)
    wide = stack([None, np.array([1.0, 2.0]), None, None])
    batched.step(0.0, DT, {"u": (wide,)}, ALL)
    assert batched.failed == {1: "raised ValueError"}
    with pytest.raises(ValueError):
        mods[1].step(0.0, DT, {"u": [np.array([1.0, 2.0])]})
    assert_allclose(batched.x[1], [5.0, 50.0])  # unchanged, as per run


# ---------------------------------------------------------------------- actuators, sensors
ACTUATORS = [
    {"u_min": 0.0, "u_max": 60.0, "rate_limit": 100.0, "time_constant_s": 0.02, "initial": 30.0},
    {"gain": 0.8, "initial": 10.0},
    {"gain": 0.0, "time_constant_s": 0.5, "initial": 5.0},
    {"u_max": 10.0, "rate_limit": 20.0, "time_constant_s": 0.1, "gain": 1.5},
]


def _actuator_inputs(rng, k, lane) -> dict[str, Any]:
    cmd = 30.0 + 20.0 * math.sin(0.05 * k) + rng.normal()
    return {"command": _maybe(rng, cmd, 0.1), "measurement": _maybe(rng, cmd + rng.normal(), 0.2)}


@pytest.mark.parametrize("width", [1, 3])
def test_actuator_lanes_are_the_per_run_actuators(width) -> None:
    params = [{**p, "width": width, "channel": [0, 2, 1, 0][i] if width > 1 else 0}
              for i, p in enumerate(ACTUATORS)]
    hooks = {50: _hand_over((2, 3), {"output": 12.0}), 70: _update(0, {"gain": 1.5})}
    batched, twins = _run(Actuator, params, _actuator_inputs, hooks)
    batched.store(ALL)
    for mod, twin in zip(batched.modules, twins, strict=True):
        assert (mod.v, mod.x, mod.prev) == pytest.approx((twin.v, twin.x, twin.prev))


SENSORS = [
    {"noise": 0.3},
    {"noise": 0.2, "resolution": 0.05},
    {"resolution": 0.5, "gain": 2.0, "bias": 1.0, "drift_per_s": 0.01, "min": 0.0, "max": 100.0},
    {"noise": 0.1, "dropout_probability": 0.2, "index": 1},
]


def _sensor_inputs(rng, k, lane) -> dict[str, Any]:
    y = np.array([5.0 + rng.normal(), 50.0 + 0.1 * k]) if lane != 2 or k % 5 else None
    return {"y": _maybe(rng, y, 0.15), "u": _maybe(rng, np.array([30.0, 1.0 + lane]), 0.5)}


def test_sensor_lanes_draw_as_the_per_run_sensors() -> None:
    """Noise, quantization, range, the y-or-u input; dropout switched on and off at run time
    (the lane's stream set back to its per-run position, then buffered again)."""
    hooks = {60: _update(0, {"dropout_probability": 0.3}),
             90: _update(3, {"dropout_probability": 0.0})}
    _run(Sensor, SENSORS, _sensor_inputs, hooks)


# ---------------------------------------------------------------------- signals
REFERENCES = [
    {"table": [[0, 50.0], [6, 70.0], [13, 40.0]], "max_rate": 5.0},
    {"table": [[0, 50.0], [6, 70.0], [13, 40.0]], "max_rate": 5.0},
    {"table": [[0, 0.0], [5, 10.0]], "interpolation": "linear"},
    {"table": [[0, 1.0], [3, -1.0]]},
]


def test_reference_lanes_are_the_per_run_references() -> None:
    hooks = {50: lambda k, mods, twins: None}  # a store and load of every lane
    batched, _ = _run(Reference, REFERENCES, lambda rng, k, lane: {}, hooks)
    assert len(batched.first) == 3  # the two lanes with one table share its lookup


def _scalar_inputs(rng, k, lane) -> dict[str, Any]:
    return {"measurement": [_maybe(rng, float(rng.normal()), 0.3), None],
            "estimate": [_maybe(rng, float(rng.normal()), 0.3)]}


def _vector_inputs(rng, k, lane) -> dict[str, Any]:
    return {"y": [_maybe(rng, rng.normal(size=2), 0.3), _maybe(rng, rng.normal(size=2), 0.3)]}


@pytest.mark.parametrize(("kind", "params", "inputs"), [
    (Gain, [{"gain": 2.0, "offset": 1.0}, {}, {"gain": -0.5}, {"gain": 3.0, "offset": 0.2}],
     _scalar_inputs),
    (Gain, [{"gain": [[1.0, 2.0], [0.0, 1.0]], "offset": [0.0, 1.0]},
            {"gain": [[0.5, 0.0], [1.0, 1.0]], "offset": [1.0, 1.0]},
            {"gain": [[2.0, 0.0], [0.0, 2.0]], "offset": [0.0, 0.0]},
            {"gain": [[1.0, 1.0], [1.0, -1.0]], "offset": [-1.0, 0.5]}], _vector_inputs),
    (Sum, [{"weights": [1.0, -1.0, 0.5]}, {}, {"weights": [2.0, 2.0, 2.0, 9.0]},
           {"weights": [0.0, 1.0, 1.0]}], _scalar_inputs),
    (Sum, [{}, {"weights": [1.0, -1.0]}, {"weights": [0.5, 0.5]}, {}], _vector_inputs),
    (Select, [{"index": 1}, {"index": 0}, {"index": 2}, {"index": 1}],
     lambda rng, k, lane: {"y": [None, _maybe(rng, rng.normal(size=3), 0.2)],
                           "estimate": [_maybe(rng, rng.normal(size=3), 0.3)]}),
    (Select, [{"index": [1, 0]}, {"index": [0, 0]}, {"index": [2, 1]}, {"index": [1, 2]}],
     lambda rng, k, lane: {"y": [_maybe(rng, rng.normal(size=3), 0.2)]}),
])
def test_static_lanes_are_the_per_run_blocks(kind, params, inputs) -> None:
    batched, _ = _run(kind, params, inputs, steps=40)
    assert type(batched).__name__ == f"{kind.__name__}Lanes"


def test_static_inputs_of_other_widths_go_lane_by_lane() -> None:
    """A scalar and a vector on one sum: the per-run block broadcasts; the lanes fall back."""
    _run(Sum, [{}] * 4, lambda rng, k, lane: {"measurement": [_maybe(rng, 1.0 + lane, 0.3)],
                                              "y": [rng.normal(size=2)]}, steps=20)


def test_relay_lanes_are_the_per_run_relays() -> None:
    params = [{"gain": 0.9, "noise": 0.1}, {}, {"gain": 1.2, "noise": 0.05}, {"noise": 0.2}]
    def inputs(rng, k, lane):
        return {"signal": [_maybe(rng, float(rng.normal()), 0.3), _maybe(rng, 2.0, 0.3), None]}

    hooks = {40: _update(1, {"noise": 0.3})}
    _run(Relay, params, inputs, hooks)


# ---------------------------------------------------------------------- control
PIDS = [
    {"kp": 1.0, "ki": 1.0, "ff_gain": 0.6, "u_min": 0.0, "u_max": 60.0},
    {"kp": 2.0, "ki": 0.5, "kd": 0.1, "derivative_filter_rad_s": 20.0,
     "anti_windup": "back_calculation", "tracking_time_s": 0.5, "u_max": 40.0},
    {"ki": 2.0, "kd": 0.05, "anti_windup": "none", "ff_rate_gain": 0.3, "ff_offset": 1.0},
    {"kp": 0.5, "ki": 0.2, "feedback_index": 1, "u_min": -5.0, "u_max": 5.0},
]
MODELS = [LtiModel(**MOTOR) for _ in SEEDS]


def _pid_inputs(rng, k, lane) -> dict[str, Any]:
    r = 50.0 + 10.0 * (k > 30) - 20.0 * (k > 80)
    y = r - 8.0 * math.exp(-0.05 * (k % 30)) + rng.normal(0, 0.3)
    return {"reference": _maybe(rng, np.array([r, 0.5 * (k % 7 == 0)]), 0.1),
            "estimate": _maybe(rng, np.array([y, y - 1.0]), 0.2),
            "measurement": _maybe(rng, y + 0.1, 0.5),
            "model": MODELS[lane] if k > 3 else None}


def test_pid_lanes_are_the_per_run_pids() -> None:
    hooks = {50: _hand_over((1, 2), {"integral": 3.0}), 70: _update(0, {"kp": 1.6, "ki": 1.6})}
    batched, twins = _run(Pid, PIDS, _pid_inputs, hooks)
    batched.store(ALL)
    for mod, twin in zip(batched.modules, twins, strict=True):
        assert (mod.integral, mod.y_f, mod.last) == pytest.approx((twin.integral, twin.y_f,
                                                                   twin.last))
        assert mod.model is twin.model is not None
    for mod, twin in zip(batched.modules[:3], twins, strict=False):  # lane 3 feeds back y[1]
        assert_allclose(mod.linearization(), twin.linearization(), **TOL)


def test_model_node_lanes_publish_each_lanes_object() -> None:
    mods = [LtiModelNode("m", MOTOR, module_rng(s, "m")) for s in SEEDS]
    batched = lane_module(mods)
    assert [o is m._out["model"] for o, m in zip(batched.output(0.0, ALL)["model"], mods,
                                                  strict=True)] == [True] * 4
    mods[2].set_params({"A": [[-9.0, -5.0], [1.0, -0.1]]})
    batched.load(np.array([2]))
    (got,) = batched.output(0.0, np.array([2]))["model"]
    assert got is mods[2]._out["model"] and got.A[0, 0] == -9.0


# ---------------------------------------------------------------------- the Kalman filter
KALMANS = [
    {"Q": [0.01, 0.05], "R": 0.09, "P0": [1.0, 4.0], "x0": [5.0, 50.0],
     "innovation_window_s": 4.0, "settle_s": 1.0},
    {"Q": [0.01, 0.05], "R": 0.04, "P0": [1.0, 4.0], "x0": [5.0, 50.0],
     "innovation_window_s": 5.0, "settle_s": 2.0},
    {"Q": [0.02, 0.1], "R": 0.09},  # starts from the least-squares estimate
    {"Q": 0.02, "R": 0.1, "P0": 2.0, "settle_s": 0.0, "innovation_window_s": 3.0},
]
KF_MODELS = [LtiModel(**MOTOR), LtiModel(**MOTOR),
             LtiModel([[-8.0, -5.0], [1.0, -0.2]], [[9.0], [0.0]], [[0.0, 1.0]]),
             LtiModel(**MOTOR)]
NEW_MODEL = LtiModel(**MOTOR)  # lane 1's model object from step 40 on


def _kalman_inputs(rng, k, lane) -> dict[str, Any]:
    model = NEW_MODEL if lane == 1 and k >= 40 else KF_MODELS[lane]
    w = 50.0 + 0.2 * k + (0.02 * (k - 70) if lane == 0 and k > 70 else 0.0)  # lane 0 drifts
    return {"model": None if k < 2 or (lane == 3 and k < 5) else model,
            "u": _maybe(rng, 30.0 + rng.normal(0, 0.1), 0.1),
            "measurement": None if k in (10, 11) else _maybe(rng, w + rng.normal(0, 0.3), 0.1)}


def test_kalman_lanes_are_the_per_run_filters() -> None:
    """Start (x0 or least squares), a new model object, windows, settle; a hand-over (P0, the
    window cleared, the monitor paused) and a retune through the per-run bridge."""
    hooks = {60: _hand_over((0, 2), {"state": [4.0, 45.0]}), 90: _update(3, {"R": 0.2})}
    batched, twins = _run(KalmanFilter, KALMANS, _kalman_inputs, hooks)
    sigs = batched.local_signals(ALL)  # lane 2's window (10 s) not half full after its hand-over
    assert np.isfinite(sigs["innovation"]).tolist() == [True, True, False, True]
    batched.store(ALL)
    for mod, twin in zip(batched.modules, twins, strict=True):
        assert_allclose(mod.export_state()["state"], twin.export_state()["state"], **TOL)
        assert_allclose(mod.P, twin.P, **TOL)
        assert_allclose(mod.linearization(), twin.linearization(), **TOL)
        assert [t for t, _ in mod.window.items] == [t for t, _ in twin.window.items]
        assert_allclose(mod.window.total, twin.window.total, **TOL)
        assert mod.model is twin.model and mod._dt == twin._dt


def test_kalman_lanes_built_from_handed_over_instances() -> None:
    """A filter switched in: its instances hold an estimate before any model arrived."""
    def prepare(mods):
        mods[0].import_state({"state": [4.0, 48.0]})
        mods[3].import_state({"state": [6.0, 52.0]})

    _run(KalmanFilter, KALMANS, _kalman_inputs, steps=40, prepare=prepare)


OBSERVERS = [
    {"poles": [-4.0, -5.0], "x0": [5.0, 50.0], "innovation_window_s": 4.0, "settle_s": 1.0},
    {"poles": [-4.0, -5.0], "innovation_window_s": 3.0, "settle_s": 0.5},
    {"gain": [[0.5], [2.0]], "x0": [5.0, 50.0], "innovation_window_s": 2.0, "settle_s": 0.0},
    {"poles": [[-3.0, 1.0]], "innovation_window_s": 3.0},  # a complex pair
]


def test_luenberger_lanes_are_the_per_run_observers() -> None:
    """Gains placed once for the lanes that agree; a hand-over and a new gain at run time."""
    hooks = {60: _hand_over((0, 2), {"state": [4.0, 45.0]}),
             90: _update(2, {"gain": [[0.3], [1.5]]})}
    batched, twins = _run(Luenberger, OBSERVERS, _kalman_inputs, hooks)
    assert len(batched._shared) == 4  # lanes 0 and 1 share theirs; lane 2 has two gains
    assert np.isfinite(batched.local_signals(ALL)["innovation"]).all()
    batched.store(ALL)
    for mod, twin in zip(batched.modules, twins, strict=True):
        assert_allclose(mod.export_state()["state"], twin.export_state()["state"], **TOL)
        assert_allclose(mod.linearization(), twin.linearization(), **TOL)
        assert_allclose(mod._y, twin._y, **TOL)


EKFS = [
    {**KALMANS[0], "effectiveness_noise": 1e-3},
    {**KALMANS[1], "effectiveness_noise": 1e-2, "effectiveness_p0": 0.05},
    {**KALMANS[2]},
    {**KALMANS[3], "effectiveness_noise": 1e-4},
]


@pytest.mark.parametrize("parts", [{}, {"estimate_effectiveness": False, "estimate_bias": True},
                                   {"estimate_bias": True}])
def test_ekf_lanes_are_the_per_run_filters(parts) -> None:
    """η and/or b in the state; a hand-over (the parameters kept) and a retune at run time."""
    params = [{**p, **parts} for p in EKFS]
    hooks = {60: _hand_over((0, 2), {"state": [4.0, 45.0]}), 90: _update(3, {"R": 0.2})}
    batched, twins = _run(AugmentedEkf, params, _kalman_inputs, hooks)
    assert np.isfinite(batched.local_signals(ALL)["effectiveness_loss"]).sum() >= 3
    batched.store(ALL)
    for mod, twin in zip(batched.modules, twins, strict=True):
        got, want = mod.export_state(), twin.export_state()
        for key in ("state", "parameters"):
            assert_allclose(got[key], want[key], err_msg=key, **TOL)
        assert_allclose(mod.P, twin.P, **TOL)


@pytest.mark.parametrize(("kind", "why"), [(KalmanFilter, "non-finite output"),
                                         (AugmentedEkf, "raised ValueError")])
def test_a_filter_lane_whose_covariance_broke_fails_alone(kind, why) -> None:
    """A NaN covariance: numpy's inverse gives NaN (a non-finite estimate), scipy's raises
    (filterpy's EKF); only that lane fails, the others go on as their twins."""
    name = kind.__name__
    twins = [kind(name, p, module_rng(s, name)) for p, s in zip(KALMANS, SEEDS, strict=True)]
    batched = lane_module([kind(name, p, module_rng(s, name))
                           for p, s in zip(KALMANS, SEEDS, strict=True)])
    rng = np.random.default_rng(2)
    for k in range(12):
        if k == 8:
            batched.store(ALL)
            for m in (batched.modules[1], twins[1]):
                m.P = np.full_like(m.P, math.nan)
            batched.load(ALL)
        per_run = [{**_kalman_inputs(rng, k, i), "measurement": 50.0} for i in range(4)]
        got = batched.step(k * DT, DT, _lane_inputs(per_run), ALL)
        for i in range(4):
            if k >= 8 and i == 1:
                assert batched.failed == {1: why}
                if kind is AugmentedEkf:
                    with pytest.raises(ValueError):
                        twins[1].step(k * DT, DT, per_run[1])
                else:
                    assert not np.isfinite(twins[1].step(k * DT, DT, per_run[1])["estimate"]).all()
                continue
            want = twins[i].step(k * DT, DT, per_run[i])["estimate"]
            _same(got["estimate"][i] if want is not None else None, want, f"{k} {i}")
        batched.failed.clear()


# ---------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def motor_drive():
    return load_architecture(data_dir("architectures") / "motor_drive.yaml").arch


def test_every_motor_drive_type_is_batched(motor_drive) -> None:
    from archself.lanes.batching import batched_types

    assert batched_types(motor_drive)


@pytest.mark.parametrize("scenario", ["nominal", "tacho_drift", "drive_loss", "drift_then_drive",
                                      "both_drives_weak"])
def test_adaptive_motor_drive_lanes_are_the_per_run_runs(motor_drive, scenario) -> None:
    """The same switches (times, configurations, actions) and errors as per run."""
    from archself.runtime import MapeK

    seeds = [1, 2]
    lanes = simulate_lanes(motor_drive, scenario, seeds, adapt=True)
    for got, seed in zip(lanes, seeds, strict=True):
        want = simulate(motor_drive, scenario, seed=seed, adapt=MapeK(motor_drive))
        assert got.switches == want.switches
        assert got.final_configuration == want.final_configuration
        for key, val in want.metrics.items():
            assert_allclose(got.metrics[key], val, rtol=0, atol=1e-9, err_msg=key)
        for key, val in want.series.items():
            assert_allclose(got.series[key], val, rtol=0, atol=1e-9, err_msg=key)
