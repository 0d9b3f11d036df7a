"""The diff-drive pack's batched physical modules, planner and model nodes (issue 16).

Each batched class (:mod:`archself_diffdrive.lanes_physical`) steps N = 5 lanes built
from per-run instances with other parameters and seeds; per-run twins (the same
parameters and seeds) step lane by lane with the same inputs, absent lanes (NaN rows)
and absent signals (None) included, and every output, residual signal and stored
state must agree to 1e-12 (the only differences allowed are ``np.sin``/``np.cos``
against :mod:`math` in the last bit). Some steps run a lane subset only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose

from archself.lanes import ALL, lane_module, row, simulate_lanes, stack
from archself.model.loader import load_architecture
from archself.resources import data_dir
from archself.sim.run import simulate
from archself.system.live import module_rng
from archself_diffdrive.models import ActuatorModel, DiffDriveKinematicsModel
from archself_diffdrive.physical import DiffDrivePlant, Gps, Imu, WheelActuator, WheelEncoders
from archself_diffdrive.planner import SplinePlanner

DT = 0.05
STEPS = 50
SEEDS = (11, 12, 13, 14, 15)
SUBSET = np.array([0, 3])
SUBSET_STEPS = frozenset({7, 8, 20, 33})  # steps that advance lanes 0 and 3 only
TOL = {"rtol": 0, "atol": 1e-12}


def _twins(kind: type, name: str, params: list[dict]) -> tuple[list, list]:
    """Two sets of per-run instances with the same parameters and seeds."""
    def build() -> list:
        return [kind(name, p, module_rng(s, name)) for p, s in zip(params, SEEDS, strict=True)]

    return build(), build()


def _same(got: Any, want: Any, what: str) -> None:
    """Two lane values agree (None and an all-NaN array both mean absent everywhere)."""
    if got is None and want is None:
        return
    if type(want) is list or type(got) is list:
        assert got == want, what
        return
    ref = np.asarray(want if want is not None else got, dtype=float)
    g = np.full(ref.shape, math.nan) if got is None else np.asarray(got, dtype=float)
    w = np.full(ref.shape, math.nan) if want is None else ref
    assert_allclose(g, w, err_msg=what, **TOL)


def _absent(rng: np.random.Generator, value: np.ndarray, p: float = 0.2) -> np.ndarray:
    """``value`` with random lanes absent (NaN rows)."""
    out = value.copy()
    out[rng.random(len(out)) < p] = math.nan
    return out


def _run(
    kind: type,
    name: str,
    params: list[dict],
    inputs: Callable[[np.random.Generator, int, int], dict[str, Any]],
    state: Callable[[Any], list[Any]] = lambda m: [],
    steps: int = STEPS,
    t0: float = 0.0,
) -> tuple[Any, list]:
    """Step the batched class and the per-run twins with the same inputs; compare all."""
    twins, mods = _twins(kind, name, params)
    batched = lane_module(mods)
    assert type(batched).__module__.startswith("archself_diffdrive.lanes_")  # batched
    rng = np.random.default_rng(99)
    for k in range(steps):
        t = t0 + k * DT
        lanes = SUBSET if k in SUBSET_STEPS else ALL
        idx = np.arange(len(mods))[lanes]
        vals = inputs(rng, k, len(idx))
        if not kind.direct_feedthrough:
            want = [twins[i].output(t) for i in idx]
            got = batched.output(t, lanes)
            for key in want[0]:
                _same(got.get(key), stack([w.get(key) for w in want]), f"{key} at step {k}")
        want = [twins[i].step(t, DT, {s: row(v, j) for s, v in vals.items()})
                for j, i in enumerate(idx)]
        got = batched.step(t, DT, vals, lanes)
        for key in {*got, *(key for w in want for key in w)}:
            _same(got.get(key), stack([(w or {}).get(key) for w in want]), f"{key} at step {k}")
        sig = batched.local_signals(lanes)
        for key in kind.residual_signals:
            _same(sig[key], np.array([twins[i].local_signals()[key] for i in idx]), key)
        assert not batched.failed
    batched.store(ALL)
    for m, twin in zip(mods, twins, strict=True):
        for a, b in zip(state(m), state(twin), strict=True):
            _same(stack([a]), stack([b]), f"stored state of {name}")
    return batched, twins


# ---------------------------------------------------------------------- the plant
PLANT_MIXED = [
    {"max_wheel_speed_rad_s": 12.0, "wheel_time_constant_s": 0.1, "slip_variance_m": 1e-4,
     "lateral_noise_m_sqrt_s": 0.005, "yaw_noise_rad_sqrt_s": 0.002},
    {"wheel_base_m": 0.4, "wheel_radius_m": 0.08, "wheel_time_constant_s": 0.0,
     "slip_variance_m": 1e-3, "effectiveness": [0.7, 1.0]},  # slip only, no lag, no limit
    {"max_wheel_speed_rad_s": 8.0, "wheel_time_constant_s": 0.3, "yaw_noise_rad_sqrt_s": 0.01,
     "initial_pose": [1.0, -2.0, 0.5]},  # process noise only (yaw)
    {"max_wheel_speed_rad_s": 10.0, "wheel_time_constant_s": 0.05, "slip_variance_m": 1e-4,
     "lateral_noise_m_sqrt_s": 0.02},
    {"max_wheel_speed_rad_s": 12.0, "wheel_time_constant_s": 0.1},  # undisturbed, straight
]
PLANT_UNIFORM = [
    {"max_wheel_speed_rad_s": 12.0 - j, "wheel_time_constant_s": 0.1 + 0.02 * j,
     "slip_variance_m": 1e-4 * (j + 1), "lateral_noise_m_sqrt_s": 0.005,
     "yaw_noise_rad_sqrt_s": 0.002 * (j + 1)}
    for j in range(5)
]


def _wheel_speeds(rng: np.random.Generator, k: int, n: int) -> dict[str, Any]:
    if k == 5:
        return {"wheel_speed_left": None, "wheel_speed_right": rng.uniform(-15, 15, n)}
    left = _absent(rng, rng.uniform(-15, 15, n))
    right = _absent(rng, rng.uniform(-15, 15, n))
    if n == len(SEEDS):
        right[4] = left[4]  # the undisturbed lane drives straight (the straight-arc branch)
    return {"wheel_speed_left": left, "wheel_speed_right": right}


@pytest.mark.parametrize("params", [PLANT_MIXED, PLANT_UNIFORM], ids=["mixed", "uniform"])
def test_plant_lanes_are_the_per_run_plants(params: list[dict]) -> None:
    _run(DiffDrivePlant, "chassis", params, _wheel_speeds,
         state=lambda m: [m.pose, np.array([m.wl, m.wr])])


def test_plant_store_and_load_hand_a_lane_over() -> None:
    batched, twins = _run(DiffDrivePlant, "chassis", PLANT_MIXED, _wheel_speeds)
    batched.load(ALL)  # the round trip changes nothing
    for i in (1, 3):  # a hand-over into lanes 1 and 3 through the per-run API
        state = {"pose": [5.0, 6.0, -1.0 + i], "wheel_speeds": [2.0, -1.0]}
        batched.modules[i].import_state(state)
        twins[i].import_state(state)
    batched.load(np.array([1, 3]))
    rng = np.random.default_rng(5)
    for k in range(10):
        t = (STEPS + k) * DT
        vals = _wheel_speeds(rng, k + 10, 5)
        batched.step(t, DT, vals, ALL)
        for j, twin in enumerate(twins):
            twin.step(t, DT, {s: row(v, j) for s, v in vals.items()})
    batched.store(ALL)
    for m, twin in zip(batched.modules, twins, strict=True):
        assert_allclose(m.export_state()["pose"], twin.export_state()["pose"], **TOL)
        assert_allclose(m.export_state()["wheel_speeds"], twin.export_state()["wheel_speeds"],
                        **TOL)


# ---------------------------------------------------------------------- the wheels
WHEELS = [
    {"error_smoothing_s": 0.5, "response_time_s": 0.1},
    {"error_smoothing_s": 0.0, "response_time_s": 0.0},
    {"error_smoothing_s": 0.2, "response_time_s": 0.0},
    {"error_smoothing_s": 0.0, "response_time_s": 0.3},
    {"error_smoothing_s": 1.0, "response_time_s": 0.05},
]


WHEELS_UNIFORM = [
    {"error_smoothing_s": 0.5 + 0.1 * j, "response_time_s": 0.1 + 0.05 * j} for j in range(5)
]


def _wheel_inputs(rng: np.random.Generator, k: int, n: int) -> dict[str, Any]:
    cmd = None if k in (3, 4, 30) else _absent(rng, rng.uniform(-8, 8, (n, 2)))
    enc = None if k in (10, 30) else _absent(rng, rng.uniform(-8, 8, (n, 2)))
    return {"wheel_cmd": cmd, "encoder_speeds": enc}


@pytest.mark.parametrize(
    ("side", "wheels"),
    [("left", WHEELS), ("right", WHEELS), ("left", WHEELS_UNIFORM)],
    ids=["left-mixed", "right-mixed", "left-uniform"],
)
def test_wheel_lanes_are_the_per_run_wheels(side: str, wheels: list[dict]) -> None:
    params = [{**p, "side": side} for p in wheels]
    batched, twins = _run(
        WheelActuator, f"wheel_{side}", params, _wheel_inputs,
        state=lambda m: [m.expected, m.signals["command_error"],
                         math.nan if m.prev_cmd is None else m.prev_cmd],
    )
    assert [m.prev_cmd is None for m in batched.modules] == [m.prev_cmd is None for m in twins]


def test_wheel_store_and_load_keep_the_previous_command() -> None:
    params = [{**p, "side": "left"} for p in WHEELS]
    twins, mods = _twins(WheelActuator, "wheel_left", params)
    batched = lane_module(mods)
    batched.step(0.0, DT, {"wheel_cmd": np.array([[1.0, 2.0]] * 4 + [[math.nan] * 2])}, ALL)
    batched.store(ALL)
    assert [m.prev_cmd for m in mods] == [1.0, 1.0, 1.0, 1.0, None]
    mods[2].prev_cmd = None  # through the per-run API, then back
    batched.load(np.array([2]))
    enc = np.full((5, 2), 0.5)
    batched.step(DT, DT, {"encoder_speeds": enc, "wheel_cmd": None}, ALL)
    err = batched.local_signals(ALL)["command_error"]
    assert np.isnan(err[[2, 4]]).all() and np.isfinite(err[[0, 1, 3]]).all()


def test_wheel_lanes_of_both_sides_are_refused() -> None:
    mods = [WheelActuator("w", {"side": s}, module_rng(1, "w")) for s in ("left", "right")]
    with pytest.raises(ValueError, match="same side"):
        lane_module(mods)


# ---------------------------------------------------------------------- the sensors
def _poses(rng: np.random.Generator, k: int, n: int) -> dict[str, Any]:
    if k == 6:
        return {"pose": None}
    pose = np.column_stack([rng.uniform(-50, 50, (n, 2)), rng.uniform(-10, 10, n)])
    return {"pose": _absent(rng, pose)}


def test_encoder_lanes_are_the_per_run_encoders() -> None:
    params = [{"noise_rad_s": s} for s in (0.05, 0.0, 0.2, 0.01, 1.0)]

    def speeds(rng, k, n):
        return {"wheel_speeds": None if k == 4 else _absent(rng, rng.uniform(-12, 12, (n, 2)))}

    _run(WheelEncoders, "encoders", params, speeds)


def test_imu_lanes_are_the_per_run_imus() -> None:
    params = [{"noise_rad": s, "bias_rad": b}
              for s, b in ((0.005, 0.0), (0.0, 0.1), (0.05, -0.2), (0.01, 0.0), (3.0, 3.0))]
    _run(Imu, "imu", params, _poses)


def test_gps_lanes_fix_at_their_own_rates() -> None:
    params = [{"rate_hz": r, "noise_m": s}
              for r, s in ((1.0, 0.2), (2.0, 0.0), (0.5, 1.0), (10.0, 0.3), (3.0, 0.3))]
    batched, twins = _run(Gps, "gps", params, _poses, state=lambda m: [m.next_fix],
                          steps=4 * STEPS)
    batched.next_fix[:] = 0.0
    batched.load(ALL)  # the round trip
    assert_allclose(batched.next_fix, [m.next_fix for m in twins], **TOL)


def test_gps_lanes_that_all_fix_draw_together() -> None:
    params = [{"rate_hz": 1.0, "noise_m": 0.1 * (j + 1)} for j in range(5)]

    def poses(rng, k, n):
        return {"pose": rng.uniform(-50, 50, (n, 3))}

    _run(Gps, "gps", params, poses, state=lambda m: [m.next_fix], steps=3 * STEPS)


# ---------------------------------------------------------------------- planner and models
PATH = [[0, 0], [3, 0], [6, 2], [8, 5]]
OTHER = [[0, 0], [2, 1], [4, 0]]
PLANNERS = {
    "by-lane": [  # five groups of lanes: the vectorized lookup
        {"waypoints": PATH, "speed_mps": 0.5},
        {"waypoints": PATH, "speed_mps": 2.0},
        {"waypoints": OTHER, "speed_mps": 0.5, "resolution_m": 0.05},
        {"waypoints": PATH, "speed_mps": 0.3},
        {"waypoints": OTHER, "speed_mps": 1.5},
    ],
    "by-group": [  # two groups: each group's reference once
        {"waypoints": PATH, "speed_mps": 0.5},
        {"waypoints": OTHER, "speed_mps": 0.5},
        {"waypoints": PATH, "speed_mps": 0.5},
        {"waypoints": PATH, "speed_mps": 0.5},
        {"waypoints": OTHER, "speed_mps": 0.5},
    ],
}


@pytest.mark.parametrize("case", PLANNERS)
def test_planner_lanes_are_the_per_run_planners(case: str) -> None:
    batched, _ = _run(SplinePlanner, "planner", PLANNERS[case], lambda rng, k, n: {},
                      steps=4 * STEPS, t0=-0.1)  # beyond the end of some paths
    assert len({*batched.start}) == 2 + (case == "by-lane")  # lanes share tables
    assert len(batched.first) == (5 if case == "by-lane" else 2)


def test_model_lanes_publish_each_lanes_object() -> None:
    for kind, key, field in ((DiffDriveKinematicsModel, "kinematics", "wheel_base_m"),
                             (ActuatorModel, "actuation", "max_wheel_speed_rad_s")):
        params = [{field: 0.5 + j} for j in range(5)]
        batched, twins = _run(kind, key, params, lambda rng, k, n: {}, steps=5)
        assert batched.output(0.0, ALL)[key] == [m.output(0.0)[key] for m in twins]
        assert [getattr(o, field) for o in batched.output(0.0, SUBSET)[key]] == [0.5, 3.5]


# ---------------------------------------------------------------------- whole runs
@pytest.mark.parametrize(("scenario", "configuration"), [("nominal", "a1"), ("combined", "a3")])
def test_whole_runs_in_lanes_are_the_per_run_runs(scenario: str, configuration: str) -> None:
    arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
    lanes = simulate_lanes(arch, scenario, [1, 2, 3], configuration=configuration)
    for got, seed in zip(lanes, (1, 2, 3), strict=True):
        want = simulate(arch, scenario, seed=seed, configuration=configuration)
        assert_allclose(got.series["J"], want.series["J"], rtol=0, atol=1e-9)
        for key in ("residual.wheel_left", "residual.wheel_right"):
            assert_allclose(got.series[key], want.series[key], rtol=0, atol=1e-9, err_msg=key)
