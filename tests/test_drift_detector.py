"""The heading-drift GLR of dead reckoning (:mod:`archself_diffdrive.drift_glr`).

Its suffix-sum algebra against the direct least squares for every onset, its
distribution on white noise (a t-statistic: N(0, 1) for one onset, the same at any
GPS noise), and the lane-batched odometry's ``drift_glr`` against the per-run one.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from archself.lanes import ALL, lane_module, stack
from archself.system.live import module_rng
from archself_diffdrive.drift_glr import DriftGlr, DriftWindows, drift_glr
from archself_diffdrive.estimators import Odometry


def _direct(t, e, moved, n, min_span, min_support, walk=0.0) -> float:
    """max over onsets of |z| by explicit templates and least squares (O(n²)); the
    numerator's variance with a random walk ``walk`` (m²/s) by its explicit covariance."""
    t, e, moved = t[:n], e[:n], moved[:n].copy()
    moved[0] = 0.0
    tau = t - t[0]
    if n < 5 or tau[-1] < min_span:
        return math.nan
    d = np.cumsum(moved[:, :2], axis=0)
    a = np.cumsum(moved[:, 2:] + np.r_[0.0, tau[:-1]][:, None] * moved[:, :2], axis=0)
    var = np.mean(np.diff(e, axis=0) ** 2) / 2.0
    brownian = np.minimum.outer(tau, tau)  # cov of a unit random walk from the first fix
    best = -math.inf
    for m in range(n):
        if tau[-1] - tau[m] < min_support:
            continue
        g = np.zeros((n, 2))
        g[m:] = (a[m:] - a[m]) - tau[m] * (d[m:] - d[m])
        g -= g.mean(axis=0)
        noise = var * (g * g).sum() + walk * np.einsum("ic,ij,jc->", g, brownian, g)
        best = max(best, abs((g * e).sum()) / math.sqrt(noise))
    return best


@pytest.mark.parametrize("walk", [0.0, 0.02])
def test_drift_glr_is_the_direct_least_squares(walk: float) -> None:
    """Irregular fix times, padded rows of different lengths, random turns; with and
    without the random walk in the noise."""
    rng = np.random.default_rng(0)
    rows, width = 6, 60
    t = np.cumsum(rng.uniform(0.5, 2.0, (rows, width)), axis=1) + 100.0
    e = rng.normal(0.0, 0.3, (rows, width, 2))
    moved = rng.normal(0.0, 0.5, (rows, width, 4))
    count = np.array([60, 31, 12, 44, 4, 20])
    span, support = np.full(rows, 5.0), np.full(rows, 3.0)
    got = drift_glr(t, e, moved, count, span, support, walk=np.full(rows, walk))
    want = [_direct(t[i], e[i], moved[i], count[i], 5.0, 3.0, walk) for i in range(rows)]
    assert math.isnan(got[4]) and math.isnan(want[4])  # fewer than 5 fixes
    assert_allclose(got, want, rtol=1e-9)


def test_sliding_windows_and_their_rebased_origin_stay_the_direct_least_squares() -> None:
    """Fixes dropped from the window and the time origin moved (every two windows): at
    every fix of 400, each lane's value is that of its window's fixes taken afresh (lane
    2 with a random walk in its noise)."""
    rng = np.random.default_rng(4)
    lanes, fixes = 3, 400
    windows = np.array([20.0, 35.0, 12.0])
    walks = np.array([0.0, 0.0, 0.05])
    w = DriftWindows(lanes, capacity=4)
    w.window_s[:], w.min_span_s[:], w.min_support_s[:] = windows, 5.0, 2.0
    w.walk[:] = walks
    t = np.cumsum(rng.uniform(0.5, 1.5, (lanes, fixes)), axis=1) + 1e4  # far from 0
    e = rng.normal(0.0, 0.3, (lanes, fixes, 2)) + np.linspace(0, 40, fixes)[None, :, None]
    moved = rng.normal(0.0, 0.5, (lanes, fixes, 4))  # (since the lane's previous fix)
    origins = set()
    for j in range(fixes):
        idx = np.arange(lanes) if j % 7 else np.array([0, 2])  # lane 1 misses some fixes
        w.add(t[idx, j], idx, e[idx, j], moved[idx, j])
        origins.update(w.origin.tolist())
        if j % 5:
            continue
        for i in idx:
            got = w.value(np.array([i]))[0]
            keep = (t[i, : j + 1] > t[i, j] - windows[i]) & ((np.arange(j + 1) % 7 > 0) | (i != 1))
            sel = np.flatnonzero(keep)
            want = _direct(t[i, sel], e[i, sel], moved[i, sel], len(sel), 5.0, 2.0, walks[i])
            assert_allclose(got, want, rtol=1e-9, err_msg=f"lane {i}, fix {j}")
    assert len(origins) > 3 * lanes  # the origins moved


def _white(rng, lanes: int, n: int, sigma: float):
    t = np.broadcast_to(np.arange(float(n)), (lanes, n))
    e = rng.normal(0.0, sigma, (lanes, n, 2))
    heading = np.cumsum(rng.normal(0.0, 0.05, (lanes, n)), axis=1)
    moved = np.zeros((lanes, n, 4))
    moved[:, :, 0], moved[:, :, 1] = 0.5 * np.sin(heading), -0.5 * np.cos(heading)
    moved[:, :, 2:] = 0.5 * moved[:, :, :2]
    return t, e, moved


def test_on_white_noise_one_onset_is_standard_normal_at_any_noise() -> None:
    """Only the window's start as onset: |z| of N(0, 1) (σ̂ from 119 differences)."""
    rng = np.random.default_rng(1)
    lanes, n = 4000, 120
    t, e, moved = _white(rng, lanes, n, 0.2)
    count, span = np.full(lanes, n), np.full(lanes, 20.0)
    z = drift_glr(t, e, moved, count, span, np.full(lanes, n - 1.0))
    assert_allclose(np.mean(z * z), 1.0, atol=0.08)  # sd of the mean: 0.022
    assert_allclose(np.mean(z > 1.96), 0.05, atol=0.012)  # sd: 0.0034
    assert_allclose(np.quantile(z, 0.99), 2.576, atol=0.2)
    # twice the GPS noise: the same statistic (σ̂ is measured from the fixes)
    assert_allclose(drift_glr(t, 2.0 * e, moved, count, span, np.full(lanes, n - 1.0)), z,
                    rtol=1e-12)
    # every onset: the maximum is larger, but little (neighbouring onsets' templates are
    # nearly the same test): median 1.2 against 0.67, 99 % quantile 3.0 against 2.6
    every = drift_glr(t, e, moved, count, span, np.full(lanes, 5.0))
    assert (every >= z - 1e-12).all()
    assert_allclose(np.quantile(every, [0.5, 0.99]), [1.2, 3.0], atol=0.15)


def test_with_a_random_walk_in_the_innovation_the_walk_term_keeps_it_standard_normal() -> None:
    """Dead reckoning wanders (slip): the innovation is the GPS's white noise plus a
    random walk. Counted as noise (``walk`` = its intensity), the one-onset statistic is
    N(0, 1) again; left out, its spread is too wide, the more so the lower the GPS
    noise — which is what made the fault-free level depend on it."""
    rng = np.random.default_rng(5)
    lanes, n, q = 4000, 120, 2.5e-5  # the robot's walk: 0.005 m/√s
    t, white, moved = _white(rng, lanes, n, 0.2)
    walk = np.cumsum(rng.normal(0.0, math.sqrt(q), (lanes, n, 2)), axis=1)
    count, span, one = np.full(lanes, n), np.full(lanes, 20.0), np.full(lanes, n - 1.0)
    for sigma, inflated in ((0.2, 1.5), (0.4, 1.1)):
        e = white * (sigma / 0.2) + walk
        plain = drift_glr(t, e, moved, count, span, one)
        counted = drift_glr(t, e, moved, count, span, one, walk=np.full(lanes, q))
        assert_allclose(np.mean(counted**2), 1.0, atol=0.08)
        assert np.mean(plain**2) > inflated  # 2.0 at 0.2 m, 1.25 at 0.4 m
        assert (np.abs(counted) <= np.abs(plain) + 1e-12).all()


def test_a_drift_on_a_curve_stands_out_of_the_noise() -> None:
    """A 2.8·10⁻³ rad/s drift from t = 60 s on a curving path, 0.2 m noise, 120 s window."""
    rng = np.random.default_rng(2)
    glr = DriftGlr(120.0, 20.0, 5.0)
    x = y = th = 0.0
    off = np.zeros(2)
    values = []
    for k in range(1, 2401):  # 120 s in 0.05 s steps, a fix every second
        s = 0.05 * k
        th += 0.1 * math.sin(0.05 * s) * 0.05
        dx, dy = 0.025 * math.cos(th), 0.025 * math.sin(th)
        x, y = x + dx, y + dy
        glr.move(s, dx, dy)
        beta = 2.8e-3 * max(s - 60.0, 0.0)
        off += beta * np.array([dy, -dx])  # the true position falls off the odometry's
        if k % 20 == 0:
            e = off + rng.normal(0.0, 0.2, 2)
            glr.add(s, float(e[0]), float(e[1]))
            values.append(glr.value())
    assert math.isnan(values[0]) and np.nanmax(values[:60]) < 4.0  # before the onset
    assert values[-1] > 10.0


def test_odometry_lanes_give_the_per_run_drift_glr() -> None:
    """Five lanes with other windows, a hand-over and a lane-subset step: within 1e-9."""
    params = [
        {"drift_window_s": 20.0, "drift_min_span_s": 5.0, "drift_min_support_s": 2.0},
        {"drift_window_s": 12.0, "drift_min_span_s": 6.0, "drift_min_support_s": 1.0},
        {"drift_window_s": 30.0, "drift_min_span_s": 8.0, "drift_min_support_s": 3.0},
        {},
        {"drift_window_s": 15.0, "drift_min_span_s": 5.0, "drift_min_support_s": 4.0},
    ]

    def build() -> list[Odometry]:
        return [Odometry("odometry", p, module_rng(20 + i, "odometry"))
                for i, p in enumerate(params)]

    twins, mods = build(), build()
    batched = lane_module(mods)
    rng = np.random.default_rng(3)
    dt, subset = 0.05, np.array([0, 3])
    pos = np.zeros((5, 2))
    finite = 0
    for k in range(1200):
        t = k * dt
        if k == 600:  # a hand-over into lane 2: the window starts anew
            state = {"pose": np.array([1.0, 2.0, 0.5])}
            twins[2].import_state(state)
            batched.store(np.array([2]))
            mods[2].import_state(state)
            batched.load(np.array([2]))
        lanes = subset if k % 97 == 5 else ALL
        idx = np.arange(5)[lanes]
        per_run = []
        for i in idx:
            pos[i] += 0.025 * np.array([math.cos(0.02 * t + i), math.sin(0.02 * t + i)])
            fix = k % 20 == 3 and not (i == 4 and k % 60 == 23)
            per_run.append({
                "encoder_speeds": np.array([5.0, 5.0 + 0.1 * i]) + rng.normal(0, 0.05, 2),
                "heading": 0.02 * t + i + 1e-3 * max(t - 20.0, 0.0) + rng.normal(0, 0.005),
                "position": pos[i] + rng.normal(0, 0.2, 2) if fix else None,
            })
        lane_in = {key: stack([p[key] for p in per_run]) for key in per_run[0]}
        batched.step(t, dt, lane_in, lanes)
        for i, p in zip(idx, per_run, strict=True):
            twins[i].step(t, dt, p)
        got = batched.local_signals(lanes)["drift_glr"]
        want = [twins[i].local_signals()["drift_glr"] for i in idx]
        assert_allclose(got, want, rtol=1e-9, atol=1e-12, err_msg=f"step {k}")
        finite += int(np.isfinite(got).sum())
    assert finite > 2000
    batched.store(ALL)
    for mod, twin in zip(mods, twins, strict=True):
        assert mod.drift.times() == twin.drift.times()
        got, want = mod.drift.windows, twin.drift.windows
        assert_allclose(got.total, want.total, rtol=1e-12)
        assert_allclose(got.origin, want.origin, rtol=0)
        assert_allclose(mod.drift.moved, twin.drift.moved, rtol=0, atol=1e-12)


def _drifting_odometry(rate: float, onset: float, duration: float, seed: int = 0) -> Odometry:
    """Dead reckoning driving straight at 0.5 m/s on a gyro whose bias ramps at ``rate``
    from ``onset``; the GPS (1 Hz, 0.2 m) sees the true position."""
    rng = np.random.default_rng(seed)
    odo = Odometry("odo", {}, module_rng(seed, "odo"))
    speed = 5.0  # rad/s of both wheels: 0.5 m/s
    x = 0.0
    dt = 0.05
    for k in range(int(round(duration / dt)) + 1):
        t = k * dt
        x = 0.5 * t
        bias = rate * max(t - onset, 0.0)
        inputs = {"encoder_speeds": np.array([speed, speed]), "heading": bias}
        if k % 20 == 0:
            inputs["position"] = np.array([x, 0.0]) + rng.normal(0.0, 0.2, 2)
        odo.step(t, dt, inputs)
    return odo


def test_drift_fit_recovers_the_rate_onset_and_position_error() -> None:
    odo = _drifting_odometry(rate=2.8e-3, onset=20.0, duration=70.0)
    z, rate, rate_std, onset, error, bias, bias_std = odo.drift.estimate()
    assert abs(z) > 6.0
    # the heading error's standard error covers the onsets the data cannot tell apart
    # (seeds 0–7: best onsets 16–22 s, all within one standard error); the rate is the
    # slowest of them (seeds 0–7: 0.64–0.84 of the true rate), known to half its size
    assert_allclose(rate_std, 0.5 * rate, rtol=1e-12)
    assert 0.5 * 2.8e-3 < rate < 2.8e-3
    assert_allclose(onset, 20.0, atol=5.0)
    assert abs(bias - 2.8e-3 * (odo.drift.last - 20.0)) < 2.0 * bias_std
    # the odometry runs off to the left of the true (y = 0) line: GPS − odometry
    assert_allclose(error, [0.0 - odo.x + 0.5 * 70.0, -odo.y], atol=0.15)


@pytest.mark.parametrize("seed", range(8))
def test_a_drift_just_found_hands_over_an_honest_heading_error(seed: int) -> None:
    """26 s after the onset (z 4.4–5.9, about where the loop alarms) the best onset
    lies anywhere from 0 to 30 s, and the heading error ``rate·(t − onset)`` from
    0.035 to 0.16 rad for a true 0.073 rad: its standard error must say so, or the
    estimator taking over trusts a heading two or three times too far off (the
    robustness matrix had such a run: 1.15 m after the switch, 0.55 m with this). The
    best onset's rate is worse still; the slowest rate of the set is handed over."""
    odo = _drifting_odometry(rate=2.8e-3, onset=20.0, duration=46.0, seed=seed)
    z, rate, rate_std, onset, error, bias, bias_std = odo.drift.estimate()
    true_bias = 2.8e-3 * (odo.drift.last - 20.0)
    assert abs(z) > 4.0
    assert abs(bias - true_bias) < 2.0 * bias_std
    # the best onset's rate spans 0.8–10·10⁻³ rad/s here; the slowest of the set is
    # never much faster than the true one (0.23–1.04 of it)
    assert 0.0 < rate < 1.2 * 2.8e-3
    state = odo.export_state()
    assert_allclose(state["imu_bias_std"], bias_std, rtol=1e-12)
    assert_allclose([state["imu_bias_rate"], state["imu_bias_rate_std"]], [rate, rate_std],
                    rtol=1e-12)
    # the heading is as unsure as the bias taken off it
    assert_allclose(state["covariance"][2, 2], odo.covariance()[2, 2] + bias_std**2, rtol=1e-12)


def test_odometry_hands_a_found_drift_over_as_imu_bias() -> None:
    odo = _drifting_odometry(rate=2.8e-3, onset=20.0, duration=70.0)
    state = odo.export_state()
    true_bias = 2.8e-3 * (odo.drift.last - 20.0)
    assert_allclose(state["imu_bias"], true_bias, atol=2 * state["imu_bias_std"])
    assert 0.5 * 2.8e-3 < state["imu_bias_rate"] < 2.8e-3  # the slowest likely rate
    assert_allclose(state["pose"][2], odo.th - state["imu_bias"], atol=1e-12)  # heading = IMU − b
    assert abs(state["pose"][1]) < 0.15 < abs(odo.y)  # back on the line the GPS sees
    quiet = _drifting_odometry(rate=0.0, onset=0.0, duration=70.0).export_state()
    assert quiet["imu_bias"] == 0.0 and "imu_bias_std" not in quiet  # nothing found


def test_ekf_starts_at_least_as_unsure_as_the_handed_over_bias() -> None:
    from archself_diffdrive.estimators import Ekf

    ekf = Ekf("ekf", {}, module_rng(0, "ekf"))
    prior = ekf.P.copy()
    ekf.import_state({"pose": np.zeros(3), "imu_bias": 0.1, "imu_bias_std": 1.0,
                      "imu_bias_rate": 0.01, "imu_bias_rate_std": 1e-9})
    assert_allclose(ekf.x[3:], [0.1, 0.01])
    assert_allclose(ekf.P[3, 3], 1.0)  # wider than the prior: taken
    assert_allclose(ekf.P[4, 4], prior[4, 4])  # surer than the prior: the prior stays


def test_a_repeated_fix_is_not_a_measurement() -> None:
    """A stuck receiver repeats its last fix: the odometry's windows skip it (per run and
    lanes), so a drift test is not fed a robot running away from a frozen point."""
    def feed(odo_step, fixes):
        for k, fix in enumerate(fixes):
            odo_step(0.05 * k, {"encoder_speeds": np.array([5.0, 5.0]), "heading": 0.0,
                                "position": None if fix is None else np.array(fix)})

    fixes = [None, (0.1, 0.0), (0.1, 0.0), (0.1, 0.0), (0.2, 0.1), (0.2, 0.1), (0.25, 0.0)]
    odo = Odometry("odo", {}, module_rng(0, "odo"))
    feed(lambda t, inp: odo.step(t, 0.05, inp), fixes)
    assert [round(t, 2) for t in odo.drift.times()] == [0.05, 0.2, 0.3]
    assert len(odo.monitor.items) == len(odo.trend.items) == 3

    twins = [Odometry("odo", {}, module_rng(s, "odo")) for s in (0, 1)]
    lanes = lane_module(twins)

    def lane_step(t, inp):
        pos = inp["position"]
        rows = np.full((2, 2), math.nan) if pos is None else np.stack([pos, pos + 1.0])
        lanes.step(t, 0.05, {"encoder_speeds": stack([inp["encoder_speeds"]] * 2),
                             "heading": np.zeros(2), "position": rows}, ALL)

    feed(lane_step, fixes)
    lanes.store(ALL)
    assert [round(t, 2) for t in twins[0].drift.times()] == [0.05, 0.2, 0.3]
    assert twins[0].last_fix == (0.25, 0.0) and twins[1].last_fix == (1.25, 1.0)
