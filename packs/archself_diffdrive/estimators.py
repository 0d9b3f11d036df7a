"""Estimators: dead-reckoning odometry and an EKF with GPS fusion and IMU-bias state.

Both publish ``pose_estimate`` ``[x, y, θ]`` and the residual signal
``innovation``: the norm of the *vector mean* of the GPS innovations
(GPS position − predicted position) over a sliding window. Averaging the vectors
lets zero-mean GPS noise cancel while a slowly growing estimation bias (an IMU
drift dragging dead reckoning away) shows early.

Dead reckoning also publishes ``innovation_trend``: how fast it is moving away from
the GPS, in units of its own standard error (:class:`InnovationTrend`). A heading
error ``b`` makes the estimated velocity point the wrong way, so the innovation
grows at about ``v·b`` per second; a fault-free odometry's slip and noise make it
wander but not run away, and the statistic is divided by the GPS noise measured
from the same fixes, so one band holds at any GPS noise level. And ``drift_glr``: the
template-matched test of a heading drift (:mod:`archself_diffdrive.drift_glr`), which
follows the turns of the path and a drift's quadratic growth over a longer window.
"""

from __future__ import annotations

import math
from collections import deque
from typing import ClassVar

import numpy as np

from archself.modules.base import Param, RuntimeModule
from archself_diffdrive.drift_glr import DriftGlr
from archself_diffdrive.models import Kinematics

__all__ = ["InnovationTrend", "InnovationWindow", "Odometry", "Ekf", "predict_entries",
           "predict_rows", "update_heading_entries", "update_heading_rows",
           "update_position_entries", "update_position_rows"]

_DEFAULT_KIN = Kinematics()
_ZERO3 = np.zeros((3, 3))
#: Parameters both estimators take.
_COMMON = {
    "encoder_noise_rad_s": Param(
        0.05, "rad/s", "assumed encoder noise, propagated", min=0.0, max=100.0
    ),
    "innovation_window_s": Param(
        20.0, "s", "window of the GPS innovation monitor", min=0.5, max=3600.0
    ),
    "initial_pose": Param(
        [0.0, 0.0, 0.0], "m, m, rad", "start pose [x, y, θ]", min=-1000000.0, max=1000000.0
    ),
}


class InnovationWindow:
    """Sliding-window vector mean of 2-D innovations.

    Parameters
    ----------
    window_s : float
        Length of the window (s). The value is NaN until innovations span at
        least half of it (a mean of one or two noisy fixes would look like a bias).

    Examples
    --------
    >>> w = InnovationWindow(4.0)
    >>> w.add(0.0, 1.0, 0.0); w.add(1.0, -1.0, 0.0); w.add(2.0, 0.0, 3.0)
    >>> w.value()
    1.0
    """

    def __init__(self, window_s: float) -> None:
        self.window_s = float(window_s)
        self.items: deque[tuple[float, float, float]] = deque()
        self.sx = 0.0
        self.sy = 0.0
        self.start: float | None = None
        self.last = 0.0

    def add(self, t: float, ex: float, ey: float) -> None:
        """Add the innovation ``(ex, ey)`` observed at ``t`` and drop old ones."""
        if self.start is None:
            self.start = t
        self.last = t
        self.items.append((t, ex, ey))
        self.sx += ex
        self.sy += ey
        while self.items and self.items[0][0] <= t - self.window_s:
            _, ox, oy = self.items.popleft()
            self.sx -= ox
            self.sy -= oy

    def value(self) -> float:
        """Norm of the mean innovation (NaN until the window is half full)."""
        n = len(self.items)
        if n == 0 or self.start is None or self.last - self.start < 0.5 * self.window_s:
            return math.nan
        return math.hypot(self.sx / n, self.sy / n)

    def clear(self) -> None:
        """Forget every innovation."""
        self.items.clear()
        self.sx = self.sy = 0.0
        self.start = None


class InnovationTrend:
    """t-statistic of the linear trend of 2-D innovations over a sliding window.

    Per axis, the least-squares slope ``b̂`` of the innovations against time over
    the last ``window_s``; the noise ``σ̂`` is measured from the same fixes by
    their first differences (``E[(e_k − e_{k−1})²] = 2σ²`` for white noise, hardly
    touched by a slow trend), pooled over both axes. The value is
    ``‖b̂‖ / (σ̂ / √Σ(t − t̄)²)``: the trend in units of its standard error, so its
    fault-free level does not depend on the GPS noise.

    Parameters
    ----------
    window_s : float
        Length of the window (s). NaN until the fixes span half of it (and at
        least 5 fixes).

    Examples
    --------
    A position error growing at 5 cm/s under ±0.1 m of alternating noise:

    >>> w = InnovationTrend(10.0)
    >>> for k in range(11):
    ...     w.add(float(k), 0.05 * k + 0.1 * (-1) ** k, 0.0)
    >>> round(w.value(), 1)
    4.8
    """

    def __init__(self, window_s: float) -> None:
        self.window_s = float(window_s)
        # rows (t, ex, ey) in a ring written twice (slot s and s + capacity), so the
        # window, oldest first, is the slice [head, head + count)
        self._ring = np.zeros((2 * 64, 3))
        self._head = 0
        self._count = 0

    @property
    def items(self) -> list[tuple[float, float, float]]:
        """The innovations ``(t, ex, ey)`` in the window, oldest first."""
        return [tuple(r) for r in self._rows().tolist()]

    @items.setter
    def items(self, rows: list[tuple[float, float, float]]) -> None:
        self.clear()
        for row in rows:
            self._put(*row)

    def _rows(self) -> np.ndarray:
        return self._ring[self._head : self._head + self._count]

    def _put(self, t: float, ex: float, ey: float) -> None:
        cap = len(self._ring) // 2
        if self._count == cap:  # double the ring
            rows = self._rows().copy()
            self._ring = np.zeros((4 * cap, 3))
            self._ring[:cap] = self._ring[2 * cap : 3 * cap] = rows
            self._head, cap = 0, 2 * cap
        slot = (self._head + self._count) % cap
        self._ring[slot] = self._ring[slot + cap] = (t, ex, ey)
        self._count += 1

    def add(self, t: float, ex: float, ey: float) -> None:
        """Add the innovation ``(ex, ey)`` observed at ``t`` and drop old ones."""
        self._put(t, ex, ey)
        ring, cap = self._ring, len(self._ring) // 2
        while self._count and ring[self._head, 0] <= t - self.window_s:
            self._head = (self._head + 1) % cap
            self._count -= 1

    def value(self) -> float:
        """‖slope‖ / standard error (NaN until the window is half full or without noise)."""
        n = self._count
        a = self._rows()  # (as np.array of the rows: the same layout, the same sums)
        if n < 5 or a[-1, 0] - a[0, 0] < 0.5 * self.window_s:
            return math.nan
        tt = a[:, 0] - a[:, 0].mean()
        stt = float(tt @ tt)
        d = a[1:, 1:] - a[:-1, 1:]  # (np.diff's own operation)
        var = float(np.mean(d * d)) / 2.0
        if stt <= 0.0 or var <= 0.0:
            return math.nan
        slope = tt @ (a[:, 1:] - a[:, 1:].mean(axis=0)) / stt
        return float(math.hypot(slope[0], slope[1]) / math.sqrt(var / stt))

    def clear(self) -> None:
        """Forget every innovation."""
        self._head = self._count = 0


def _wheel_body(enc, kin: Kinematics) -> tuple[float, float]:
    wl, wr = enc.tolist() if type(enc) is np.ndarray else (float(enc[0]), float(enc[1]))
    r = kin.wheel_radius_m
    return r * (wl + wr) / 2.0, r * (wr - wl) / kin.wheel_base_m


class _PoseEstimator(RuntimeModule):
    """The interface both pose estimators share (signals, residual, common parameters)."""

    parameters = _COMMON
    role = "estimator"
    inputs = ("encoder_speeds", "heading", "kinematics")
    optional_inputs = ("position",)
    outputs = ("pose_estimate", "covariance")
    output_sizes = {"pose_estimate": 3}
    output_elements = {"pose_estimate": ("x", "y", "theta")}
    residual_signals: ClassVar[tuple[str, ...]] = ("innovation",)


class Odometry(_PoseEstimator):
    """Dead reckoning: encoder speeds for the distance, IMU heading for the direction.

    The assumed sensor noises (``heading_noise_rad``, ``encoder_noise_rad_s``)
    set the covariance only. An IMU bias handed over by the estimator it replaces
    (the EKF's ``imu_bias`` state, e.g. when the GPS is lost) is taken off the IMU
    heading — when it is significant: ``|b| ≥ bias_significance · σ_b`` with
    ``σ_b`` the estimate's standard deviation (``imu_bias_std``; 2 by default, the
    95 % level: at 3 a drift the EKF had 2σ of after 25 s was thrown away, at 1 a
    wheel fault's transient taken for a bias, docs/hardening.md). A
    handed-over bias rate (``imu_bias_rate``, ``imu_bias_rate_std``), significant by
    the same test, carries the bias forward (``b ← b + ḃ·dt``), so a drifting gyro
    keeps being corrected after the GPS is lost. Handing over itself, it passes on the
    heading drift its ``drift_glr`` test found (|z| ≥ ``drift_handover_z``): the bias
    built up since the drift's onset as IMU bias (taken off the pose's heading, whose
    variance grows by the bias's), with a standard error that covers every onset the
    fixes cannot rule out, and the position corrected by the fitted innovation — the
    estimator taking over from a drifting dead reckoning starts on the drift instead
    of learning it from the GPS. Its rate is the slowest the fixes allow
    (:meth:`~archself_diffdrive.drift_glr.DriftWindows.estimate`): just after an alarm
    the best fit's rate is often several times the true one.

    Inputs ``encoder_speeds``, ``heading``, ``kinematics``; optional ``position``
    (GPS) used only for the residuals ``innovation``, ``innovation_trend`` and
    ``drift_glr`` (``drift_*`` parameters), never for the estimate. Outputs
    ``pose_estimate`` and ``covariance`` (3×3).

    Examples
    --------
    >>> o = Odometry("odo", {}, np.random.default_rng(0))
    >>> for k in range(21):
    ...     out = o.step(0.05 * k, 0.05, {"encoder_speeds": np.array([5.0, 5.0]),
    ...                                    "heading": 0.0})
    >>> out["pose_estimate"].round(3)
    array([0.5, 0. , 0. ])
    """

    finite_outputs = True  # sums of finite increments (needs_checks)
    state_fields = ("x", "y", "th")  # the variance grows open loop: not a signal

    parameters = {
        "heading_noise_rad": Param(0.005, "rad", "assumed IMU heading noise", min=0.0, max=3.2),
        "trend_window_s": Param(
            60.0, "s", "window of the innovation-trend statistic", min=5.0, max=3600.0
        ),
        "drift_window_s": Param(
            120.0, "s", "window of the drift GLR statistic", min=10.0, max=3600.0
        ),
        "drift_min_span_s": Param(
            20.0, "s", "the drift GLR is NaN until its fixes span this long", min=1.0,
            max=3600.0,
        ),
        "drift_min_support_s": Param(
            5.0, "s", "fixes a drift-onset candidate needs after it", min=1.0, max=3600.0
        ),
        "drift_walk_m_sqrt_s": Param(
            0.0, "m/√s", "random walk of dead reckoning against the true position (per"
            " coordinate; slip): part of the drift GLR's noise, 0 = the GPS noise alone",
            min=0.0, max=10.0,
        ),
        "bias_significance": Param(
            2.0,
            "",
            "a handed-over IMU bias (or rate) is used if ≥ this many standard deviations",
            min=0.0,
            max=100.0,
        ),
        "drift_handover_z": Param(
            4.0,
            "",
            "the drift found by drift_glr is handed over (IMU bias and rate) if |z| ≥ this",
            min=0.0,
            max=100.0,
        ),
        **_COMMON,
    }
    residual_signals = ("innovation", "innovation_trend", "drift_glr")
    lanes = "archself_diffdrive.lanes_estimators:OdometryLanes"

    def __init__(self, name, params, rng):
        self.monitor = InnovationWindow(math.nan)  # the windows are set by configure()
        self.trend = InnovationTrend(math.nan)
        self.drift = DriftGlr(math.nan, math.nan, math.nan)
        super().__init__(name, params, rng)
        self.x, self.y, self.th = (float(v) for v in self.params["initial_pose"])
        self.var_pos = 0.01
        self.bias = 0.0  # IMU heading bias taken off the heading (from a hand-over)
        self.bias_rate = 0.0  # and its rate (from a hand-over)
        self.started = False
        self.last_fix = (math.nan, math.nan)  # the last GPS fix used
        self.signals = {"innovation": math.nan, "innovation_trend": math.nan,
                        "drift_glr": math.nan}

    def configure(self) -> None:
        p = self.params
        self.sig_enc = float(p["encoder_noise_rad_s"])
        self.var_th = float(p["heading_noise_rad"]) ** 2
        self.monitor.window_s = float(p["innovation_window_s"])
        self.trend.window_s = float(p["trend_window_s"])
        self.drift.configure(float(p["drift_window_s"]), float(p["drift_min_span_s"]),
                             float(p["drift_min_support_s"]), float(p["drift_walk_m_sqrt_s"]) ** 2)

    def step(self, t, dt, inputs):
        kin = inputs.get("kinematics") or _DEFAULT_KIN
        enc = inputs.get("encoder_speeds")
        heading = inputs.get("heading")
        th0 = self.th
        if self.started:
            self.bias += self.bias_rate * dt
        if enc is not None:
            v, w = _wheel_body(enc, kin)
        else:
            v, w = 0.0, 0.0
        if heading is not None:
            th1 = th0 + ((float(heading) - self.bias - th0 + math.pi) % (2 * math.pi) - math.pi)
            if not self.started:
                th0 = th1
        else:
            th1 = th0 + w * dt
        if self.started:
            mid = 0.5 * (th0 + th1)
            dx, dy = v * dt * math.cos(mid), v * dt * math.sin(mid)
            self.x += dx
            self.y += dy
            self.drift.move(t, dx, dy)
            sv = kin.wheel_radius_m * self.sig_enc / math.sqrt(2.0)
            self.var_pos += (sv * dt) ** 2 + (v * dt) ** 2 * self.var_th
        self.started = True
        self.th = (th1 + math.pi) % (2 * math.pi) - math.pi
        pos = inputs.get("position")
        if pos is not None and (float(pos[0]), float(pos[1])) != self.last_fix:
            # (a fix equal to the last one is a stuck receiver, not a measurement)
            self.last_fix = (float(pos[0]), float(pos[1]))
            ex, ey = self.last_fix[0] - self.x, self.last_fix[1] - self.y
            self.monitor.add(t, ex, ey)
            self.trend.add(t, ex, ey)
            self.drift.add(t, ex, ey)
            self.signals["innovation"] = self.monitor.value()
            self.signals["innovation_trend"] = self.trend.value()
            self.signals["drift_glr"] = self.drift.value()
        return {
            "pose_estimate": np.array([self.x, self.y, self.th]),
            "covariance": self.covariance(),
        }

    def _significant(self, state, key: str) -> float:
        """``state[key]`` if significant against ``state[key + '_std']`` (if given), else 0."""
        value = float(state.get(key, 0.0))
        std = state.get(key + "_std")
        if std is None or abs(value) >= float(self.params["bias_significance"]) * std:
            return value
        return 0.0

    def covariance(self) -> np.ndarray:
        """Pose covariance (isotropic position variance, heading variance)."""
        c = _ZERO3.copy()  # (np.diag's 1.4 µs a step; this 0.3)
        c[0, 0] = c[1, 1] = self.var_pos
        c[2, 2] = self.var_th
        return c

    def export_state(self):
        state = {
            "pose": np.array([self.x, self.y, self.th]),
            "covariance": self.covariance(),
            "imu_bias": self.bias,
            "imu_bias_rate": self.bias_rate,
        }
        z, rate, rate_std, _, error, extra, extra_std = self.drift.estimate()
        if abs(z) >= float(self.params["drift_handover_z"]):  # False for NaN
            # the heading error the drift has built up by the last fix, taken off the
            # heading and handed over as IMU bias (the heading as unsure as the bias
            # taken off it), its slowest likely rate, and the position error it caused
            # (the fit's innovation), so that the next estimator starts on the drift
            th = (self.th - extra + math.pi) % (2 * math.pi) - math.pi
            cov = self.covariance()
            cov[2, 2] += extra_std**2
            state.update({
                "pose": np.array([self.x + error[0], self.y + error[1], th]),
                "covariance": cov,
                "imu_bias": self.bias + extra,
                "imu_bias_std": extra_std,
                "imu_bias_rate": self.bias_rate + rate,
                "imu_bias_rate_std": rate_std,
            })
        return state

    def import_state(self, state):
        if "pose" in state:
            self.x, self.y, self.th = (float(v) for v in np.asarray(state["pose"])[:3])
            self.started = True
        self.bias = self._significant(state, "imu_bias")
        self.bias_rate = self._significant(state, "imu_bias_rate")
        if "covariance" in state:
            c = np.asarray(state["covariance"], dtype=float)
            self.var_pos = float(max(c[0, 0], c[1, 1]))
        self.monitor.clear()
        self.trend.clear()
        self.drift.clear()
        # no stale residual from an earlier activation
        for key in self.signals:
            self.signals[key] = math.nan


class Ekf(_PoseEstimator):
    """Extended Kalman filter on ``[x, y, θ, b, ḃ]``: the IMU bias and its rate are states.

    Predict with the encoder speeds (unicycle model, encoder noise propagated
    into Q) and the bias as a local ramp (``b ← b + ḃ·dt``); update with the IMU
    heading (``h = θ + b``) every step and with a GPS position whenever a fix
    arrives. The three steps are closed forms written once on the entries of the state
    and of P's upper triangle (:func:`predict_entries`, :func:`update_heading_entries`,
    :func:`update_position_entries`): floats here, arrays over the lanes in
    :class:`~archself_diffdrive.lanes_estimators.EkfLanes`; filterpy's
    ``ExtendedKalmanFilter`` is their test oracle (tests/test_modules.py).

    Why a rate state: a gyro's heading bias drifts — an integrated rate error
    grows linearly in time (Groves, *Principles of GNSS, Inertial, and
    Multisensor Integrated Navigation Systems*, 2nd ed., §4.4.3). A random-walk
    bias model (``ḃ = 0``) follows such a ramp only with a lag proportional to the
    rate over its gain: with ``q_bias_rad`` = 0.002 rad/√s the filter ran 1.2–1.3 m
    off the path under a 2.8·10⁻³ rad/s drift; with the rate state (an integrated
    random walk, ``q_bias_rate_rad_s``) the lag is zero for a ramp and the same run
    stays at 0.52–0.66 m (seeds 1–4, fault-free 0.35–0.75 m). The rate's noise and
    prior (3·10⁻⁵ rad/s/√s, 10⁻³ rad/s) are small enough that a wheel fault's heading
    transient after a switch is not taken for a drift (larger values raised the
    actuator-fault errors by up to 0.2 m).

    The ``q_*`` parameters are additive process-noise densities, the ``r_*``
    measurement-noise standard deviations, the ``initial_*_std_*`` the initial
    uncertainty and the inflation added to a handed-over covariance. A handed-over
    IMU bias or rate comes with its standard error (``imu_bias_std``,
    ``imu_bias_rate_std``) when the estimator before knew it; the filter starts with
    at least that uncertainty on it (a drift estimate from dead reckoning's
    ``drift_glr`` can be rougher than the prior).

    Inputs ``encoder_speeds``, ``heading``, ``kinematics``; optional ``position``.
    Outputs ``pose_estimate`` and ``covariance`` (3×3 pose block). Attributes
    ``x``/``P`` give the full state (5) and covariance (5×5; filterpy's names).
    """

    state_fields = ("x",)  # pose, heading bias and rate; P follows its own Riccati map

    parameters = {
        "q_position_m": Param(
            0.02, "m/√s", "process noise density of the position", min=0.0, max=100.0
        ),
        "q_heading_rad": Param(
            0.01, "rad/√s", "process noise density of the heading", min=0.0, max=10.0
        ),
        "q_bias_rad": Param(
            0.002, "rad/√s", "process noise density of the IMU bias", min=0.0, max=10.0
        ),
        "q_bias_rate_rad_s": Param(
            3e-5, "rad/s/√s", "process noise density of the IMU-bias rate", min=0.0, max=1.0
        ),
        "r_gps_m": Param(
            0.3, "m", "GPS noise (standard deviation per coordinate)", min=0.0001, max=1000.0
        ),
        "r_heading_rad": Param(
            0.005, "rad", "IMU heading noise (standard deviation)", min=1e-06, max=3.2
        ),
        "initial_position_std_m": Param(
            0.5, "m", "initial position uncertainty", min=0.0, max=10000.0
        ),
        "initial_heading_std_rad": Param(
            0.05, "rad", "initial heading uncertainty", min=0.0, max=3.2
        ),
        "initial_bias_std_rad": Param(
            0.05, "rad", "initial IMU-bias uncertainty", min=0.0, max=3.2
        ),
        "initial_bias_rate_std_rad_s": Param(
            0.001, "rad/s", "initial IMU-bias-rate uncertainty", min=0.0, max=1.0
        ),
        **_COMMON,
    }

    lanes = "archself_diffdrive.lanes_estimators:EkfLanes"
    _N = 5  # state size

    def __init__(self, name, params, rng):
        self.monitor = InnovationWindow(math.nan)  # its window is set by configure()
        super().__init__(name, params, rng)
        # the state and P live as floats (``_x``, P's upper triangle ``_p``) while the filter
        # steps, as arrays (``_xa``, ``_pa``) once read through ``x`` / ``P``: one form at a
        # time, so an array read and changed in place is what the next step starts from
        self._x: list[float] = []
        self._p: list[float] = []
        self._xa: np.ndarray | None = None
        self._pa: np.ndarray | None = None
        self.x = np.array([*map(float, self.params["initial_pose"]), 0.0, 0.0])
        self.P = self._initial_covariance()
        self.started = False
        self.signals = {"innovation": math.nan}

    def configure(self) -> None:
        p = self.params
        self.r_head = float(p["r_heading_rad"])
        self.sig_enc = float(p["encoder_noise_rad_s"])
        self.R_gps = np.eye(2) * float(p["r_gps_m"]) ** 2
        self._r2_gps = float(self.R_gps[0, 0])
        q = ("q_position_m", "q_position_m", "q_heading_rad", "q_bias_rad", "q_bias_rate_rad_s")
        self._q2 = tuple(float(p[k]) ** 2 for k in q)
        sd = (
            "initial_position_std_m",
            "initial_heading_std_rad",
            "initial_bias_std_rad",
            "initial_bias_rate_std_rad_s",
        )
        self._p0 = tuple(float(p[k]) for k in sd)
        self.monitor.window_s = float(p["innovation_window_s"])

    def _initial_covariance(self) -> np.ndarray:
        pos, th, b, rate = self._p0
        return np.diag([pos**2, pos**2, th**2, b**2, rate**2])

    @property
    def x(self) -> np.ndarray:
        """The state ``[x, y, θ, b, ḃ]`` (filterpy's name; changed in place, it is kept)."""
        if self._xa is None:
            self._xa = np.array(self._x)
        return self._xa

    @x.setter
    def x(self, value) -> None:
        self._xa = np.asarray(value, dtype=float)

    @property
    def P(self) -> np.ndarray:  # noqa: N802 - filterpy's name
        """The covariance (5×5; filterpy's name; changed in place, it is kept)."""
        if self._pa is None:
            self._pa = np.array(self._p)[_FULL]
        return self._pa

    @P.setter
    def P(self, value) -> None:  # noqa: N802
        self._pa = np.asarray(value, dtype=float)

    def _entries(self) -> tuple[list[float], list[float]]:
        """The state and P's upper triangle as floats (the ``*_entries`` functions'); the
        arrays read through ``x`` / ``P`` are taken back first."""
        if self._xa is not None:
            self._x, self._xa = self._xa.tolist(), None
        if self._pa is not None:
            self._p, self._pa = self._pa[_UI, _UJ].tolist(), None
        return self._x, self._p

    def _set(self, x: list[float], p: list[float]) -> None:
        self._x, self._p, self._xa, self._pa = x, p, None, None

    def _predict(self, x, p, dt: float, enc, kin: Kinematics):
        v, w = _wheel_body(enc, kin) if enc is not None else (0.0, 0.0)
        sig2 = (self.sig_enc if enc is not None else 10.0) ** 2
        return predict_entries(x, p, dt, v, w, sig2, kin.wheel_radius_m, kin.wheel_base_m,
                               self._q2)

    def _update_position(self, x, p, pos) -> tuple[list, list, float, float]:
        """The GPS update and the innovation ``z − Hx``; raises ValueError (as filterpy's
        update does) when the position covariance is not finite."""
        if not (math.isfinite(p[0]) and math.isfinite(p[1]) and math.isfinite(p[5])):
            self._set(x, p)
            raise ValueError("array must not contain infs or NaNs")
        z0, z1 = float(pos[0]), float(pos[1])
        ex, ey = z0 - x[0], z1 - x[1]
        x, p = update_position_entries(x, p, z0, z1, self._r2_gps)
        return x, p, ex, ey

    def predict(self, dt: float, enc, kin: Kinematics = _DEFAULT_KIN) -> None:
        """Propagate state and covariance over ``dt`` with encoder speeds ``enc``
        (:func:`predict_entries`)."""
        self._set(*self._predict(*self._entries(), dt, enc, kin))

    def update_heading(self, heading: float) -> None:
        """Update with an IMU heading ``h = θ + b`` (:func:`update_heading_entries`)."""
        self._set(*update_heading_entries(*self._entries(), float(heading), self.r_head))

    def update_position(self, pos) -> tuple[float, float]:
        """Update with a GPS fix (:func:`update_position_entries`).

        Returns the innovation ``z − Hx``.

        Raises
        ------
        ValueError
            The position covariance is not finite (as filterpy's update raises).
        """
        x, p, ex, ey = self._update_position(*self._entries(), pos)
        self._set(x, p)
        return ex, ey

    # data flow ---------------------------------------------------------------
    def step(self, t, dt, inputs):
        kin = inputs.get("kinematics") or _DEFAULT_KIN
        heading = inputs.get("heading")
        x, p = self._entries()
        if self.started:
            x, p = self._predict(x, p, dt, inputs.get("encoder_speeds"), kin)
        elif heading is not None:
            x = [*x[:2], float(heading) - x[3], *x[3:]]
        self.started = True
        if heading is not None:
            x, p = update_heading_entries(x, p, float(heading), self.r_head)
        pos = inputs.get("position")
        if pos is not None:
            x, p, ex, ey = self._update_position(x, p, pos)
            self.monitor.add(t, ex, ey)
            self.signals["innovation"] = self.monitor.value()
        self._set(x, p)
        return {"pose_estimate": np.array(x[:3]), "covariance": np.array(
            [[p[0], p[1], p[2]], [p[1], p[5], p[6]], [p[2], p[6], p[9]]])}

    def export_state(self):
        return {
            "pose": self.x[:3].copy(),
            "covariance": self.P[:3, :3].copy(),
            "imu_bias": float(self.x[3]),
            "imu_bias_std": math.sqrt(max(float(self.P[3, 3]), 0.0)),
            "imu_bias_rate": float(self.x[4]),
            "imu_bias_rate_std": math.sqrt(max(float(self.P[4, 4]), 0.0)),
        }

    def import_state(self, state):
        if "pose" in state:
            pose = np.asarray(state["pose"], dtype=float)[:3]
            bias = float(state.get("imu_bias", 0.0))
            rate = float(state.get("imu_bias_rate", 0.0))
            self.x = np.array([pose[0], pose[1], pose[2], bias, rate])
            self.started = True
        P = self._initial_covariance()
        if "covariance" in state:
            P[:3, :3] += np.asarray(state["covariance"], dtype=float)[:3, :3]
        for k, key in ((3, "imu_bias_std"), (4, "imu_bias_rate_std")):
            std = state.get(key)  # a bias handed over less sure than the prior widens it
            if std is not None and math.isfinite(std):
                P[k, k] = max(P[k, k], float(std) ** 2)
        self.P = P
        self.monitor.clear()
        self.signals["innovation"] = math.nan  # no stale residual from an earlier activation


#: The covariance's upper triangle, row by row: entry k of ``p`` is ``P[_UI[k], _UJ[k]]``.
_UI, _UJ = np.triu_indices(5)
#: ``P`` from its upper triangle: ``P = p[_FULL]`` (a symmetric matrix, exactly).
_FULL = np.zeros((5, 5), dtype=int)
_FULL[_UI, _UJ] = _FULL[_UJ, _UI] = np.arange(15)
#: ``_AT[i][j]``: the entry of ``p`` holding ``P[i, j]``.
_AT = _FULL.tolist()


def _trig(a):
    """``(cos a, sin a)``: math's for a float, numpy's for an array."""
    if isinstance(a, np.ndarray):
        return np.cos(a), np.sin(a)
    return math.cos(a), math.sin(a)


def _wrap(a):
    """An angle into [−π, π)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


# The EKF's three steps, written once on the entries of the state x (5) and of the
# covariance's upper triangle p (15): each entry a float (one run) or an array over
# lanes (EkfLanes), the same floating-point operations in the same order for both.
# filterpy's ExtendedKalmanFilter is the tests' oracle (tests/test_modules.py).


def predict_entries(x, p, dt, v, w, sig2, r, base, q):
    """:meth:`Ekf.predict` on entries: ``x`` (5), ``p`` (15, upper triangle of P).

    ``x ← f(x, u)`` (unicycle, midpoint heading; ``b ← b + ḃ dt``), ``P ← F P Fᵀ + Q``
    with ``Q = σ_enc² G Gᵀ + diag(q²) dt``, G the Jacobian of the motion with respect to
    the two wheel speeds, ``F = I + f₀ e₀e₂ᵀ + f₁ e₁e₂ᵀ + dt e₃e₄ᵀ``: three row and three
    column operations. ``v``, ``w`` (body speeds), ``sig2`` (encoder variance), ``r``,
    ``base`` (wheels) and the five process-noise densities squared ``q``: entries too.
    """
    x0, x1, th, b, bd = x
    mid = th + 0.5 * w * dt
    c, s = _trig(mid)
    f0 = -v * dt * s  # F[0, 2]
    f1 = v * dt * c  # F[1, 2]
    h = 0.5 * r * dt
    k = r * dt / base
    u0, u1 = h * c, h * s
    (p00, p01, p02, p03, p04, p11, p12, p13, p14, p22, p23, p24, p33, p34, p44) = p
    # F's row operations (rows 0, 1 and 3), then its column operations: written out
    r02, r12, r34 = p02 + f0 * p22, p12 + f1 * p22, p34 + dt * p44
    r04, r14 = p04 + f0 * p24, p14 + f1 * p24
    out = [
        (p00 + f0 * p02) + f0 * r02, (p01 + f0 * p12) + f1 * r02, r02,
        (p03 + f0 * p23) + dt * r04, r04,
        (p11 + f1 * p12) + f1 * r12, r12, (p13 + f1 * p23) + dt * r14, r14,
        p22, p23 + dt * p24, p24,
        (p33 + dt * p34) + dt * r34, r34, p44,
    ]
    sig2_2 = 2 * sig2
    out[0] = out[0] + (q[0] * dt + sig2_2 * u0 * u0)
    out[1] = out[1] + sig2_2 * u0 * u1
    out[5] = out[5] + (q[1] * dt + sig2_2 * u1 * u1)
    out[9] = out[9] + (q[2] * dt + sig2_2 * k * k)
    out[12] = out[12] + q[3] * dt
    out[14] = out[14] + q[4] * dt
    vdt = v * dt
    return [x0 + vdt * c, x1 + vdt * s, th + w * dt, b + bd * dt, bd], out


def update_heading_entries(x, p, heading, r_head):
    """:meth:`Ekf.update_heading` on entries: ``H = [0, 0, 1, 1, 0]``, Joseph form
    ``(I − KH) P (I − KH)ᵀ + K R Kᵀ`` written out (the angle residual wrapped)."""
    r2 = r_head * r_head
    y = _wrap(heading - (x[2] + x[3]))
    (p00, p01, p02, p03, p04, p11, p12, p13, p14, p22, p23, p24, p33, p34, p44) = p
    h0, h1, h2, h3, h4 = p02 + p03, p12 + p13, p22 + p23, p23 + p33, p24 + p34  # P Hᵀ
    S = h2 + h3 + r2
    k0, k1, k2, k3, k4 = h0 / S, h1 / S, h2 / S, h3 / S, h4 / S  # K
    # ci = (I − K H) P Hᵀ, row by row (P[i, 2] − kᵢ h₂ + P[i, 3] − kᵢ h₃), and r2·K
    c0, c1 = (p02 - k0 * h2) + (p03 - k0 * h3), (p12 - k1 * h2) + (p13 - k1 * h3)
    c2, c3 = (p22 - k2 * h2) + (p23 - k2 * h3), (p23 - k3 * h2) + (p33 - k3 * h3)
    c4 = (p24 - k4 * h2) + (p34 - k4 * h3)
    q0, q1, q2, q3, q4 = r2 * k0, r2 * k1, r2 * k2, r2 * k3, r2 * k4
    out = [  # P[i, j] − kᵢ hⱼ − cᵢ kⱼ + r2 kᵢ kⱼ over the upper triangle
        (p00 - k0 * h0) - c0 * k0 + q0 * k0, (p01 - k0 * h1) - c0 * k1 + q0 * k1,
        (p02 - k0 * h2) - c0 * k2 + q0 * k2, (p03 - k0 * h3) - c0 * k3 + q0 * k3,
        (p04 - k0 * h4) - c0 * k4 + q0 * k4,
        (p11 - k1 * h1) - c1 * k1 + q1 * k1, (p12 - k1 * h2) - c1 * k2 + q1 * k2,
        (p13 - k1 * h3) - c1 * k3 + q1 * k3, (p14 - k1 * h4) - c1 * k4 + q1 * k4,
        (p22 - k2 * h2) - c2 * k2 + q2 * k2, (p23 - k2 * h3) - c2 * k3 + q2 * k3,
        (p24 - k2 * h4) - c2 * k4 + q2 * k4,
        (p33 - k3 * h3) - c3 * k3 + q3 * k3, (p34 - k3 * h4) - c3 * k4 + q3 * k4,
        (p44 - k4 * h4) - c4 * k4 + q4 * k4,
    ]
    x0, x1, x2, x3, x4 = x
    x = [x0 + k0 * y, x1 + k1 * y, _wrap(x2 + k2 * y), x3 + k3 * y, x4 + k4 * y]
    return x, out


def update_position_entries(x, p, z0, z1, r2):
    """:meth:`Ekf.update_position` on entries: a GPS fix ``(z0, z1)`` with
    ``H = [I₂ 0]`` and ``R = r2·I₂``, Joseph form ``(I − KH) P (I − KH)ᵀ + K R Kᵀ``
    written out: ``S`` is P's leading 2×2 block plus R, inverted by its adjugate,
    ``K = P[:, :2] S⁻¹``."""
    P = [[p[_AT[i][j]] for j in range(5)] for i in range(5)]
    a, b, d = P[0][0] + r2, P[0][1], P[1][1] + r2  # S = [[a, b], [b, d]]
    det = a * d - b * b
    K0 = [(P[i][0] * d - P[i][1] * b) / det for i in range(5)]
    K1 = [(P[i][1] * a - P[i][0] * b) / det for i in range(5)]
    A = [[P[i][j] - (K0[i] * P[0][j] + K1[i] * P[1][j]) for j in range(5)]
         for i in range(5)]  # (I − K H) P
    out = [A[i][j] - (A[i][0] * K0[j] + A[i][1] * K1[j])
           + r2 * (K0[i] * K0[j] + K1[i] * K1[j])
           for i, j in zip(_UI.tolist(), _UJ.tolist(), strict=True)]
    y0, y1 = z0 - x[0], z1 - x[1]
    return [x[i] + (K0[i] * y0 + K1[i] * y1) for i in range(5)], out


def _rows(fn, x, P, *args):
    """``fn`` (an ``*_entries`` step) on rows: ``x`` (L, 5), ``P`` (L, 5, 5)."""
    xe, pe = fn(list(x.T), list(P[:, _UI, _UJ].T), *args)
    return np.stack(xe, 1), np.stack(pe, 1)[:, _FULL]


def predict_rows(x, P, dt, v, w, sig2, r, base, q):
    """:func:`predict_entries` of every row: ``x`` (L, 5), ``P`` (L, 5, 5), ``q`` (L, 5)."""
    return _rows(predict_entries, x, P, dt, v, w, sig2, r, base, list(q.T))


def update_heading_rows(x, P, heading, r_head):
    """:func:`update_heading_entries` of every row."""
    return _rows(update_heading_entries, x, P, heading, r_head)


def update_position_rows(x, P, z, r2):
    """:func:`update_position_entries` of every row: fixes ``z`` (L, 2)."""
    return _rows(update_position_entries, x, P, z[:, 0], z[:, 1], r2)
