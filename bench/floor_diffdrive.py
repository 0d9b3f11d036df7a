"""A hand-written floor for the diff-drive a1 fixed run (issue 16 item 1).

The run of ``archself simulate architectures/diffdrive.yaml --scenario nominal --fixed
--config a1`` written out as one plain loop: no framework, no ``RuntimeModule``, no
executor. The same plant (wheel-speed lag, speed limit, wheel slip, lateral and yaw
noise: ``packs/archself_diffdrive/physical.py``), encoders and IMU, the spline
reference, dead reckoning and the LQR (gain from ``control.lqr`` on the same error
dynamics) with the same floating-point operations in the same order, and the same
random streams: each module draws from ``numpy.random.default_rng([seed,
blake2b-64(name)])`` (``archself.system.live.module_rng``), and a Generator's normals do not
depend on how many are drawn per call, so the floor draws each stream in blocks and
reproduces the framework's trace bit for bit (tests/test_floor.py checks it to 1e-9).

What the floor leaves out because it cannot change J: the GPS (in a1 only the
odometry's residuals read it; its stream is its own), the residual signals
(``command_error``, ``innovation``, ``innovation_trend``, ``tracking_error``), the
odometry's covariance, the model nodes (constants here) and the recording of anything
but J.

The J-only floors:

- :func:`run_floor` (one seed; Python floats, the per-run floor), and
- :func:`run_floor_lanes` (N seeds at once: every state a numpy array with a leading
  lane axis, one loop over the time steps; the "limit" of lane batching).

The same-work floors (issue 38: the GPS, every residual signal, the recording; every
recorded series bit for bit the framework's):

- :func:`run_floor_same_work` (a1, one seed), :func:`run_floor_lanes_same_work` (a1, N
  seeds), and
- :func:`run_floor_lanes_switching` (N seeds: fixed a2 with the EKF, or adaptive
  imu_drift with the framework's switches replayed and the Monitor's bands by hand).

The vectorized floors share their noise blocks, chassis and wheels' command errors
(:class:`_Noise`, :class:`_Chassis`, :class:`_WheelErrors`).

``python bench/floor_diffdrive.py`` prints, side by side, the framework's a1 fixed run
(``archself.simulate``, as bench/test_bench_sim.py), the floor's per-run time and step
cost, the vectorized floor's runs/s for N = 1, 10, 100, 1000 lanes and its memory per
lane (docs/benchmarks.md, "A hand-written floor"); ``--ratios [a1 a2 adaptive] --lanes
200 1000`` the framework's lanes against the same-work floors (docs/benchmarks.md,
"Lanes against their floors").
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # as the archself command and bench/conftest.py: before numpy
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from functools import cache  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DIFFDRIVE = ROOT / "architectures" / "diffdrive.yaml"
#: The modules of configuration a1 (the floor implements exactly these).
A1 = frozenset(
    {
        "chassis",
        "wheel_left",
        "wheel_right",
        "encoders",
        "imu",
        "gps",
        "planner",
        "odometry",
        "lqr",
        "kinematic_model",
        "dynamic_model",
        "actuator_model",
    }
)
PI = math.pi
TWO_PI = 2.0 * math.pi


def stream(seed: int, name: str) -> np.random.Generator:
    """The random stream of module ``name``: ``default_rng([seed, blake2b-64(name)])``.

    Examples
    --------
    >>> float(stream(1, "imu").standard_normal()) == float(stream(1, "imu").standard_normal())
    True
    """
    h = int.from_bytes(hashlib.blake2b(name.encode("utf-8"), digest_size=8).digest(), "little")
    return np.random.default_rng([int(seed), h])


def spline_table(waypoints: Any, ds: float) -> tuple[np.ndarray, ...]:
    """``x, y, θ, κ`` at equal arc-length steps ``ds`` of the not-a-knot cubic spline.

    The arithmetic of ``archself_diffdrive.planner.spline_path`` (chord-length
    parameter, trapezoidal arc length, resampled), so the reference is the same to the bit.
    """
    from scipy.interpolate import CubicSpline

    pts = np.asarray(waypoints, dtype=float)
    pts = pts[np.r_[True, np.hypot(*np.diff(pts, axis=0).T) > 1e-9]]
    chord = np.r_[0.0, np.cumsum(np.hypot(*np.diff(pts, axis=0).T))]
    cs = CubicSpline(chord, pts, axis=0, bc_type="not-a-knot" if len(pts) > 3 else "natural")
    u = np.linspace(0.0, chord[-1], max(2000, int(chord[-1] / ds) * 4))
    d1 = cs(u, 1)
    speed = np.hypot(d1[:, 0], d1[:, 1])
    arc = np.r_[0.0, np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(u))]
    s = np.arange(0.0, arc[-1], ds)
    s = np.r_[s, arc[-1]] if arc[-1] - s[-1] > 1e-9 else s
    us = np.interp(s, arc, u)
    xy, d1, d2 = cs(us), cs(us, 1), cs(us, 2)
    theta = np.unwrap(np.arctan2(d1[:, 1], d1[:, 0]))
    kappa = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.maximum(
        np.hypot(d1[:, 0], d1[:, 1]) ** 3, 1e-12
    )
    return xy[:, 0], xy[:, 1], theta, kappa, float(arc[-1])


def lqr_gain(v: float, q: Sequence[float], r: Sequence[float]) -> tuple[float, ...]:
    """The 2×3 gain of ``control.lqr`` on the tracking-error dynamics at speed ``v``, row by row.

    ``ė = A e + B δu`` with ``A = [[0, 0, 0], [0, 0, v], [0, 0, 0]]``, ``B = [[1, 0], [0, 0],
    [0, 1]]``, speed floored at 0.05 m/s and weights at 1e-9 (as the pack does).
    """
    import control

    v = max(float(v), 0.05)
    A = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, v], [0.0, 0.0, 0.0]])
    B = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    K, _, _ = control.lqr(A, B, np.diag([max(float(x), 1e-9) for x in q]), np.diag(r))
    return tuple(np.asarray(K, dtype=float).ravel().tolist())


@dataclass(frozen=True)
class Setup:
    """Everything of the file the a1 run needs, read once (no seed in it).

    Build it with :func:`load_setup`. ``ref`` is the reference ``[x, y, θ, v, ω]`` at
    every step's time ``k·dt`` (it depends on time only), as five float arrays, and
    ``ref_cs`` the cosine and sine of its θ (the controller's frame).
    """

    dt: float
    steps: int
    # chassis (the true geometry and disturbances)
    radius: float
    base: float
    limit: float
    tau: float
    slip: float
    lateral: float
    yaw: float
    pose0: tuple[float, float, float]
    # sensors
    enc_noise: float
    imu_noise: float
    imu_bias: float
    # the model nodes as the estimator and controller see them
    kin_radius: float
    kin_base: float
    act_limit: float
    # controller
    q: tuple[float, float, float]
    r: tuple[float, float]
    design_speed: float
    ref: tuple[np.ndarray, ...]
    ref_cs: tuple[np.ndarray, np.ndarray]
    #: the scenario's IMU heading bias drift (onset s, rad/s), or None (fault-free)
    drift: tuple[float, float] | None = None


def _value(mods: dict, module: str, key: str, default: Any) -> Any:
    spec = (mods[module].get("params") or {}).get(key)
    return default if spec is None else spec["value"]


@cache
def load_setup(path: str | Path = DIFFDRIVE, scenario: str = "nominal") -> Setup:
    """The parameters of configuration a1 and the reference of ``scenario``.

    The file is read as plain YAML; a parameter it does not set takes the pack's
    default. Raises ``ValueError`` for a scenario with faults other than one IMU heading
    drift (kept in ``drift``; only :func:`run_floor_lanes_switching` runs it) or a
    different a1.
    """
    from ruamel.yaml import YAML

    raw = YAML(typ="safe").load(Path(path).read_text(encoding="utf-8"))
    mods = raw["modules"]
    import archself  # a1 as the loader expands it (its subsystem modes and own modules)

    if set(archself.load(path).configurations["a1"].modules) != A1:
        raise ValueError("configuration a1 is not the one the floor implements")
    sc = raw["scenarios"][scenario]
    faults = sc.get("faults") or []
    drift = None
    if faults:  # an IMU heading drift alone (imu_drift): run_floor_lanes_switching runs it
        f = faults[0]
        if len(faults) > 1 or (f["module"], f["kind"]) != ("imu", "bias_drift"):
            raise ValueError(f"scenario {scenario!r} has faults the floor does not run")
        drift = (float(f["onset_s"]), float(f["magnitude"]))
    dt = float(raw["runtime"]["step_s"])
    steps = int(round(float(sc["duration_s"]) / dt))

    def v(module: str, key: str, default: Any) -> Any:
        return _value(mods, module, key, default)

    # the reference at t = k·dt (planner.spline: linear interpolation of the table)
    speed = float(v("planner", "speed_mps", 0.5))
    ds = float(v("planner", "resolution_m", 0.02))
    x, y, th, kappa, length = spline_table(v("planner", "waypoints", None), ds)
    t = np.arange(steps) * dt
    s = speed * t
    f = np.maximum(s, 0.0) / ds
    i = np.minimum(f.astype(np.int64), len(x) - 2)
    a = np.minimum(f - i, 1.0)
    b = 1.0 - a
    ref = [
        b * x[i] + a * x[i + 1],
        b * y[i] + a * y[i + 1],
        b * th[i] + a * th[i + 1],
        np.full(steps, speed),
        (b * kappa[i] + a * kappa[i + 1]) * speed,
    ]
    end = s >= length  # past the end of the path: stop there
    for arr, last in zip(ref, (x[-1], y[-1], th[-1], 0.0, 0.0), strict=True):
        arr[end] = last
    return Setup(
        dt=dt,
        steps=steps,
        radius=float(v("chassis", "wheel_radius_m", 0.1)),
        base=float(v("chassis", "wheel_base_m", 0.5)),
        limit=float(v("chassis", "max_wheel_speed_rad_s", math.inf)),
        tau=float(v("chassis", "wheel_time_constant_s", 0.1)),
        slip=float(v("chassis", "slip_variance_m", 0.0)),
        lateral=float(v("chassis", "lateral_noise_m_sqrt_s", 0.0)),
        yaw=float(v("chassis", "yaw_noise_rad_sqrt_s", 0.0)),
        pose0=tuple(float(p) for p in v("chassis", "initial_pose", [0.0, 0.0, 0.0])),
        enc_noise=float(v("encoders", "noise_rad_s", 0.05)),
        imu_noise=float(v("imu", "noise_rad", 0.005)),
        imu_bias=float(v("imu", "bias_rad", 0.0)),
        kin_radius=float(v("kinematic_model", "wheel_radius_m", 0.1)),
        kin_base=float(v("kinematic_model", "wheel_base_m", 0.5)),
        act_limit=float(v("actuator_model", "max_wheel_speed_rad_s", 12.0)),
        q=(
            float(v("lqr", "q_along", 1.0)),
            float(v("lqr", "q_lateral", 1.0)),
            float(v("lqr", "q_heading", 1.0)),
        ),
        r=(float(v("lqr", "r_speed", 1.0)), float(v("lqr", "r_turn", 1.0))),
        design_speed=float(v("lqr", "design_speed_mps", 0.5)),
        ref=tuple(ref),
        ref_cs=tuple(np.array([f(x) for x in ref[2].tolist()]) for f in (math.cos, math.sin)),
        drift=drift,
    )


def _gain(setup: Setup, v: float) -> tuple[float, ...]:
    """The LQR gain at reference speed ``v``, cached by speed rounded to 1 cm/s (as the pack)."""
    return _cached_gain(round(max(float(v), 0.05), 2), setup.q, setup.r)


@cache
def _cached_gain(v: float, q: tuple[float, ...], r: tuple[float, ...]) -> tuple[float, ...]:
    return lqr_gain(v, q, r)


def _metrics(t: np.ndarray, J: np.ndarray) -> dict[str, float]:
    """The framework's metrics of J (``archself.sim.result.error_metrics``) and its mean."""
    i = int(np.argmax(J))
    return {
        "max_error": float(J[i]),
        "final_error": float(J[-1]),
        "rms_error": float(np.sqrt(np.mean(J**2))),
        "mean_error": float(np.mean(J)),
        "peak_time_s": float(t[i]),
    }


def run_floor(seed: int, setup: Setup | None = None) -> dict[str, Any]:
    """One a1 fixed run, written out on Python floats.

    Parameters
    ----------
    seed : int
        The seed of every random stream (``archself simulate --seed``).
    setup : Setup, optional
        From :func:`load_setup` (default: architectures/diffdrive.yaml, nominal).

    Returns
    -------
    dict
        ``max_error``, ``final_error``, ``rms_error``, ``mean_error`` (m), ``peak_time_s``,
        and the series ``t`` and ``J`` (as the framework's ``RunResult.series``).

    Examples
    --------
    >>> out = run_floor(1)
    >>> 0.0 < out["max_error"] < 0.5, len(out["J"])
    (True, 8000)
    """
    S = setup or load_setup()
    n, dt = S.steps, S.dt
    # the noise of the run, drawn in one block per stream (the same numbers)
    cha = stream(seed, "chassis").standard_normal((n, 4)).tolist()  # slip l, r; lateral, yaw
    enc = stream(seed, "encoders").standard_normal((n, 2)).tolist()
    imu = stream(seed, "imu").standard_normal(n).tolist()
    rx_, ry_, rth_, rv_, rw_ = (a.tolist() for a in S.ref)
    rc_, rs_ = (a.tolist() for a in S.ref_cs)
    sin, cos, sqrt = math.sin, math.cos, math.sqrt
    # constants
    r, b, lim, slip, sig_e, sig_h = S.radius, S.base, S.limit, S.slip, S.enc_noise, S.imu_noise
    a_lag = 1.0 - math.exp(-dt / S.tau) if S.tau > 0 else 1.0
    lag = S.tau > 0
    rdt = r * dt
    sq_dt = sqrt(dt)
    kr, kb, alim = S.kin_radius, S.kin_base, S.act_limit
    v_design = S.design_speed
    k00, k01, k02, k10, k11, k12 = _gain(S, v_design)
    # state: true pose and wheel speeds, the odometry's pose
    px, py, pth = S.pose0
    wl = wr = 0.0
    ox, oy, oth = 0.0, 0.0, 0.0
    J = [0.0] * n
    for k in range(n):
        rx, ry, rth, rv, rw = rx_[k], ry_[k], rth_[k], rv_[k], rw_[k]
        dx, dy = px - rx, py - ry
        J[k] = sqrt(dx * dx + dy * dy)  # the objective of the pose published at t
        # encoders and IMU (sensor.encoders, sensor.imu)
        e = enc[k]
        el = wl + sig_e * e[0]
        er = wr + sig_e * e[1]
        h = pth + S.imu_bias + sig_h * imu[k]
        h = (h + PI) % TWO_PI - PI
        # dead reckoning (estimator.odometry; no handed-over bias in a1)
        v = kr * (el + er) / 2.0
        th0 = oth
        th1 = th0 + ((h - th0 + PI) % (2 * PI) - PI)
        if k:
            mid = 0.5 * (th0 + th1)
            ox += v * dt * cos(mid)
            oy += v * dt * sin(mid)
        oth = (th1 + PI) % (2 * PI) - PI
        # LQR (controller.lqr): gain at the reference speed, feed-forward, limit
        if abs(rv - v_design) > 0.005:
            v_design = rv
            k00, k01, k02, k10, k11, k12 = _gain(S, rv)
        dx, dy = ox - rx, oy - ry
        c, s = rc_[k], rs_[k]
        e0 = c * dx + s * dy
        e1 = -s * dx + c * dy
        e2 = (oth - rth + PI) % TWO_PI - PI
        vc = rv - (k00 * e0 + k01 * e1 + k02 * e2)
        wc = rw - (k10 * e0 + k11 * e1 + k12 * e2)
        half = wc * kb / 2.0
        cl = (vc - half) / kr
        cr = (vc + half) / kr
        peak = max(abs(cl), abs(cr))
        if peak > alim:
            cl, cr = cl * alim / peak, cr * alim / peak
        # chassis (plant.diffdrive): lag, slip, exact arc, lateral and yaw noise
        cl = min(max(cl, -lim), lim)
        cr = min(max(cr, -lim), lim)
        wl0, wr0 = wl, wr
        wl = wl0 + a_lag * (cl - wl0)
        wr = wr0 + a_lag * (cr - wr0)
        ul, ur = (0.5 * (wl0 + wl), 0.5 * (wr0 + wr)) if lag else (wl, wr)
        z = cha[k]
        ul = ul + sqrt(slip * abs(r * ul * dt)) * z[0] / rdt
        ur = ur + sqrt(slip * abs(r * ur * dt)) * z[1] / rdt
        vb = r * (ul + ur) / 2.0
        wb = r * (ur - ul) / b
        dth = wb * dt
        th2 = pth + dth
        s2, c2 = sin(th2), cos(th2)  # the arc's end, and the frame of the lateral noise
        if abs(dth) < 1e-9:
            m = pth + 0.5 * dth
            px += vb * dt * cos(m)
            py += vb * dt * sin(m)
        else:
            rad = vb / wb
            px += rad * (s2 - sin(pth))
            py -= rad * (c2 - cos(pth))
        pth = th2
        lat = S.lateral * (z[2] * sq_dt)
        px += -s2 * lat
        py += c2 * lat
        pth += S.yaw * (z[3] * sq_dt)
    t = (np.arange(n) + 1) * dt
    Ja = np.array(J)
    return {**_metrics(t, Ja), "t": t, "J": Ja}


@dataclass(frozen=True)
class Work:
    """What the a1 run does besides J, read once from the compiled modules' parameters
    (:func:`load_work`): the GPS, the residual signals, the odometry's covariance."""

    gps_period: float
    gps_noise: float
    odo_pose0: tuple[float, float, float]
    odo_var_th: float
    odo_sv: float  # wheel radius · encoder noise / √2 (the odometry's speed noise)
    windows: tuple[float, float]  # innovation, trend (s)
    drift: tuple[float, float, float, float]  # window, span, support (s), walk² (m²/s)
    wheel_response: tuple[float, float]
    wheel_smoothing: tuple[float, float]


@cache
def load_work(path: str | Path = DIFFDRIVE) -> Work:
    """The parameters :func:`run_floor_same_work` needs, as the compiled a1 modules hold them
    (the file's values and the pack's defaults)."""
    import archself
    from archself.system.live import compile_system

    arch = archself.load(path)
    system = compile_system(arch, "a1", seed=1, scenario=arch.scenarios["nominal"])
    p = {name: system.modules[name].params for name in ("gps", "odometry", "wheel_left",
                                                       "wheel_right", "kinematic_model")}
    odo = p["odometry"]
    return Work(
        gps_period=1.0 / float(p["gps"]["rate_hz"]),
        gps_noise=float(p["gps"]["noise_m"]),
        odo_pose0=tuple(float(v) for v in odo["initial_pose"]),
        odo_var_th=float(odo["heading_noise_rad"]) ** 2,
        odo_sv=float(p["kinematic_model"]["wheel_radius_m"]) * float(odo["encoder_noise_rad_s"])
        / math.sqrt(2.0),
        windows=(float(odo["innovation_window_s"]), float(odo["trend_window_s"])),
        drift=(float(odo["drift_window_s"]), float(odo["drift_min_span_s"]),
               float(odo["drift_min_support_s"]), float(odo["drift_walk_m_sqrt_s"]) ** 2),
        wheel_response=tuple(float(p[w]["response_time_s"]) for w in ("wheel_left", "wheel_right")),
        wheel_smoothing=tuple(float(p[w]["error_smoothing_s"])
                              for w in ("wheel_left", "wheel_right")),
    )


#: The residual signals of a1 the runtime reads, in the order of the run's series.
RESIDUALS = ("wheel_left", "wheel_right", "odometry", "lqr")


def run_floor_same_work(
    seed: int, setup: Setup | None = None, work: Work | None = None
) -> dict[str, Any]:
    """One a1 fixed run doing the work of the shipped scenario, on Python floats.

    :func:`run_floor` and besides: the GPS fixes (its own stream), every residual signal
    the runtime reads (the wheels' ``command_error``, the odometry's GPS innovation
    window, trend and drift test — the pack's own :class:`InnovationWindow`,
    :class:`InnovationTrend` and :class:`DriftGlr` — and the LQR's ``tracking_error``),
    the odometry's covariance, and the recording of a run (J, the reference, the actual
    pose and each residual signal at every step, as ``RunResult.series``).

    Returns
    -------
    dict
        As :func:`run_floor`, and ``reference`` (steps × 5), ``actual``, ``estimate``
        (steps × 3), ``command`` (steps × 2) and ``residual.<module>`` (steps) for each of
        :data:`RESIDUALS`: the framework's series, bit for bit (tests/test_floor.py).
    """
    from archself_diffdrive.drift_glr import DriftGlr
    from archself_diffdrive.estimators import InnovationTrend, InnovationWindow

    S = setup or load_setup()
    W = work or load_work()
    n, dt = S.steps, S.dt
    cha = stream(seed, "chassis").standard_normal((n, 4)).tolist()
    enc = stream(seed, "encoders").standard_normal((n, 2)).tolist()
    imu = stream(seed, "imu").standard_normal(n).tolist()
    gps_rng = stream(seed, "gps")
    rx_, ry_, rth_, rv_, rw_ = (a.tolist() for a in S.ref)
    rc_, rs_ = (a.tolist() for a in S.ref_cs)
    sin, cos, sqrt, exp, hypot = math.sin, math.cos, math.sqrt, math.exp, math.hypot
    r, b, lim, slip, sig_e, sig_h = S.radius, S.base, S.limit, S.slip, S.enc_noise, S.imu_noise
    a_lag = 1.0 - math.exp(-dt / S.tau) if S.tau > 0 else 1.0
    lag = S.tau > 0
    rdt = r * dt
    sq_dt = sqrt(dt)
    kr, kb, alim = S.kin_radius, S.kin_base, S.act_limit
    v_design = S.design_speed
    k00, k01, k02, k10, k11, k12 = _gain(S, v_design)
    px, py, pth = S.pose0
    wl = wr = 0.0
    ox, oy, oth = W.odo_pose0
    var_pos, var_th, sv = 0.01, W.odo_var_th, W.odo_sv
    window, trend = InnovationWindow(W.windows[0]), InnovationTrend(W.windows[1])
    drift = DriftGlr(math.nan, math.nan, math.nan)
    drift.configure(*W.drift)
    next_fix, last_fix, period, gnoise = 0.0, (math.nan, math.nan), W.gps_period, W.gps_noise
    resp, smooth = W.wheel_response, W.wheel_smoothing
    prev = None  # the last wheel command
    expected = [0.0, 0.0]
    cmd_err = [math.nan, math.nan]
    odo_sig = tracking = math.nan
    J = [0.0] * n
    ref_rec = np.empty((n, 5))
    act_rec = np.empty((n, 3))
    res_rec = np.empty((n, 4))
    est_rec = np.empty((n, 3))
    cmd_rec = np.empty((n, 2))
    cov = None
    for k in range(n):
        t = k * dt
        rx, ry, rth, rv, rw = rx_[k], ry_[k], rth_[k], rv_[k], rw_[k]
        dx, dy = px - rx, py - ry
        J[k] = sqrt(dx * dx + dy * dy)
        ref_rec[k] = (rx, ry, rth, rv, rw)
        act_rec[k] = (px, py, pth)
        # encoders, IMU and GPS
        e = enc[k]
        el = wl + sig_e * e[0]
        er = wr + sig_e * e[1]
        h = pth + S.imu_bias + sig_h * imu[k]
        h = (h + PI) % TWO_PI - PI
        fix = None
        if t >= next_fix - 1e-9:
            next_fix += period * max(1.0, math.floor((t - next_fix) / period) + 1)
            fix = np.array([px, py]) + gnoise * gps_rng.standard_normal(2)
        # dead reckoning, its covariance and its GPS residuals
        v = kr * (el + er) / 2.0
        th0 = oth
        th1 = th0 + ((h - th0 + PI) % (2 * PI) - PI)
        if k:
            mid = 0.5 * (th0 + th1)
            ddx, ddy = v * dt * cos(mid), v * dt * sin(mid)
            ox += ddx
            oy += ddy
            drift.move(t, ddx, ddy)
            var_pos += (sv * dt) ** 2 + (v * dt) ** 2 * var_th
        oth = (th1 + PI) % (2 * PI) - PI
        if fix is not None and (float(fix[0]), float(fix[1])) != last_fix:
            last_fix = (float(fix[0]), float(fix[1]))
            ex, ey = last_fix[0] - ox, last_fix[1] - oy
            window.add(t, ex, ey)
            trend.add(t, ex, ey)
            drift.add(t, ex, ey)
            window.value(), trend.value()
            odo_sig = drift.value()
        cov = np.diag([var_pos, var_pos, var_th])
        # LQR and its tracking error
        if abs(rv - v_design) > 0.005:
            v_design = rv
            k00, k01, k02, k10, k11, k12 = _gain(S, rv)
        dx, dy = ox - rx, oy - ry
        c, s = rc_[k], rs_[k]
        e0 = c * dx + s * dy
        e1 = -s * dx + c * dy
        e2 = (oth - rth + PI) % TWO_PI - PI
        vc = rv - (k00 * e0 + k01 * e1 + k02 * e2)
        wc = rw - (k10 * e0 + k11 * e1 + k12 * e2)
        tracking = hypot(ox - rx, oy - ry)
        half = wc * kb / 2.0
        cl = (vc - half) / kr
        cr = (vc + half) / kr
        peak = max(abs(cl), abs(cr))
        if peak > alim:
            cl, cr = cl * alim / peak, cr * alim / peak
        # the wheels' command error (the last command against this step's encoders)
        if prev is not None:
            for i, m in ((0, el), (1, er)):
                cw = prev[i]
                if resp[i] > 0:
                    cw = expected[i] = expected[i] + (1.0 - exp(-dt / resp[i])) * (cw - expected[i])
                ew = cw - m if cw >= 0 else m - cw
                last = cmd_err[i]
                if smooth[i] > 0 and last == last:
                    ew = last + (1.0 - exp(-dt / smooth[i])) * (ew - last)
                cmd_err[i] = ew
        prev = (cl, cr)
        res_rec[k] = (cmd_err[0], cmd_err[1], odo_sig, tracking)
        est_rec[k] = (ox, oy, oth)
        cmd_rec[k] = prev
        # chassis
        cl = min(max(cl, -lim), lim)
        cr = min(max(cr, -lim), lim)
        wl0, wr0 = wl, wr
        wl = wl0 + a_lag * (cl - wl0)
        wr = wr0 + a_lag * (cr - wr0)
        ul, ur = (0.5 * (wl0 + wl), 0.5 * (wr0 + wr)) if lag else (wl, wr)
        z = cha[k]
        ul = ul + sqrt(slip * abs(r * ul * dt)) * z[0] / rdt
        ur = ur + sqrt(slip * abs(r * ur * dt)) * z[1] / rdt
        vb = r * (ul + ur) / 2.0
        wb = r * (ur - ul) / b
        dth = wb * dt
        th2 = pth + dth
        s2, c2 = sin(th2), cos(th2)
        if abs(dth) < 1e-9:
            m = pth + 0.5 * dth
            px += vb * dt * cos(m)
            py += vb * dt * sin(m)
        else:
            rad = vb / wb
            px += rad * (s2 - sin(pth))
            py -= rad * (c2 - cos(pth))
        pth = th2
        lat = S.lateral * (z[2] * sq_dt)
        px += -s2 * lat
        py += c2 * lat
        pth += S.yaw * (z[3] * sq_dt)
    t = (np.arange(n) + 1) * dt
    Ja = np.array(J)
    out = {**_metrics(t, Ja), "t": t, "J": Ja, "reference": ref_rec, "actual": act_rec,
           "estimate": est_rec, "command": cmd_rec, "covariance": cov}
    for j, name in enumerate(RESIDUALS):
        out[f"residual.{name}"] = res_rec[:, j]
    return out


def run_floor_lanes(
    seeds: Sequence[int], setup: Setup | None = None, *, block: int = 400, record: bool = False
) -> dict[str, Any]:
    """The a1 fixed run for N seeds at once: states with a leading lane axis, one time loop.

    Parameters
    ----------
    seeds : sequence of int
        One lane per seed.
    setup : Setup, optional
        From :func:`load_setup` (default: architectures/diffdrive.yaml, nominal).
    block : int
        Steps of noise drawn per stream and lane at a time (memory per lane ≈ 112·block
        bytes: a lane-major and a step-major copy of 7 normals per step).
    record : bool
        Keep J of every step (``J``, shape (steps, N)); otherwise the metrics are
        accumulated and nothing grows with the run's length.

    Returns
    -------
    dict
        ``max_error``, ``final_error``, ``rms_error``, ``mean_error``, ``peak_time_s``,
        each an array of shape (N,) (the metrics of :func:`run_floor` per lane; rms and
        mean summed in step order, so they may differ from it in the last bits), and
        ``J`` if ``record``.

    Examples
    --------
    >>> out = run_floor_lanes([1, 2])
    >>> out["max_error"].shape
    (2,)
    """
    S = setup or load_setup()
    n, dt, N = S.steps, S.dt, len(seeds)
    noise = _Noise(seeds, S, block)
    rx_, ry_, rth_, rv_, rw_ = (a.tolist() for a in S.ref)
    rc_, rs_ = (a.tolist() for a in S.ref_cs)
    kr, kb, alim = S.kin_radius, S.kin_base, S.act_limit
    v_design = S.design_speed
    k00, k01, k02, k10, k11, k12 = _gain(S, v_design)
    sin, cos, sqrt, absolute, where = np.sin, np.cos, np.sqrt, np.abs, np.where
    chassis = _Chassis(S, N)
    ox, oy, oth = np.zeros(N), np.zeros(N), np.zeros(N)
    jmax, tmax = np.full(N, -np.inf), np.zeros(N)
    jsum, j2sum = np.zeros(N), np.zeros(N)
    Jrec = np.empty((n, N)) if record else None
    J = jmax
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(n):
            enc, imu, cha = noise.step(k)
            rx, ry, rth, rv, rw = rx_[k], ry_[k], rth_[k], rv_[k], rw_[k]
            px, py, pth = chassis.px, chassis.py, chassis.pth
            dx, dy = px - rx, py - ry
            J = sqrt(dx * dx + dy * dy)
            if Jrec is not None:
                Jrec[k] = J
            better = J > jmax  # the first maximum, as np.argmax
            np.copyto(jmax, J, where=better)
            np.copyto(tmax, (k + 1) * dt, where=better)
            jsum += J
            j2sum += J * J
            # encoders and IMU
            el = chassis.wl + enc[0]
            er = chassis.wr + enc[1]
            h = (pth + S.imu_bias if S.imu_bias else pth) + imu  # x + 0.0 is x
            h = (h + PI) % TWO_PI - PI
            # dead reckoning
            v = kr * (el + er) / 2.0
            th0 = oth
            th1 = th0 + ((h - th0 + PI) % (2 * PI) - PI)
            if k:
                mid = 0.5 * (th0 + th1)
                vdt = v * dt
                ox = ox + vdt * cos(mid)
                oy = oy + vdt * sin(mid)
            oth = (th1 + PI) % (2 * PI) - PI
            # LQR
            if abs(rv - v_design) > 0.005:
                v_design = rv
                k00, k01, k02, k10, k11, k12 = _gain(S, rv)
            dx, dy = ox - rx, oy - ry
            c, s = rc_[k], rs_[k]
            e0 = c * dx + s * dy
            e1 = -s * dx + c * dy
            e2 = (oth - rth + PI) % TWO_PI - PI
            vc = rv - (k00 * e0 + k01 * e1 + k02 * e2)
            wc = rw - (k10 * e0 + k11 * e1 + k12 * e2)
            half = wc * kb / 2.0
            cl = (vc - half) / kr
            cr = (vc + half) / kr
            peak = np.maximum(absolute(cl), absolute(cr))
            over = peak > alim
            if over.any():
                cl = where(over, cl * alim / peak, cl)
                cr = where(over, cr * alim / peak, cr)
            chassis.step(cl, cr, cha)
    out: dict[str, Any] = {
        "max_error": jmax,
        "final_error": J,
        "rms_error": np.sqrt(j2sum / n),
        "mean_error": jsum / n,
        "peak_time_s": tmax,
    }
    if Jrec is not None:
        out["J"] = Jrec
    return out


def run_floor_lanes_same_work(
    seeds: Sequence[int], setup: Setup | None = None, work: Work | None = None,
    *, block: int = 400,
) -> dict[str, Any]:
    """:func:`run_floor_same_work` for N seeds at once (states with a leading lane axis).

    The work of the framework's lanes: :func:`run_floor_lanes` and the GPS fixes, the
    wheels' ``command_error``, the odometry's covariance and its innovation window, trend
    and drift test (the pack's lane classes ``LaneWindows`` and ``DriftWindows``), the
    LQR's ``tracking_error``, and the recording of every lane's series (J, reference,
    actual, estimate, command: steps × N × width; the residuals: steps × N × 4), as the
    framework's lane recording keeps them.

    Returns
    -------
    dict
        The metrics as :func:`run_floor_lanes`, and the series ``J``, ``reference``,
        ``actual``, ``estimate``, ``command``, ``residual`` (steps × N [× width]).
    """
    from archself_diffdrive.drift_glr import DriftWindows
    from archself_diffdrive.lanes_windows import LaneWindows

    S = setup or load_setup()
    W = work or load_work()
    n, dt, N = S.steps, S.dt, len(seeds)
    ALL = np.arange(N)
    noise = _Noise(seeds, S, block)
    fixes = int(n * dt / W.gps_period) + 2  # every lane's GPS noise, drawn at once
    gps = np.stack([stream(s, "gps").standard_normal((fixes, 2)) for s in seeds], axis=1)
    gps *= W.gps_noise
    rx_, ry_, rth_, rv_, rw_ = (a.tolist() for a in S.ref)
    rc_, rs_ = (a.tolist() for a in S.ref_cs)
    kr, kb, alim = S.kin_radius, S.kin_base, S.act_limit
    v_design = S.design_speed
    k00, k01, k02, k10, k11, k12 = _gain(S, v_design)
    sin, cos, sqrt, absolute, where = np.sin, np.cos, np.sqrt, np.abs, np.where
    chassis = _Chassis(S, N)
    ox, oy, oth = (np.full(N, p) for p in W.odo_pose0)
    var_pos = np.full(N, 0.01)
    var_th, sv = W.odo_var_th, W.odo_sv
    window, trend = LaneWindows(N), LaneWindows(N)
    window.window[:], trend.window[:] = W.windows
    drift = DriftWindows(N, *W.drift[:3], walk=W.drift[3])
    moved, drift_last = np.zeros((N, 4)), np.zeros(N)
    odo_sig = np.full(N, math.nan)
    next_fix, n_fix, period = 0.0, 0, W.gps_period
    wheels = _WheelErrors(W, dt, N)
    rec = {"J": np.empty((n, N)), "reference": np.empty((n, N, 5)),
           "actual": np.empty((n, N, 3)), "estimate": np.empty((n, N, 3)),
           "command": np.empty((n, N, 2)), "residual": np.empty((n, N, 4))}
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(n):
            t = k * dt
            enc, imu, cha = noise.step(k)
            rx, ry, rth, rv, rw = rx_[k], ry_[k], rth_[k], rv_[k], rw_[k]
            px, py, pth = chassis.px, chassis.py, chassis.pth
            dx, dy = px - rx, py - ry
            rec["J"][k] = sqrt(dx * dx + dy * dy)
            rec["reference"][k] = (rx, ry, rth, rv, rw)
            act = rec["actual"][k]
            act[:, 0], act[:, 1], act[:, 2] = px, py, pth
            el = chassis.wl + enc[0]
            er = chassis.wr + enc[1]
            h = (pth + S.imu_bias if S.imu_bias else pth) + imu
            h = (h + PI) % TWO_PI - PI
            fix = None
            if t >= next_fix - 1e-9:
                next_fix += period * max(1.0, math.floor((t - next_fix) / period) + 1)
                fix = np.stack([px, py], axis=1) + gps[n_fix]
                n_fix += 1
            v = kr * (el + er) / 2.0
            th0 = oth
            th1 = th0 + ((h - th0 + PI) % (2 * PI) - PI)
            if k:
                mid = 0.5 * (th0 + th1)
                vdt = v * dt
                ddx, ddy = vdt * cos(mid), vdt * sin(mid)
                ox = ox + ddx
                oy = oy + ddy
                since = t - drift_last
                moved[:, 0] += ddy
                moved[:, 1] -= ddx
                moved[:, 2] += since * ddy
                moved[:, 3] -= since * ddx
                var_pos = var_pos + ((sv * dt) ** 2 + vdt**2 * var_th)
            oth = (th1 + PI) % (2 * PI) - PI
            if fix is not None:
                e = fix - np.stack([ox, oy], axis=1)
                window.add(t, ALL, e)
                trend.add(t, ALL, e)
                drift.add(t, ALL, e, moved)
                moved[:] = 0.0
                drift_last[:] = t
                window.mean_norm(ALL), trend.trend(ALL)
                odo_sig = drift.value(ALL)
            if abs(rv - v_design) > 0.005:
                v_design = rv
                k00, k01, k02, k10, k11, k12 = _gain(S, rv)
            dx, dy = ox - rx, oy - ry
            c, s = rc_[k], rs_[k]
            e0 = c * dx + s * dy
            e1 = -s * dx + c * dy
            e2 = (oth - rth + PI) % TWO_PI - PI
            vc = rv - (k00 * e0 + k01 * e1 + k02 * e2)
            wc = rw - (k10 * e0 + k11 * e1 + k12 * e2)
            tracking = np.hypot(dx, dy)
            half = wc * kb / 2.0
            cl = (vc - half) / kr
            cr = (vc + half) / kr
            peak = np.maximum(absolute(cl), absolute(cr))
            over = peak > alim
            if over.any():
                cl = where(over, cl * alim / peak, cl)
                cr = where(over, cr * alim / peak, cr)
            err = wheels.step(el, er)
            wheels.prev = (cl, cr)
            res = rec["residual"][k]
            res[:, 0], res[:, 1], res[:, 2], res[:, 3] = err[0], err[1], odo_sig, tracking
            est, cmd = rec["estimate"][k], rec["command"][k]
            est[:, 0], est[:, 1], est[:, 2] = ox, oy, oth
            cmd[:, 0], cmd[:, 1] = cl, cr
            chassis.step(cl, cr, cha)
    J = rec["J"]
    i = np.argmax(J, axis=0)
    out: dict[str, Any] = {
        "max_error": J[i, ALL],
        "final_error": J[-1],
        "rms_error": np.sqrt(np.mean(J**2, axis=0)),
        "mean_error": np.mean(J, axis=0),
        "peak_time_s": (i + 1) * dt,
        "covariance_pos": var_pos,
    }
    return {**out, **rec}


class _Noise:
    """Every lane's sensor and chassis noise, drawn per stream and lane in blocks of
    ``block`` steps (a lane-major buffer, transposed once per block to step-major) and
    scaled as the modules scale it (the same products)."""

    def __init__(self, seeds: Sequence[int], S: Setup, block: int) -> None:
        N = len(seeds)
        self.S, self.block, self.n = S, block, S.steps
        self.streams = [(stream(s, "chassis"), stream(s, "encoders"), stream(s, "imu"))
                        for s in seeds]
        self.draw = (np.empty((N, block, 4)), np.empty((N, block, 2)), np.empty((N, block)))
        self.cha = np.empty((block, 4, N))
        self.enc = np.empty((block, 2, N))
        self.imu = np.empty((block, N))

    def step(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Step ``k``'s encoder noise (2 × N), IMU noise (N) and chassis noise (4 × N)."""
        j = k % self.block
        if j == 0:
            S, draw, cha, enc, imu = self.S, self.draw, self.cha, self.enc, self.imu
            m = min(self.block, self.n - k)
            for lane, (gc, ge, gi) in enumerate(self.streams):
                gc.standard_normal(out=draw[0][lane, :m])
                ge.standard_normal(out=draw[1][lane, :m])
                gi.standard_normal(out=draw[2][lane, :m])
            cha[:m] = draw[0][:, :m].transpose(1, 2, 0)
            enc[:m] = draw[1][:, :m].transpose(1, 2, 0)
            imu[:m] = draw[2][:, :m].T
            np.multiply(S.enc_noise, enc, out=enc)
            np.multiply(S.imu_noise, imu, out=imu)
            np.multiply(cha[:, 2:], math.sqrt(S.dt), out=cha[:, 2:])
            np.multiply(S.lateral, cha[:, 2], out=cha[:, 2])
            np.multiply(S.yaw, cha[:, 3], out=cha[:, 3])
        return self.enc[j], self.imu[j], self.cha[j]


class _Chassis:
    """The true pose and wheel speeds of every lane (plant.diffdrive): lag, limit, slip,
    the exact arc, lateral and yaw noise."""

    def __init__(self, S: Setup, N: int) -> None:
        self.S = S
        self.px, self.py, self.pth = (np.full(N, p) for p in S.pose0)
        self.wl, self.wr = np.zeros(N), np.zeros(N)
        self.a_lag = 1.0 - math.exp(-S.dt / S.tau) if S.tau > 0 else 1.0

    def step(self, cl: np.ndarray, cr: np.ndarray, cha: np.ndarray) -> None:
        """One step with wheel commands ``cl``, ``cr`` and noise ``cha`` (4 × N)."""
        S, absolute, where, sin, cos = self.S, np.abs, np.where, np.sin, np.cos
        r, b, lim, slip, dt = S.radius, S.base, S.limit, S.slip, S.dt
        rdt = r * dt
        cl = np.minimum(np.maximum(cl, -lim), lim)
        cr = np.minimum(np.maximum(cr, -lim), lim)
        wl0, wr0 = self.wl, self.wr
        wl = self.wl = wl0 + self.a_lag * (cl - wl0)
        wr = self.wr = wr0 + self.a_lag * (cr - wr0)
        if S.tau > 0:
            ul, ur = 0.5 * (wl0 + wl), 0.5 * (wr0 + wr)
        else:
            ul, ur = wl, wr
        ul = ul + np.sqrt(slip * absolute(r * ul * dt)) * cha[0] / rdt
        ur = ur + np.sqrt(slip * absolute(r * ur * dt)) * cha[1] / rdt
        vb = r * (ul + ur) / 2.0
        wb = r * (ur - ul) / b
        dth = wb * dt
        pth = self.pth
        th2 = pth + dth
        straight = absolute(dth) < 1e-9
        rad = vb / wb
        s2, c2 = sin(th2), cos(th2)
        ax = rad * (s2 - sin(pth))
        ay = rad * (c2 - cos(pth))
        if straight.any():
            mth = pth + 0.5 * dth
            vdt = vb * dt
            ax = where(straight, vdt * cos(mth), ax)
            ay = where(straight, -(vdt * sin(mth)), ay)
        lat = cha[2]
        self.px = (self.px + ax) - s2 * lat  # x + (−s)·l is x − s·l exactly
        self.py = (self.py - ay) + c2 * lat
        self.pth = th2 + cha[3]


class _WheelErrors:
    """The wheels' ``command_error`` in every lane: the last command (through the wheel's
    response lag) against this step's encoder speed, smoothed."""

    def __init__(self, W: Work, dt: float, N: int) -> None:
        self.lag = [1.0 - math.exp(-dt / x) if x > 0 else 0.0 for x in W.wheel_response]
        self.smooth = [1.0 - math.exp(-dt / x) if x > 0 else 0.0 for x in W.wheel_smoothing]
        self.expected = [np.zeros(N), np.zeros(N)]
        self.err = [np.full(N, math.nan), np.full(N, math.nan)]
        self.prev: tuple[np.ndarray, np.ndarray] | None = None

    def step(self, el: np.ndarray, er: np.ndarray) -> list[np.ndarray]:
        """Both wheels' errors against the encoder speeds ``el``, ``er`` (before the new
        command: set :attr:`prev` after)."""
        if self.prev is not None:
            where = np.where
            for i, meas in ((0, el), (1, er)):
                cw = self.prev[i]
                if self.lag[i]:
                    cw = self.expected[i] = self.expected[i] + self.lag[i] * (cw - self.expected[i])
                ew = where(cw >= 0, cw - meas, meas - cw)
                last = self.err[i]
                if self.smooth[i]:
                    ew = where(last == last, last + self.smooth[i] * (ew - last), ew)
                self.err[i] = ew
        return self.err


@dataclass(frozen=True)
class Fused:
    """What configuration a2 runs besides a1's modules, read once from the compiled
    modules (:func:`load_fused`): the EKF's noises, prior and window, lqr_fused's weights,
    the hand-over threshold of the odometry's drift, the Monitor's residual bands."""

    q2: tuple[float, ...]  # the EKF's process-noise densities squared
    r_head: float
    sig_enc: float
    R_gps: np.ndarray
    P0: np.ndarray
    pose0: tuple[float, float, float]
    window: float  # the EKF's innovation window (s)
    latency: int  # steps of the GPS -> EKF edge
    q: tuple[float, float, float]  # lqr_fused's weights
    r: tuple[float, float]
    handover_z: float
    #: residual modules (the recorded order), their sensitivity, nominal and smoothing (s)
    residual: tuple[tuple[str, float, float, float], ...]
    threshold: float
    period: int  # steps per MAPE-K cycle


@cache
def load_fused(path: str | Path = DIFFDRIVE) -> Fused:
    """The parameters :func:`run_floor_lanes_switching` needs besides :func:`load_work`'s."""
    import archself
    from archself.system.live import compile_system

    arch = archself.load(path)
    system = compile_system(arch, "a2", seed=1, scenario=arch.scenarios["nominal"])
    ekf, lqr = system.modules["ekf"], system.modules["lqr_fused"]
    edge = next(e for e in arch.edges if e.source == "gps" and e.target == "ekf")
    p = lqr.params
    dt = arch.runtime.step_s
    return Fused(
        q2=tuple(ekf._q2), r_head=ekf.r_head, sig_enc=ekf.sig_enc, R_gps=ekf.R_gps.copy(),
        P0=ekf._initial_covariance(), pose0=tuple(float(v) for v in ekf.x[:3]),
        window=float(ekf.monitor.window_s), latency=int(round(edge.latency_s / dt)),
        q=(float(p["q_along"]), float(p["q_lateral"]), float(p["q_heading"])),
        r=(float(p["r_speed"]), float(p["r_turn"])),
        handover_z=float(compile_system(arch, "a1", seed=1).modules["odometry"]
                         .params["drift_handover_z"]),
        residual=tuple((name, m.residual.sensitivity, m.residual.nominal, m.residual.smoothing_s)
                       for name, m in arch.modules.items()
                       if m.residual is not None and name in SWITCHING_RESIDUALS),
        threshold=float(arch.runtime.threshold),
        period=int(round(arch.runtime.period_s / dt)),
    )


#: The residual signals of a1 and a2 recorded by :func:`run_floor_lanes_switching`.
SWITCHING_RESIDUALS = ("wheel_left", "wheel_right", "odometry", "ekf", "lqr", "lqr_fused")


def _gps_update(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray) -> tuple[Any, Any]:
    """The EKF's GPS update of every row, as the pack's lanes do it (filterpy's Joseph form:
    stacked products, scipy's 2×2 inverses one by one)."""
    import scipy.linalg as linalg

    H = np.eye(2, 5)
    PHT = P @ H.T
    S = H @ PHT + R
    K = PHT @ np.array([linalg.inv(s, check_finite=False) for s in S])
    x = x + (K @ (z - x[:, :2])[:, :, None])[:, :, 0]
    I_KH = np.eye(5) - K @ H
    P = (I_KH @ P) @ I_KH.transpose(0, 2, 1) + (K @ R) @ K.transpose(0, 2, 1)
    return x, P


def run_floor_lanes_switching(
    seeds: Sequence[int], setup: Setup | None = None, work: Work | None = None,
    fused: Fused | None = None, *, start: str = "a1", switches: Sequence[int] | None = None,
    block: int = 400,
) -> dict[str, Any]:
    """Fixed a2, or adaptive (a1, then a2 where the framework switched), for N seeds at once.

    The same work as the framework's lanes (:func:`run_floor_lanes_same_work` and besides):
    in a2 the 5-state EKF with its GPS fixes through the edge's latency, written out as the
    pack's lanes do it (the pack's closed-form :func:`predict_rows` and
    :func:`update_heading_rows`, the GPS update as :func:`_gps_update`), its innovation
    window, and lqr_fused (its own gains); the scenario's IMU bias drift (``setup``); every
    ``runtime.period_s`` the Monitor's stage by hand on every lane — each residual signal
    filtered (its ``smoothing_s``), normalized (``nominal``, ``sensitivity``) and compared
    with the band (``runtime.threshold``) — and at a switch the hand-over (the odometry's
    drift estimate, :meth:`DriftWindows.estimate`, into the EKF's state and covariance;
    lqr_fused takes lqr's design speed).

    The floor does not decide: it **replays the framework's decisions** (``switches``: per
    lane, the step after which the framework's loop switched it a1 -> a2, or -1), so it
    has no Analyze, Plan or stability test; the Monitor's comparisons are its cost only.

    Parameters
    ----------
    start : {"a1", "a2"}
        The configuration every lane starts in (``"a2"`` with no switches: fixed a2).
    switches : sequence of int, optional
        One per lane (``start="a1"``).

    Returns
    -------
    dict
        ``max_error`` (per lane), and the series ``J``, ``reference``, ``actual``,
        ``estimate``, ``command`` (steps × N [× width]) and ``residual`` (steps × N × 6, in
        :data:`SWITCHING_RESIDUALS` order, NaN where inactive), as the framework's lanes.
    """
    from archself_diffdrive.drift_glr import DriftWindows
    from archself_diffdrive.estimators import predict_rows, update_heading_rows
    from archself_diffdrive.lanes_windows import LaneWindows

    S, W, F = setup or load_setup(), work or load_work(), fused or load_fused()
    n, dt, N = S.steps, S.dt, len(seeds)
    ALL = np.arange(N)
    noise = _Noise(seeds, S, block)
    fixes = int(n * dt / W.gps_period) + 2
    gps = np.stack([stream(s, "gps").standard_normal((fixes, 2)) for s in seeds], axis=1)
    gps *= W.gps_noise
    rx_, ry_, rth_, rv_, rw_ = (a.tolist() for a in S.ref)
    rc_, rs_ = (a.tolist() for a in S.ref_cs)
    kr, kb, alim = S.kin_radius, S.kin_base, S.act_limit
    v_design = S.design_speed
    gains = {"a1": _gain(S, v_design), "a2": _cached_gain(round(v_design, 2), F.q, F.r)}
    sqrt, absolute, where = np.sqrt, np.abs, np.where
    chassis = _Chassis(S, N)
    # a1: dead reckoning and its GPS tests
    ox, oy, oth = (np.full(N, p) for p in W.odo_pose0)
    var_pos = np.full(N, 0.01)
    var_th, sv = W.odo_var_th, W.odo_sv
    window, trend = LaneWindows(N), LaneWindows(N)
    window.window[:], trend.window[:] = W.windows
    drift = DriftWindows(N, *W.drift[:3], walk=W.drift[3])
    moved, drift_last = np.zeros((N, 4)), np.zeros(N)
    odo_sig = np.full(N, math.nan)
    # a2: the EKF
    x = np.zeros((N, 5))
    x[:, :3] = F.pose0
    P = np.repeat(F.P0[None], N, axis=0)
    started = np.zeros(N, dtype=bool)
    ekf_win = LaneWindows(N)
    ekf_win.window[:] = F.window
    ekf_sig = np.full(N, math.nan)
    q2 = np.array(F.q2)[None].repeat(N, axis=0)
    r_head = np.full(N, F.r_head)
    in2 = np.full(N, start == "a2")
    since = np.where(in2, 0, n + 1)  # the step each lane entered a2 (its latency line starts)
    after: dict[int, list[int]] = {}
    for lane, k in enumerate(switches if switches is not None else ()):
        if k >= 0:
            after.setdefault(int(k), []).append(lane)
    fix_at: dict[int, np.ndarray] = {}
    next_fix, n_fix, period = 0.0, 0, W.gps_period
    wheels = _WheelErrors(W, dt, N)
    # the Monitor's filters by hand (every residual module, every lane)
    sens = np.array([m[1] for m in F.residual])
    nom = np.array([m[2] for m in F.residual])
    gain_m = 1.0 - np.exp(-(F.period * dt) / np.array([m[3] for m in F.residual]))
    filt = np.full((N, len(F.residual)), math.nan)
    col = {m[0]: j for j, m in enumerate(F.residual)}
    over = 0
    rec = {"J": np.empty((n, N)), "reference": np.empty((n, N, 5)),
           "actual": np.empty((n, N, 3)), "estimate": np.empty((n, N, 3)),
           "command": np.empty((n, N, 2)),
           "residual": np.full((n, N, len(SWITCHING_RESIDUALS)), math.nan)}
    groups = _groups_of(in2)
    K = None
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(n):
            t = k * dt
            enc, imu, cha = noise.step(k)
            rx, ry, rth, rv, rw = rx_[k], ry_[k], rth_[k], rv_[k], rw_[k]
            px, py, pth = chassis.px, chassis.py, chassis.pth
            dx, dy = px - rx, py - ry
            rec["J"][k] = sqrt(dx * dx + dy * dy)
            rec["reference"][k] = (rx, ry, rth, rv, rw)
            act = rec["actual"][k]
            act[:, 0], act[:, 1], act[:, 2] = px, py, pth
            wl, wr = chassis.wl, chassis.wr
            el = wl + enc[0]
            er = wr + enc[1]
            h = (pth + S.imu_bias if S.imu_bias else pth) + imu
            h = (h + PI) % TWO_PI - PI
            if S.drift is not None and S.drift[0] <= t + 1e-9:
                h = h + S.drift[1] * (t - S.drift[0])
            fix = None
            if t >= next_fix - 1e-9:
                next_fix += period * max(1.0, math.floor((t - next_fix) / period) + 1)
                fix = fix_at[k] = np.stack([px, py], axis=1) + gps[n_fix]
                n_fix += 1
            est = np.empty((N, 3))
            res = rec["residual"][k]
            for conf, idx in groups:
                sel = ALL if idx is None else idx
                if conf == "a1":
                    v = kr * (el[sel] + er[sel]) / 2.0
                    th0 = oth[sel]
                    th1 = th0 + ((h[sel] - th0 + PI) % (2 * PI) - PI)
                    if k:
                        mid = 0.5 * (th0 + th1)
                        vdt = v * dt
                        ddx, ddy = vdt * np.cos(mid), vdt * np.sin(mid)
                        ox[sel] = ox[sel] + ddx
                        oy[sel] = oy[sel] + ddy
                        lag = t - drift_last[sel]
                        m = moved[sel]
                        m[:, 0] += ddy
                        m[:, 1] -= ddx
                        m[:, 2] += lag * ddy
                        m[:, 3] -= lag * ddx
                        moved[sel] = m
                        var_pos[sel] = var_pos[sel] + ((sv * dt) ** 2 + vdt**2 * var_th)
                    oth[sel] = (th1 + PI) % (2 * PI) - PI
                    if fix is not None:
                        lanes = ALL if idx is None else idx
                        e = fix[lanes] - np.stack([ox[lanes], oy[lanes]], axis=1)
                        window.add(t, lanes, e)
                        trend.add(t, lanes, e)
                        drift.add(t, lanes, e, moved[lanes])
                        moved[lanes] = 0.0
                        drift_last[lanes] = t
                        window.mean_norm(lanes), trend.trend(lanes)
                        odo_sig[lanes] = drift.value(lanes)
                    est[sel, 0], est[sel, 1], est[sel, 2] = ox[sel], oy[sel], oth[sel]
                    res[sel, col["odometry"]] = odo_sig[sel]
                else:
                    lanes = ALL if idx is None else idx
                    xs, Ps = x[lanes], P[lanes]
                    go = started[lanes]
                    v = kr * (el[lanes] + er[lanes]) / 2.0
                    w = kr * (er[lanes] - el[lanes]) / kb
                    sig2 = F.sig_enc**2
                    if go.all():
                        xs, Ps = predict_rows(xs, Ps, dt, v, w, sig2, kr, kb, q2[lanes])
                    else:
                        j = np.flatnonzero(go)
                        if len(j):
                            xs[j], Ps[j] = predict_rows(xs[j], Ps[j], dt, v[j], w[j], sig2, kr,
                                                        kb, q2[lanes][j])
                        first = np.flatnonzero(~go)
                        xs[first, 2] = h[lanes][first] - xs[first, 3]
                    started[lanes] = True
                    xs, Ps = update_heading_rows(xs, Ps, h[lanes], r_head[lanes])
                    late = fix_at.get(k - F.latency)
                    if late is not None:
                        has = since[lanes] <= k - F.latency
                        if has.any():
                            j = np.flatnonzero(has)
                            z = late[lanes][j]
                            e = z - xs[j, :2]
                            xs[j], Ps[j] = _gps_update(xs[j], Ps[j], z, F.R_gps)
                            ekf_win.add(t, lanes[j], e)
                            ekf_sig[lanes[j]] = ekf_win.mean_norm(lanes[j])
                    x[lanes], P[lanes] = xs, Ps
                    est[lanes] = xs[:, :3]
                    res[lanes, col["ekf"]] = ekf_sig[lanes]
            fix_at.pop(k - F.latency, None)
            if abs(rv - v_design) > 0.005:
                v_design = rv
                gains = {"a1": _gain(S, rv), "a2": _cached_gain(round(max(rv, 0.05), 2), F.q, F.r)}
                K = None
            if K is None:  # each lane's controller's gain (a lane's row of a1's or a2's)
                K = (gains[groups[0][0]] if len(groups) == 1 else
                     tuple(where(in2, f, o) for o, f in zip(gains["a1"], gains["a2"], strict=True)))
            k00, k01, k02, k10, k11, k12 = K
            dx, dy = est[:, 0] - rx, est[:, 1] - ry
            c, s = rc_[k], rs_[k]
            e0 = c * dx + s * dy
            e1 = -s * dx + c * dy
            e2 = (est[:, 2] - rth + PI) % TWO_PI - PI
            vc = rv - (k00 * e0 + k01 * e1 + k02 * e2)
            wc = rw - (k10 * e0 + k11 * e1 + k12 * e2)
            tracking = np.hypot(dx, dy)
            half = wc * kb / 2.0
            cl = (vc - half) / kr
            cr = (vc + half) / kr
            peak = np.maximum(absolute(cl), absolute(cr))
            big = peak > alim
            if big.any():
                cl = where(big, cl * alim / peak, cl)
                cr = where(big, cr * alim / peak, cr)
            res[:, col["wheel_left"]], res[:, col["wheel_right"]] = wheels.step(el, er)
            wheels.prev = (cl, cr)
            for conf, idx in groups:
                sel = ALL if idx is None else idx
                res[sel, col["lqr" if conf == "a1" else "lqr_fused"]] = tracking[sel]
            rec["estimate"][k] = est
            cmd = rec["command"][k]
            cmd[:, 0], cmd[:, 1] = cl, cr
            chassis.step(cl, cr, cha)
            if (k + 1) % F.period == 0:  # the Monitor's stage by hand: filters and bands
                sample = np.isfinite(res)
                filt = where(sample, where(filt == filt, filt + gain_m * (res - filt), res), filt)
                r = sens * np.maximum(absolute(filt) - nom, 0.0) / nom
                over += int((r > F.threshold).sum())
            lane_list = after.get(k)
            if lane_list:  # the framework's switches after this step, replayed
                _hand_over(np.array(lane_list), drift, F, ox, oy, oth, var_pos, var_th, x, P,
                           started)
                in2[lane_list] = True
                since[lane_list] = k + 1
                groups, K = _groups_of(in2), None
    J = rec["J"]
    return {"max_error": J.max(axis=0), "band_crossings": over, **rec}


def _groups_of(in2: np.ndarray) -> list[tuple[str, np.ndarray | None]]:
    """The lanes of a1 and of a2 (None: every lane)."""
    if in2.all():
        return [("a2", None)]
    if not in2.any():
        return [("a1", None)]
    return [("a1", np.flatnonzero(~in2)), ("a2", np.flatnonzero(in2))]


def _hand_over(L: np.ndarray, drift: Any, F: Fused, ox, oy, oth, var_pos, var_th, x, P,
               started) -> None:
    """a1 -> a2 in lanes ``L``: the odometry's state (and the drift it found, where its
    test passes ``drift_handover_z``) into the EKF (``export_state``/``import_state``)."""
    z, rate, rate_std, _, error, extra, extra_std = drift.estimate(L)
    hand = absolute_ge(z, F.handover_z)
    px, py, th = ox[L].copy(), oy[L].copy(), oth[L].copy()
    c22 = np.full(len(L), var_th)
    bias, brate = np.zeros(len(L)), np.zeros(len(L))
    if hand.any():
        j = np.flatnonzero(hand)
        px[j] = px[j] + error[j, 0]
        py[j] = py[j] + error[j, 1]
        th[j] = (th[j] - extra[j] + PI) % (2 * PI) - PI
        c22[j] = c22[j] + extra_std[j] ** 2
        bias[j] = 0.0 + extra[j]
        brate[j] = 0.0 + rate[j]
    x[L] = np.stack([px, py, th, bias, brate], axis=1)
    P0 = np.repeat(F.P0[None], len(L), axis=0)
    P0[:, 0, 0] += var_pos[L]
    P0[:, 1, 1] += var_pos[L]
    P0[:, 2, 2] += c22
    for kk, std in ((3, extra_std), (4, rate_std)):
        use = hand & np.isfinite(std)
        P0[use, kk, kk] = np.maximum(P0[use, kk, kk], std[use] ** 2)
    P[L] = P0
    started[L] = True


def absolute_ge(z: np.ndarray, limit: float) -> np.ndarray:
    """``abs(z) >= limit`` (False for NaN, as the per-run test)."""
    with np.errstate(invalid="ignore"):
        return np.abs(z) >= limit


# ---------------------------------------------------------------------- the measurement
def _best(fn: Any, rounds: int) -> tuple[float, float, float]:
    """Min and median wall time and min CPU time (this process) of ``rounds`` calls of ``fn``.

    On a shared machine the CPU time is the steadier figure: another job's load stretches
    the wall time but hardly the CPU time a call needs.
    """
    walls, cpus = [], []
    for _ in range(rounds):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return min(walls), float(np.median(walls)), min(cpus)


def _peak_bytes(fn: Any) -> int:
    """Peak bytes allocated (tracemalloc; numpy's arrays included) while ``fn`` runs."""
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def ratios(lanes: Sequence[int], rounds: int, cases: Sequence[str]) -> None:
    """Framework lanes against the same-work vectorized floor, case by case, interleaved.

    Cases: ``a1`` (fixed a1, nominal: :func:`run_floor_lanes_same_work`), ``a2`` (fixed a2,
    nominal) and ``adaptive`` (imu_drift with a MAPE-K loop per lane; the floor replays
    the switches the framework's first round made: :func:`run_floor_lanes_switching`).
    Each round runs the framework, then the floor, on the same seeds; CPU of this
    process, the median of the rounds per lane-step, and their ratio.
    """
    import archself
    from archself.lanes import simulate_lanes

    arch = archself.load(DIFFDRIVE)
    S, W, F = load_setup(), load_work(), load_fused()
    Sd = load_setup(scenario="imu_drift")
    for N in lanes:
        seeds = list(range(1, N + 1))
        for case in cases:
            switches: list[int] = []

            def fw(case: str = case, seeds: list[int] = seeds,
                   switches: list[int] = switches) -> Any:
                if case == "adaptive":
                    runs = simulate_lanes(arch, "imu_drift", seeds, adapt=True)
                    switches[:] = [int(round(r.switches[0]["t_s"] / S.dt)) - 1
                                   if r.switches else -1 for r in runs]
                    return runs
                return simulate_lanes(arch, "nominal", seeds, configuration=case)

            def fl(case: str = case, seeds: list[int] = seeds,
                   switches: list[int] = switches) -> Any:
                if case == "a1":
                    return run_floor_lanes_same_work(seeds, S, W)
                if case == "a2":
                    return run_floor_lanes_switching(seeds, S, W, F, start="a2")
                return run_floor_lanes_switching(seeds, Sd, W, F, switches=switches)

            cpu_fw, cpu_fl = [], []
            for _ in range(rounds):
                cpu_fw.append(_best(fw, 1)[2])
                cpu_fl.append(_best(fl, 1)[2])
            a, b = float(np.median(cpu_fw)), float(np.median(cpu_fl))
            per = 1e6 / (N * S.steps)
            print(f"N = {N:5} {case:9} framework {a:8.2f} s ({a * per:6.2f} µs/lane-step)  "
                  f"floor {b:7.2f} s ({b * per:5.2f} µs)  framework/floor {a / b:5.2f}×  "
                  f"[rounds: {' '.join(f'{x:.1f}' for x in cpu_fw)} / "
                  f"{' '.join(f'{x:.1f}' for x in cpu_fl)}; load {_load()}]", flush=True)


def main(argv: Sequence[str] | None = None) -> None:
    """Measure the framework's a1 fixed run, the floor and the vectorized floor side by side."""
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5, help="rounds of each per-run timing")
    ap.add_argument("--lanes", type=int, nargs="+", default=[1, 10, 100, 1000])
    ap.add_argument("--block", type=int, default=400, help="noise block of the vectorized floor")
    ap.add_argument("--framework-lanes", type=int, nargs="*", default=[10, 100],
                    help="N of the framework's lane-batched runs (archself.lanes.simulate_lanes)")
    ap.add_argument("--ratios", nargs="*", default=None, metavar="CASE",
                    help="only framework lanes / same-work floor at --lanes for the cases "
                         "a1, a2, adaptive (default: all three)")
    args = ap.parse_args(argv)
    if args.ratios is not None:
        ratios(args.lanes, args.rounds, args.ratios or ["a1", "a2", "adaptive"])
        return

    import archself

    arch = archself.load(DIFFDRIVE)
    t0 = time.perf_counter()
    S = load_setup()
    setup_s = time.perf_counter() - t0
    n = S.steps

    def framework(seed: int) -> Any:
        return archself.simulate(arch, "nominal", configuration="a1", seed=seed)

    # warm (python-control, scipy, the gain cache) and check the trace
    W = load_work()
    fw, fl = framework(1), run_floor(1, S)
    dev = float(np.max(np.abs(fw.series["J"] - fl["J"])))
    same = run_floor_same_work(1, S, W)
    keys = ["J", "reference", "actual", "estimate", "command",
            *(f"residual.{m}" for m in RESIDUALS)]
    equal = all(np.array_equal(fw.series[k], same[k], equal_nan=True) for k in keys)
    print(f"same-work floor, seed 1: {len(keys)} series bit for bit equal: {equal}")
    print(f"load average {_load()} · {os.cpu_count()} cores · {n} steps of {S.dt} s")
    print(
        f"trace check, seed 1: max |J_framework − J_floor| = {dev:.1e} m "
        f"(max error {fw.metrics['max_error']:.6f} / {fl['max_error']:.6f} m)"
    )
    seeds = iter(range(1000, 100000))
    rows = [
        ("framework a1 fixed (simulate)", 1, _best(lambda: framework(next(seeds)), args.rounds)),
        (
            "floor, one run (Python floats)",
            1,
            _best(lambda: run_floor(next(seeds), S), args.rounds * 4),
        ),
        (
            "floor, same work, one run",
            1,
            _best(lambda: run_floor_same_work(next(seeds), S, W), args.rounds * 2),
        ),
    ]
    for N in args.lanes:
        lanes = list(range(1, N + 1))
        r = max(1, min(args.rounds, 3000 // max(N, 1)))
        rows.append(
            (
                f"floor vectorized, N = {N}",
                N,
                _best(lambda lanes=lanes: run_floor_lanes(lanes, S, block=args.block), r),
            )
        )
        rows.append(
            (
                f"floor vectorized same work, N = {N}",
                N,
                _best(lambda lanes=lanes: run_floor_lanes_same_work(lanes, S, W,
                                                                    block=args.block), r),
            )
        )
    from archself.lanes import simulate_lanes

    def framework_lanes(N: int) -> Any:
        first = next(seeds)
        return simulate_lanes(arch, "nominal", list(range(first, first + N)), configuration="a1")

    lanes_dev = float(np.max(np.abs(simulate_lanes(arch, "nominal", [1], configuration="a1")[0]
                                    .series["J"] - fw.series["J"])))
    print(f"trace check, seed 1: max |J_lanes − J_framework| = {lanes_dev:.1e} m")
    for N in args.framework_lanes:
        r = max(1, min(args.rounds, 300 // max(N, 1)))
        rows.append(
            (f"framework lanes, N = {N}", N, _best(lambda N=N: framework_lanes(N), r))
        )
    print()
    print(
        f"{'':32} {'wall min (median) [s]':>22} {'CPU [s]':>8} {'CPU/lane-step [µs]':>19}"
        f" {'runs/s (CPU)':>13}"
    )
    for label, N, (wall, med, cpu) in rows:
        print(
            f"{label:32} {wall:>10.3f} ({med:8.3f}) {cpu:>8.3f} {cpu / n / N * 1e6:>19.2f}"
            f" {N / cpu:>13.1f}"
        )
    cpu_of = {label: c for label, _, (_, _, c) in rows}
    for N in sorted(set(args.lanes) & set(args.framework_lanes)):
        fw_n = cpu_of[f"framework lanes, N = {N}"]
        print(f"framework lanes / floor at N = {N}: "
              f"{fw_n / cpu_of[f'floor vectorized same work, N = {N}']:.2f}× the same-work "
              f"floor, {fw_n / cpu_of[f'floor vectorized, N = {N}']:.2f}× the J-only floor")
    fw_cpu, fl_cpu, same_cpu = rows[0][2][2], rows[1][2][2], rows[2][2][2]
    print(
        f"framework / floor per run: {fw_cpu / fl_cpu:.1f}× (CPU), "
        f"{rows[0][2][0] / rows[1][2][0]:.1f}× (wall); framework / same-work floor: "
        f"{fw_cpu / same_cpu:.2f}× (CPU)"
    )
    N = max(args.lanes)
    peak = _peak_bytes(lambda: run_floor_lanes(list(range(1, N + 1)), S, block=args.block))
    fw_mem = _peak_bytes(lambda: framework(2))
    print()
    print(
        f"memory: vectorized floor peak {peak / 1e6:.1f} MB for {N} lanes = "
        f"{peak / N / 1e3:.1f} kB per lane (noise blocks of {args.block} steps, J not kept); "
        f"framework, one run: peak {fw_mem / 1e6:.1f} MB (tracemalloc)"
    )
    if args.framework_lanes:
        N = max(args.framework_lanes)
        lanes_mem = _peak_bytes(lambda: framework_lanes(N))
        print(
            f"framework lanes: peak {lanes_mem / 1e6:.1f} MB for {N} lanes = "
            f"{lanes_mem / N / 1e6:.2f} MB per lane (the recorded series and N RunResults)"
        )
    print(f"floor setup, once: {setup_s:.3f} s (spline table, reference, LQR gain)")
    print(f"load average after: {_load()}")


if __name__ == "__main__":
    main()
