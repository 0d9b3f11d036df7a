"""The diff-drive pack's batched estimators and controllers against their per-run twins (issue 16).

Each batched class (:mod:`archself_diffdrive.lanes_estimators`,
:mod:`archself_diffdrive.lanes_control`) steps N = 5 lanes built from per-run
instances with other parameters, seeds and starting states (handed-over biases,
started and fresh lanes); per-run twins step lane by lane with the same random but
plausible inputs — absent lanes (NaN rows), absent signals (None), a GPS fix every
20 steps with some lanes absent, per-lane kinematics objects — and every output and
residual signal must agree to 1e-10. Some steps advance a lane subset only; the
stored state must be the twins' (``export_state``, the windows) and a lane loaded
from a changed instance must go on as that instance. End to end, ``simulate_lanes``
gives the per-run runs of ``architectures/diffdrive.yaml`` in a1–a3.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose

from archself.lanes import ALL, lane_module, simulate_lanes, stack
from archself.model.loader import load_architecture
from archself.resources import data_dir
from archself.sim.run import simulate
from archself.system.live import module_rng
from archself_diffdrive.controllers import AsymLqrController, LqrController
from archself_diffdrive.estimators import Ekf, InnovationTrend, InnovationWindow, Odometry
from archself_diffdrive.lanes_control import AsymLqrControllerLanes, LqrControllerLanes
from archself_diffdrive.lanes_estimators import EkfLanes, OdometryLanes
from archself_diffdrive.lanes_windows import LaneWindows
from archself_diffdrive.models import Actuation, Dynamics, Kinematics

DT = 0.05
STEPS = 100
SEEDS = (21, 22, 23, 24, 25)
SUBSET = np.array([0, 3])
SUBSET_STEPS = frozenset({5, 6, 41, 60, 61})  # steps that advance lanes 0 and 3 only
TOL = {"rtol": 0, "atol": 1e-10}
KINEMATICS = [
    Kinematics(),
    Kinematics(wheel_base_m=0.6, wheel_radius_m=0.12),
    None,  # the per-run default model
    Kinematics(wheel_base_m=0.45, wheel_radius_m=0.09),
    Kinematics(),
]


def _twins(kind: type, name: str, params: list[dict]) -> tuple[list, list]:
    """Two sets of per-run instances with the same parameters and seeds."""

    def build() -> list:
        return [kind(name, p, module_rng(s, name)) for p, s in zip(params, SEEDS, strict=True)]

    return build(), build()


def _same(got: Any, want: Any, what: str) -> None:
    """Two lane values agree (None and an all-NaN array both mean absent everywhere)."""
    if got is None and want is None:
        return
    ref = np.asarray(want if want is not None else got, dtype=float)
    g = np.full(ref.shape, math.nan) if got is None else np.asarray(got, dtype=float)
    w = np.full(ref.shape, math.nan) if want is None else ref
    assert_allclose(g, w, err_msg=what, **TOL)


def _maybe(rng: np.random.Generator, value: Any, p: float) -> Any:
    """``value``, or None with probability ``p`` (a lane without it this step)."""
    return None if rng.random() < p else value


def _run(
    kind: type,
    params: list[dict],
    inputs: Callable[[np.random.Generator, int, int, Any], dict[str, Any]],
    prepare: Callable[[list], None] = lambda mods: None,
    steps: int = STEPS,
) -> tuple[Any, list]:
    """Step the batched class and the twins with the same inputs; compare every step.

    ``inputs(rng, k, lane, twin)`` gives lane ``lane``'s per-run inputs at step ``k``;
    ``prepare`` sets the starting state of both sets of instances.
    """
    twins, mods = _twins(kind, kind.__name__.lower(), params)
    prepare(twins)
    prepare(mods)
    batched = lane_module(mods)
    assert type(batched).__name__ == f"{kind.__name__}Lanes"
    rng = np.random.default_rng(5)
    for k in range(steps):
        t = k * DT
        lanes = SUBSET if k in SUBSET_STEPS else ALL
        idx = np.arange(len(SEEDS))[lanes]
        per_run = [inputs(rng, k, int(i), twins[i]) for i in idx]
        lane_in = {key: stack([p.get(key) for p in per_run]) for key in per_run[0]}
        got = batched.step(t, DT, lane_in, lanes)
        want = [twins[i].step(t, DT, p) for i, p in zip(idx, per_run, strict=True)]
        for key in want[0]:
            _same(got.get(key), stack([w[key] for w in want]), f"step {k} {key}")
        sigs = batched.local_signals(lanes)
        for key in kind.residual_signals:
            expect = [twins[i].local_signals()[key] for i in idx]
            assert_allclose(sigs[key], expect, err_msg=f"step {k} {key}", **TOL)
        assert not batched.failed
    return batched, twins


def _same_state(a: dict, b: dict) -> None:
    assert set(a) == set(b)
    for key, val in b.items():
        if isinstance(val, (float, int, np.ndarray)):
            assert_allclose(a[key], val, err_msg=key, **TOL)
        else:
            assert a[key] == val, key


# ---------------------------------------------------------------------- estimators
def _estimator_inputs(rng, k, lane, twin) -> dict[str, Any]:
    # a fix every 20 steps; none ever in lane 2, every third one missing in lane 4
    fix = k % 20 == 3 and lane != 2 and not (lane == 4 and k % 60 == 23)
    speed = 5.0 + 0.5 * lane
    return {
        "encoder_speeds": _maybe(rng, np.array([speed, speed + 0.3]) + rng.normal(0, 0.05, 2),
                                 0.05),
        "heading": _maybe(rng, 0.03 * k * DT + 0.4 * lane + rng.normal(0, 0.005), 0.1),
        "kinematics": None if k == 50 else KINEMATICS[lane],  # k = 50: no lane has one
        "position": np.array([0.5 * k * DT, 0.1 * lane]) + rng.normal(0, 0.3, 2) if fix
        else None,
    }


def _estimator_windows(lane: Any, twin: Any, names: tuple[str, ...]) -> None:
    for name in names:
        a, b = getattr(lane, name), getattr(twin, name)
        assert_allclose(np.array(a.items).reshape(-1, 3), np.array(b.items).reshape(-1, 3),
                        **TOL)
        for attr in ("sx", "sy", "start", "last"):
            assert getattr(a, attr, None) == pytest.approx(getattr(b, attr, None), abs=1e-10)


def test_lane_windows_keep_the_per_run_windows() -> None:
    """Irregular fixes (gaps drop several items at once), a window per lane, buffers grown."""
    windows = (2.0, 5.0, 11.0)
    monitors = [InnovationWindow(w) for w in windows]
    trends = [InnovationTrend(w) for w in windows]
    lanes = LaneWindows(len(windows), capacity=2)
    lanes.window[:] = windows
    rng = np.random.default_rng(1)
    t = 0.0
    for k in range(200):
        t += 1.0 if k % 37 else 6.0
        idx = np.flatnonzero(rng.random(len(windows)) < 0.8)
        e = rng.normal(0.02 * k, 0.3, (len(idx), 2))
        lanes.add(t, idx, e)
        for i, (ex, ey) in zip(idx, e.tolist(), strict=True):
            monitors[i].add(t, ex, ey)
            trends[i].add(t, ex, ey)
        assert_allclose(lanes.mean_norm(idx), [monitors[i].value() for i in idx], **TOL)
        assert_allclose(lanes.trend(idx), [trends[i].value() for i in idx], **TOL)
    assert lanes.t.shape[1] >= 8
    for i, (monitor, trend) in enumerate(zip(monitors, trends, strict=True)):
        t, v, *_ = lanes.get(i)
        items = [(a, *b) for a, b in zip(t, v.tolist(), strict=True)]
        assert items == list(monitor.items) == list(trend.items)
        assert tuple(lanes.sums[i]) == (monitor.sx, monitor.sy)


def _hand_over(mods: list) -> None:
    """Lanes 1, 3 and 4 take a handed-over state (a significant bias in lane 1 only)."""
    mods[1].import_state({"pose": np.array([1.0, -2.0, 0.3]), "covariance": np.eye(3) * 0.2,
                          "imu_bias": 0.05, "imu_bias_std": 0.01,
                          "imu_bias_rate": 1e-3, "imu_bias_rate_std": 1e-4})
    mods[3].import_state({"pose": np.array([0.0, 1.0, -0.2]), "imu_bias": 0.02,
                          "imu_bias_std": 0.05, "imu_bias_rate": 2e-3})
    mods[4].import_state({"imu_bias": 0.01, "imu_bias_rate": 1e-3})  # not started: no pose


ODOMETRY = [
    {},
    {"encoder_noise_rad_s": 0.1, "heading_noise_rad": 0.01, "innovation_window_s": 4.0,
     "trend_window_s": 8.0},
    {"trend_window_s": 5.0},
    {"innovation_window_s": 2.0, "trend_window_s": 6.0, "bias_significance": 1.0},
    {"encoder_noise_rad_s": 0.02, "trend_window_s": 8.0},
]


def test_odometry_lanes_equal_the_per_run_odometry() -> None:
    batched, twins = _run(Odometry, ODOMETRY, _estimator_inputs, _hand_over, 2 * STEPS)
    assert isinstance(batched, OdometryLanes)
    # significance: lane 1 took its bias, lane 3 only its rate (its bias was within 1 σ)
    assert twins[1].bias > 0.05 and twins[3].bias == pytest.approx(2e-3 * 2 * STEPS * DT)
    assert np.isfinite(batched.local_signals(ALL)["innovation_trend"]).sum() == 3
    batched.store(ALL)
    for mod, twin in zip(batched.modules, twins, strict=True):
        _same_state(mod.export_state(), twin.export_state())
        _estimator_windows(mod, twin, ("monitor", "trend"))
        assert mod.started and mod.signals == pytest.approx(twin.signals, nan_ok=True)


EKF = [
    {},
    {"q_position_m": 0.05, "r_gps_m": 0.5, "innovation_window_s": 3.0},
    {"q_bias_rad": 0.01, "q_bias_rate_rad_s": 1e-4, "r_heading_rad": 0.01},
    {"encoder_noise_rad_s": 0.1, "initial_heading_std_rad": 0.2, "innovation_window_s": 2.0},
    {"q_heading_rad": 0.02, "r_gps_m": 0.1, "innovation_window_s": 6.0},
]


def test_ekf_lanes_equal_the_per_run_ekf() -> None:
    batched, twins = _run(Ekf, EKF, _estimator_inputs, _hand_over, 2 * STEPS)
    assert isinstance(batched, EkfLanes)
    assert np.isfinite(batched.local_signals(ALL)["innovation"]).sum() == 3
    batched.store(ALL)
    for mod, twin in zip(batched.modules, twins, strict=True):
        _same_state(mod.export_state(), twin.export_state())
        assert_allclose(mod.P, twin.P, **TOL)
        _estimator_windows(mod, twin, ("monitor",))


def test_an_ekf_lane_whose_update_raises_is_reported_alone() -> None:
    """A covariance gone NaN: the per-run GPS update raises; only that lane fails."""
    twins, mods = _twins(Ekf, "ekf", EKF)
    for m in (twins[1], mods[1]):
        m.P = np.full((5, 5), math.nan)
    batched = lane_module(mods)
    per_run = [{"heading": 0.1, "position": np.array([0.2, 0.0])} for _ in SEEDS]
    got = batched.step(0.0, DT, {k: stack([p[k] for p in per_run]) for k in per_run[0]}, ALL)
    assert batched.failed == {1: "raised ValueError"}
    with pytest.raises(ValueError):
        twins[1].step(0.0, DT, per_run[1])
    for i in (0, 2, 3, 4):
        want = twins[i].step(0.0, DT, per_run[i])["pose_estimate"]
        assert_allclose(got["pose_estimate"][i], want, **TOL)
        assert_allclose(batched.local_signals(ALL)["innovation"][i], twins[i].signals["innovation"],
                        **TOL)


def test_a_lane_loaded_from_its_instance_goes_on_from_that_state() -> None:
    """A hand-over into one lane's instance (the per-run API), then load: that lane restarts."""
    for kind, params in ((Odometry, ODOMETRY), (Ekf, EKF)):
        twins, mods = _twins(kind, "est", params)
        batched = lane_module(mods)
        rng = np.random.default_rng(3)
        for k in range(30):
            per_run = [_estimator_inputs(rng, k, i, None) for i in range(len(SEEDS))]
            lane_in = {key: stack([p[key] for p in per_run]) for key in per_run[0]}
            batched.step(k * DT, DT, lane_in, ALL)
            for twin, p in zip(twins, per_run, strict=True):
                twin.step(k * DT, DT, p)
        batched.store(np.array([2]))
        state = {"pose": np.array([3.0, 4.0, 1.0]), "covariance": np.eye(3), "imu_bias": 0.1}
        mods[2].import_state(state)
        twins[2].import_state(state)
        batched.load(np.array([2]))
        p = _estimator_inputs(rng, 31, 2, None)
        got = batched.step(31 * DT, DT, {k: stack([v]) for k, v in p.items()}, np.array([2]))
        assert_allclose(got["pose_estimate"][0], twins[2].step(31 * DT, DT, p)["pose_estimate"],
                        **TOL)


# ---------------------------------------------------------------------- controllers
DYNAMICS = [Dynamics(), Dynamics(wheel_time_constant_s=0.2), Dynamics(wheel_time_constant_s=0.3),
            Dynamics(), None]
ACTUATION = [Actuation(), Actuation(max_wheel_speed_rad_s=4.0), None,
             Actuation(max_wheel_speed_rad_s=5.5), Actuation()]


def _controller_inputs(rng, k, lane, twin) -> dict[str, Any]:
    speed = 0.5 if k < 40 else (0.3 + 0.1 * lane if k < 70 else 0.5003)
    still = lane == 3 and k < 10  # at rest on the reference: zero commands (no adaptation)
    if still:
        speed = 0.0
    s = k * DT * speed
    ref = np.array([s, 0.05 * lane, 0.02 * lane, speed, 0.0 if still else 0.1 * math.sin(0.1 * k)])
    est = ref[:3] + (0.0 if still else rng.normal(0, [0.05, 0.05, 0.02]))
    last = twin.last_cmd if twin is not None else None
    enc = None if last is None else last * (0.25 if lane == 1 else 1.0) + rng.normal(0, 0.05, 2)
    absent = k == 0 or (lane == 4 and k in (1, 2, 30))  # lane 4 repeats its last command
    return {
        "reference": None if absent else ref,
        "pose_estimate": None if absent else _maybe(rng, est, 0.05),
        "kinematics": KINEMATICS[lane],
        "dynamics": DYNAMICS[lane] if lane != 1 or k < 10 else None,  # lane 1 keeps its model
        "actuation": ACTUATION[lane],
        "encoder_speeds": _maybe(rng, enc, 0.05),
    }


LQR = [
    {},
    {"q_lateral": 0.01, "q_heading": 0.5},
    {"q_along": 4.0, "r_turn": 0.5},
    {"q_lateral": 0.001, "q_heading": 0.05, "design_speed_mps": 0.3},
    {"r_speed": 2.0},
]


@pytest.mark.parametrize("kind", [LqrController, AsymLqrController])
def test_controller_lanes_equal_the_per_run_controllers(kind) -> None:
    params = [
        {**p, "adaptation_time_s": 1.0 + i, "min_effectiveness": 0.3 + 0.1 * i}
        if kind is AsymLqrController else p
        for i, p in enumerate(LQR)
    ]
    batched, twins = _run(kind, params, _controller_inputs)
    assert isinstance(batched, AsymLqrControllerLanes if kind is AsymLqrController
                      else LqrControllerLanes)
    if kind is AsymLqrController:
        assert twins[1].effectiveness.min() == pytest.approx(0.4)  # adapted, clipped
    # gains refreshed per lane (0.3–0.7 m/s in steps 40–69), not for a change under 5 mm/s
    assert {t.v_ref for t in twins} == {0.5, 0.5003}
    batched.store(ALL)
    for mod, twin in zip(batched.modules, twins, strict=True):
        _same_state(mod.export_state(), twin.export_state())
        assert_allclose(mod.linearization(), twin.linearization(), **TOL)
        assert_allclose(mod.last_cmd, twin.last_cmd, **TOL)
        if kind is AsymLqrController:
            assert mod._sent == pytest.approx(twin._sent, abs=1e-10)
            assert_allclose([mod._num, mod._den], [twin._num, twin._den], **TOL)


# ---------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def diffdrive():
    return load_architecture(data_dir("architectures") / "diffdrive.yaml").arch


@pytest.mark.parametrize("scenario", ["nominal", "imu_drift"])
@pytest.mark.parametrize("configuration", ["a1", "a2", "a3"])
def test_simulate_lanes_gives_the_per_run_runs(diffdrive, configuration, scenario) -> None:
    seeds = [1, 2, 3]
    lanes = simulate_lanes(diffdrive, scenario, seeds, configuration=configuration)
    for got, seed in zip(lanes, seeds, strict=True):
        want = simulate(diffdrive, scenario, seed=seed, configuration=configuration)
        assert_allclose(got.series["J"], want.series["J"], rtol=0, atol=1e-9)
        for key, val in want.metrics.items():
            assert_allclose(got.metrics[key], val, rtol=0, atol=1e-9, err_msg=key)
        for key in ("estimate", "command", *(k for k in want.series if k.startswith("resid"))):
            assert_allclose(got.series[key], want.series[key], rtol=0, atol=1e-9, err_msg=key)
