"""The pose estimators in N lanes: dead reckoning and the 5-state EKF, batched.

:class:`OdometryLanes` and :class:`EkfLanes` are the :class:`~archself.lanes.LaneModule`
classes of :class:`~archself_diffdrive.estimators.Odometry` and
:class:`~archself_diffdrive.estimators.Ekf`: every lane computes what its per-run
instance computes from the same inputs, with the same floating-point operations in
the same order — the EKF's closed-form predict, heading and GPS updates are the
per-run instance's own (:func:`~archself_diffdrive.estimators.predict_entries`,
:func:`~archself_diffdrive.estimators.update_heading_entries`,
:func:`~archself_diffdrive.estimators.update_position_entries`: floats there, rows
of L lanes here) — so a lane's pose and covariance are its run's but for an ulp of
``np.cos`` (none on x86-64 with numpy 2.4: the poses, commands and J of a1–a4 runs
are the per-run runs' bit for bit). The residual signals may differ in the last
bits (``np.hypot`` against ``math.hypot``; the trend's sums in another order). The
parameters come from each lane's instance (a sweep keeps its values per lane). The
GPS ``position`` is absent in most steps and absent per lane in others (NaN rows):
the update and the innovation statistics run only in the lanes with a fix; the
sliding windows are :class:`~archself_diffdrive.lanes_windows.LaneWindows`. A lane
whose covariance went non-finite is reported as failed at a fix (``raised
ValueError``, where the per-run update raises). ``covariance`` is published
flattened, ``(L, 9)``, as :func:`archself.lanes.stack` gives a 3×3 per lane.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from archself.lanes.module import LaneModule, ModelFields
from archself_diffdrive.drift_glr import DriftWindows
from archself_diffdrive.estimators import (
    _DEFAULT_KIN,
    _FULL,
    _UI,
    _UJ,
    predict_entries,
    update_heading_entries,
    update_position_entries,
)
from archself_diffdrive.lanes_windows import LaneWindows

__all__ = ["EkfLanes", "OdometryLanes", "kinematics_fields"]

PI = math.pi
TWO_PI = 2 * math.pi
#: the rows of ``p`` (P's upper triangle) that make P[:3, :3], row by row
_COV = _FULL[:3, :3].ravel()


def _entries(fn, x, p, *args) -> tuple[np.ndarray, np.ndarray]:
    """``fn`` (an ``*_entries`` step) on entry-major lanes: ``x`` (5, L), ``p`` (15, L)."""
    xe, pe = fn(list(x), list(p), *args)
    return np.array(xe), np.array(pe)


def kinematics_fields() -> ModelFields:
    """Wheel radius and base per lane; the per-run modules' default model where absent."""
    return ModelFields(
        {"wheel_radius_m": _DEFAULT_KIN.wheel_radius_m, "wheel_base_m": _DEFAULT_KIN.wheel_base_m}
    )


def wheel_body(
    enc: np.ndarray | None, r: np.ndarray, base: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``(v, ω)`` per lane from encoder speeds (0 where absent), and the absent lanes' mask.

    The mask is None when every lane has a measurement.
    """
    if enc is None:
        return np.zeros(n), np.zeros(n), np.ones(n, dtype=bool)
    wl, wr = enc[:, 0], enc[:, 1]
    v = r * (wl + wr) / 2.0
    w = r * (wr - wl) / base
    absent = np.isnan(wl)
    if not absent.any():
        return v, w, None
    return np.where(absent, 0.0, v), np.where(absent, 0.0, w), absent


class _EstimatorLanes(LaneModule):
    """What both estimators share: the kinematics input, the non-finite check."""

    def __init__(self, modules: Sequence[Any]) -> None:
        self.kin = kinematics_fields()
        self.started = np.zeros(len(modules), dtype=bool)
        self.monitor = LaneWindows(len(modules))
        self.innovation = np.full(len(modules), math.nan)
        super().__init__(modules)

    def _flag_nonfinite(self, idx: np.ndarray | slice, pose: np.ndarray, cov: np.ndarray) -> None:
        """Report the lanes whose output is not finite (the per-run system's check)."""
        if math.isfinite(float(pose.sum()) + float(cov.sum())):
            return
        bad = ~(np.isfinite(pose).all(1) & np.isfinite(cov).all(1))
        for i in self.indices(idx)[bad]:
            self.failed.setdefault(int(i), "non-finite output")  # a raise came first


class OdometryLanes(_EstimatorLanes):
    """:class:`~archself_diffdrive.estimators.Odometry` in N lanes (see the module doc)."""

    def __init__(self, modules: Sequence[Any]) -> None:
        n = len(modules)
        self.pose = np.zeros((n, 3))
        self.var_pos = np.zeros(n)
        self.bias = np.zeros(n)
        self.bias_rate = np.zeros(n)
        self.trend = LaneWindows(n)
        self.innovation_trend = np.full(n, math.nan)
        self.drift = DriftWindows(n)
        self.drift_moved = np.zeros((n, 4))  # DriftGlr.moved
        self.drift_last = np.zeros(n)  # DriftGlr.last
        self.drift_glr = np.full(n, math.nan)
        self.last_fix = np.full((n, 2), math.nan)  # Odometry.last_fix
        super().__init__(modules)

    def step(self, t, dt, inputs, lanes):
        pose = self.pose[lanes]
        x, y, th0 = pose[:, 0], pose[:, 1], pose[:, 2]
        n = len(x)
        r, base = self.kin(inputs.get("kinematics"), n)
        started = self.started[lanes]
        every = bool(started.all())
        bias = self.bias[lanes]
        moved = bias + self.bias_rate[lanes] * dt
        bias = moved if every else np.where(started, moved, bias)
        v, w, _ = wheel_body(inputs.get("encoder_speeds"), r, base, n)
        th1 = th0 + w * dt
        heading = inputs.get("heading")
        if heading is not None:
            measured = th0 + ((heading - bias - th0 + PI) % TWO_PI - PI)
            has = ~np.isnan(heading)
            th1 = np.where(has, measured, th1)
        mid = 0.5 * (th0 + th1)
        vdt = v * dt
        var_th = self.var_th[lanes]
        sv = r * self.sig_enc[lanes] / math.sqrt(2.0)
        dx, dy = vdt * np.cos(mid), vdt * np.sin(mid)
        x1 = x + dx
        y1 = y + dy
        var1 = self.var_pos[lanes] + ((sv * dt) ** 2 + vdt**2 * var_th)
        if not every:
            x1, y1 = np.where(started, x1, x), np.where(started, y1, y)
            var1 = np.where(started, var1, self.var_pos[lanes])
            dx, dy = np.where(started, dx, 0.0), np.where(started, dy, 0.0)
        self._drift_move(t, lanes, dx, dy)
        out = np.stack([x1, y1, (th1 + PI) % TWO_PI - PI], axis=1)
        self.pose[lanes] = out
        self.var_pos[lanes] = var1
        self.bias[lanes] = bias
        self.started[lanes] = True
        pos = inputs.get("position")
        if pos is not None:
            last = self.last_fix[lanes]
            has = ~np.isnan(pos[:, 0]) & ((pos[:, 0] != last[:, 0]) | (pos[:, 1] != last[:, 1]))
            if has.any():
                idx = self.indices(lanes)[has]
                self.last_fix[idx] = pos[has, :2]
                e = pos[has, :2] - out[has, :2]
                self.monitor.add(t, idx, e)
                self.trend.add(t, idx, e)
                self.drift.add(t, idx, e, self.drift_moved[idx])
                self.drift_moved[idx] = 0.0
                self.drift_last[idx] = t
                self.innovation[idx] = self.monitor.mean_norm(idx)
                self.innovation_trend[idx] = self.trend.trend(idx)
                self.drift_glr[idx] = self.drift.value(idx)
        cov = np.zeros((n, 9))
        cov[:, 0] = cov[:, 4] = var1
        cov[:, 8] = var_th
        self._flag_nonfinite(lanes, out, cov)
        return {"pose_estimate": out, "covariance": cov}

    def _drift_move(self, t: float, lanes, dx: np.ndarray, dy: np.ndarray) -> None:
        """``DriftGlr.move`` of every lane (a lane not started moves by 0)."""
        lag = t - self.drift_last[lanes]
        m = self.drift_moved[lanes]
        m[:, 0] += dy
        m[:, 1] -= dx
        m[:, 2] += lag * dy
        m[:, 3] -= lag * dx
        self.drift_moved[lanes] = m

    def local_signals(self, lanes):
        return {
            "innovation": self.innovation[lanes].copy(),
            "innovation_trend": self.innovation_trend[lanes].copy(),
            "drift_glr": self.drift_glr[lanes].copy(),
        }

    def load(self, lanes):
        for i in self.indices(lanes):
            m = self.modules[i]
            self.pose[i] = (m.x, m.y, m.th)
            self.var_pos[i] = m.var_pos
            self.bias[i], self.bias_rate[i] = m.bias, m.bias_rate
            self.started[i] = m.started
            self.monitor.load(i, m.monitor)
            self.trend.load(i, m.trend)
            self.drift.copy_lane(i, m.drift.windows, 0)
            self.drift_moved[i] = m.drift.moved
            self.drift_last[i] = m.drift.last
            self.innovation[i] = m.signals["innovation"]
            self.innovation_trend[i] = m.signals["innovation_trend"]
            self.drift_glr[i] = m.signals["drift_glr"]
            self.last_fix[i] = m.last_fix
        self.sig_enc = self.lane_attr("sig_enc")
        self.var_th = self.lane_attr("var_th")

    def store(self, lanes):
        for i in self.indices(lanes):
            m = self.modules[i]
            m.x, m.y, m.th = self.pose[i].tolist()
            m.var_pos = float(self.var_pos[i])
            m.bias, m.bias_rate = float(self.bias[i]), float(self.bias_rate[i])
            m.started = bool(self.started[i])
            self.monitor.store(i, m.monitor)
            self.trend.store(i, m.trend)
            m.drift.windows.copy_lane(0, self.drift, i)
            m.drift.moved = self.drift_moved[i].tolist()
            m.drift.last = float(self.drift_last[i])
            m.signals["innovation"] = float(self.innovation[i])
            m.signals["innovation_trend"] = float(self.innovation_trend[i])
            m.signals["drift_glr"] = float(self.drift_glr[i])
            m.last_fix = (float(self.last_fix[i, 0]), float(self.last_fix[i, 1]))

    def state_rows(self, lanes):
        return self.pose[lanes].copy()  # x, y, th

    def set_state_rows(self, x, lanes):
        if x.shape[1] != 3:
            return False
        self.pose[lanes] = x
        return True


class EkfLanes(_EstimatorLanes):
    """:class:`~archself_diffdrive.estimators.Ekf` in N lanes.

    State entry-major: ``x`` (5, N) and P's upper triangle ``p`` (15, N), so an entry of
    all lanes is one contiguous row and a step hands the ``*_entries`` functions row
    views, never gathering or stacking the lanes (P in full only in ``store``).
    """

    def __init__(self, modules: Sequence[Any]) -> None:
        n = len(modules)
        self.x = np.zeros((5, n))
        self.p = np.zeros((15, n))
        super().__init__(modules)

    def step(self, t, dt, inputs, lanes):
        x, p = self.x[:, lanes], self.p[:, lanes]  # copies for an index array, views for ALL
        n = x.shape[1]
        r, base = self.kin(inputs.get("kinematics"), n)
        heading = inputs.get("heading")
        started = self.started[lanes]
        enc = inputs.get("encoder_speeds")
        if started.all():
            x, p = self._predict(x, p, dt, enc, r, base, lanes)
        else:
            go = np.flatnonzero(started)
            if len(go):
                sub = self.indices(lanes)[go]
                x[:, go], p[:, go] = self._predict(
                    x[:, go], p[:, go], dt, None if enc is None else enc[go], r[go], base[go], sub
                )
            if heading is not None:
                first = ~started & ~np.isnan(heading)
                x[2, first] = heading[first] - x[3, first]
        self.started[lanes] = True
        if heading is not None:
            has = ~np.isnan(heading)
            if has.all():
                x, p = _entries(update_heading_entries, x, p, heading, self.r_head[lanes])
            elif has.any():
                x[:, has], p[:, has] = _entries(
                    update_heading_entries, x[:, has], p[:, has], heading[has],
                    self.r_head[lanes][has],
                )
        pos = inputs.get("position")
        if pos is not None:
            has = ~np.isnan(pos[:, 0])
            # a covariance gone non-finite makes the per-run update raise
            raised = has & ~(np.isfinite(p[0]) & np.isfinite(p[1]) & np.isfinite(p[5]))
            if raised.any():
                for i in self.indices(lanes)[raised]:
                    self.failed[int(i)] = "raised ValueError"
                has &= ~raised
            if has.any():
                z = pos[has, :2]
                e = z - x[:2, has].T
                x[:, has], p[:, has] = _entries(
                    update_position_entries, x[:, has], p[:, has], z[:, 0], z[:, 1],
                    self.r2_gps[lanes][has],
                )
                idx = self.indices(lanes)[has]
                self.monitor.add(t, idx, e)
                self.innovation[idx] = self.monitor.mean_norm(idx)
        self.x[:, lanes], self.p[:, lanes] = x, p
        pose = x[:3].T.copy()
        cov = p[_COV].T.copy()
        self._flag_nonfinite(lanes, pose, cov)
        return {"pose_estimate": pose, "covariance": cov}

    def _predict(self, x, p, dt, enc, r, base, lanes):
        """:func:`~archself_diffdrive.estimators.predict_entries` of every lane."""
        v, w, absent = wheel_body(enc, r, base, x.shape[1])
        sig_enc = self.sig_enc[lanes]
        sig2 = (sig_enc if absent is None else np.where(absent, 10.0, sig_enc)) ** 2
        return _entries(predict_entries, x, p, dt, v, w, sig2, r, base, list(self.q2[:, lanes]))

    def local_signals(self, lanes):
        return {"innovation": self.innovation[lanes].copy()}

    def load(self, lanes):
        for i in self.indices(lanes):
            m = self.modules[i]
            self.x[:, i] = m.x
            self.p[:, i] = m.P[_UI, _UJ]
            self.started[i] = m.started
            self.monitor.load(i, m.monitor)
            self.innovation[i] = m.signals["innovation"]
        self.r_head = self.lane_attr("r_head")
        self.sig_enc = self.lane_attr("sig_enc")
        self.r2_gps = np.array([m.R_gps[0, 0] for m in self.modules], dtype=float)
        self.q2 = np.array([m._q2 for m in self.modules], dtype=float).T

    def store(self, lanes):
        for i in self.indices(lanes):
            m = self.modules[i]
            m.x = self.x[:, i].copy()
            m.P = self.p[:, i][_FULL]
            m.started = bool(self.started[i])
            self.monitor.store(i, m.monitor)
            m.signals["innovation"] = float(self.innovation[i])

    def state_rows(self, lanes):
        return self.x[:, lanes].T.copy()  # x: pose, heading bias and rate

    def set_state_rows(self, x, lanes):
        if x.shape[1] != 5:
            return False
        self.x[:, lanes] = x.T
        return True
