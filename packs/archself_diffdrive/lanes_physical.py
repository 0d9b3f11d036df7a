"""Lane-batched diff-drive physical modules (issue 16).

The batched counterparts (:class:`archself.lanes.LaneModule`) of the per-run types of
:mod:`archself_diffdrive.physical` (the planner and model nodes are in
:mod:`archself_diffdrive.lanes_planning`): each holds one module's state in N lanes (runs)
with a leading lane axis and steps them with numpy operations written in the
per-run code's order, so a lane computes the same floats as its per-run instance
(``np.sin``/``np.cos`` may differ from :mod:`math` in the last bit). Parameters are
read per lane in :meth:`~archself.lanes.LaneModule.load` (a sweep keeps each
point's values); random draws come from each lane's own stream through
:class:`archself.lanes.LaneNormals`, as many and in the order the per-run code draws
them (the GPS only at fixes, the plant's slip only where ``slip_variance_m > 0``).
:meth:`~archself.lanes.LaneModule.store` writes a lane's state back into its
per-run instance (the per-run API — ``export_state``, snapshots — then sees it).
A lane whose output goes non-finite is reported in ``failed`` (the per-run
executor's "non-finite output") and published as absent.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.lanes.module import LaneModule, LaneNormals, lane_count

__all__ = [
    "DiffDrivePlantLanes",
    "WheelActuatorLanes",
    "WheelEncodersLanes",
    "ImuLanes",
    "GpsLanes",
]

_TWO_PI = 2.0 * math.pi
_WHEEL_INPUTS = ("wheel_speed_left", "wheel_speed_right")


def _scalar(value: Any, n: int) -> np.ndarray:
    """A scalar lane value as an ``(n,)`` float array, NaN where absent."""
    if value is None:
        return np.full(n, math.nan)
    arr = np.asarray(value, dtype=float)
    return arr[:, 0] if arr.ndim == 2 else arr


def _lag(dt: float, tau: np.ndarray) -> np.ndarray:
    """``1 − exp(−dt/τ)`` per lane where ``τ > 0``, else 1 (with :func:`math.exp`)."""
    return np.array([1.0 - math.exp(-dt / x) if x > 0 else 1.0 for x in tau.tolist()])


class _Lanes(LaneModule):
    """The pack's batched types: the non-finite screen (``_read``, ``_mask``: the core's)."""

    # per-lane parameters and state, set by ``_read`` in ``load`` (arrays over the lanes)
    limit: np.ndarray
    response: np.ndarray
    smoothing: np.ndarray
    prev: np.ndarray
    error: np.ndarray
    expected: np.ndarray
    speed: np.ndarray
    ds: np.ndarray
    length: np.ndarray

    def _screen(self, value: np.ndarray, lanes: slice | np.ndarray) -> np.ndarray:
        """``value`` with present non-finite rows made absent and their lanes failed.

        A row is bad as :func:`archself.system.live.is_bad` judges it: its sum in entry
        order is not finite (an absent row is all NaN and not reported). A finite
        sum of the whole value clears every row at once (a row of finite entries
        whose sum alone overflows would need entries near 1e308).
        """
        if math.isfinite(value.sum()):
            return value
        total = value if value.ndim == 1 else value.sum(axis=1)
        absent = np.isnan(value) if value.ndim == 1 else np.isnan(value).all(axis=1)
        bad = ~np.isfinite(total) & ~absent
        if bad.any():
            for i in self.indices(lanes)[bad]:
                self.failed[int(i)] = "non-finite output"
            value = value.copy()
            value[bad] = math.nan
        return value


class _Drawing(_Lanes):
    """A batched type that draws normals from each lane's own stream."""

    def __init__(self, modules) -> None:
        super().__init__(modules)
        self.normals = LaneNormals([m.rng for m in self.modules])

    def _noisy(self, base, scale, present, lanes) -> np.ndarray:
        """``base + scale·N(0, 1)`` in the ``present`` rows (the lanes that draw), else NaN.

        ``base`` is ``(L,)`` (one normal per lane) or ``(L, w)`` (``w`` normals).
        """
        flat = base.ndim == 1
        k = 1 if flat else base.shape[1]
        scale = scale if flat else scale[:, None]
        if present.all():
            z = self.normals.take(lanes, k)
            return base + scale * (z[:, 0] if flat else z)
        out = np.full(base.shape, math.nan)
        if present.any():
            z = self.normals.take(self.indices(lanes)[present], k)
            out[present] = base[present] + scale[present] * (z[:, 0] if flat else z)
        return out


class DiffDrivePlantLanes(_Drawing):
    """:class:`~archself_diffdrive.physical.DiffDrivePlant` in N lanes.

    State: ``pose`` (N, 3) and the wheel speeds ``wheels`` (N, 2), both wheels of a
    lane computed together. Each lane clips its inputs to its limit (absent: 0),
    lags them with its time constant (trapezoidal speeds over the step where
    τ > 0), draws its slip (where ``slip_variance_m > 0``) and then its process
    noise (where a noise level is > 0), and integrates the arc exactly.
    """

    def load(self, lanes):
        mods = self._mods(lanes)
        self._read(lanes, "tau", [m.tau for m in mods])
        self._read(lanes, "limit", [[m.limit] for m in mods])
        self._read(lanes, "radius", [[m.radius] for m in mods])
        self._read(lanes, "base", [m._kp["wheel_base_m"] for m in mods])
        self._read(lanes, "eff", [m._kp["effectiveness"] for m in mods])
        self._read(lanes, "slip", [[m.slip] for m in mods])
        self._read(lanes, "lateral", [m.lateral for m in mods])
        self._read(lanes, "yaw", [m.yaw for m in mods])
        self._read(lanes, "pose", [m.pose for m in mods])
        self._read(lanes, "wheels", [[m.wl, m.wr] for m in mods])
        slipping = self.slip[:, 0] > 0
        shaken = (self.lateral > 0) | (self.yaw > 0)
        self._masks(
            slipping=slipping, shaken=shaken, disturbed=slipping | shaken, trapezoid=self.tau > 0
        )
        self._lags: dict[float, np.ndarray] = {}

    def store(self, lanes):
        for i, m in zip(self.indices(lanes), self._mods(lanes), strict=True):
            m.pose = self.pose[i].copy()
            m.wl, m.wr = (float(w) for w in self.wheels[i])

    def state_rows(self, lanes):
        return np.concatenate((self.pose[lanes], self.wheels[lanes]), axis=1)  # pose, wl, wr

    def set_state_rows(self, x, lanes):
        if x.shape[1] != 5:
            return False
        self.pose[lanes] = x[:, :3]
        self.wheels[lanes] = x[:, 3:]
        return True

    def output(self, t, lanes):
        return {
            "pose": self._screen(self.pose[lanes].copy(), lanes),
            "wheel_speeds": self._screen(self.wheels[lanes].copy(), lanes),
        }

    def _targets(self, inputs: dict[str, Any], lanes) -> np.ndarray:
        """The input wheel speeds ``(L, 2)``, clipped to ±limit, 0 where absent."""
        n = lane_count(self.n, lanes)
        target = np.column_stack([_scalar(inputs.get(k), n) for k in _WHEEL_INPUTS])
        lim = self.limit[lanes]
        clipped = np.minimum(np.maximum(target, -lim), lim)
        absent = np.isnan(target)
        return np.where(absent, 0.0, clipped) if absent.any() else clipped

    def step(self, t, dt, inputs, lanes):
        target = self._targets(inputs, lanes)
        a = self._lags.get(dt)
        if a is None:
            a = self._lags[dt] = _lag(dt, self.tau)[:, None]
        w0 = self.wheels[lanes]
        w1 = w0 + a[lanes] * (target - w0)
        trap, some, every = self._mask("trapezoid", lanes)
        if every:
            u = 0.5 * (w0 + w1)
        else:
            u = np.where(trap[:, None], 0.5 * (w0 + w1), w1) if some else w1
        self.wheels[lanes] = w1  # after the trapezoid: w0 may be a view of self.wheels
        dist, disturbed, all_disturbed = self._mask("disturbed", lanes)
        if disturbed:
            u = self._slip(u, dt, lanes)
        pose = self.pose[lanes]
        u = u * self.eff[lanes]
        px, py, th = _integrate(
            pose[:, 0], pose[:, 1], pose[:, 2], u[:, 0], u[:, 1],
            self.radius[lanes, 0], self.base[lanes], dt,
        )
        if disturbed:  # the process noise (zeros in lanes without it, as per run)
            nx, ny, nth = self._process_noise(th, dt, lanes)
            if all_disturbed:
                px, py, th = px + nx, py + ny, th + nth
            else:
                px, py, th = (np.where(dist, p + q, p) for p, q in ((px, nx), (py, ny), (th, nth)))
        self.pose[lanes] = np.stack((px, py, th), axis=1)
        return {}

    def _slip(self, u, dt, lanes):
        """The wheel speeds whose ground travel carries the slip (σ² = k·|r·ω·dt|)."""
        slipping, slips, every = self._mask("slipping", lanes)
        if dt <= 0 or not slips:
            return u
        r, k = self.radius[lanes], self.slip[lanes]
        if every:
            z = self.normals.take(lanes, 2)
            return u + np.sqrt(k * np.abs(r * u * dt)) * z / (r * dt)
        z = self.normals.take(self.indices(lanes)[slipping], 2)
        r, k, us = r[slipping], k[slipping], u[slipping]
        u = u.copy()
        u[slipping] = us + np.sqrt(k * np.abs(r * us * dt)) * z / (r * dt)
        return u

    def _process_noise(self, th, dt, lanes):
        """Pose increments ``(x, y, θ)`` of the lateral and yaw noise across heading ``th``."""
        shaken, shakes, every = self._mask("shaken", lanes)
        if dt <= 0 or not shakes:
            return 0.0, 0.0, 0.0
        lateral, yaw = self.lateral[lanes], self.yaw[lanes]
        if every:
            z = self.normals.take(lanes, 2) * math.sqrt(dt)
            lat = lateral * z[:, 0]
            return -np.sin(th) * lat, np.cos(th) * lat, yaw * z[:, 1]
        z = self.normals.take(self.indices(lanes)[shaken], 2) * math.sqrt(dt)
        out = np.zeros((3, len(th)))
        lat = lateral[shaken] * z[:, 0]
        out[0, shaken] = -np.sin(th[shaken]) * lat
        out[1, shaken] = np.cos(th[shaken]) * lat
        out[2, shaken] = yaw[shaken] * z[:, 1]
        return out[0], out[1], out[2]


def _integrate(px, py, th, wl, wr, r, b, dt):
    """:func:`~archself_diffdrive.kinematics.integrate_pose` per lane (effective speeds)."""
    v = r * (wl + wr) / 2.0
    w = r * (wr - wl) / b
    dth = w * dt
    th1 = th + dth
    straight = np.abs(dth) < 1e-9
    if not straight.any():
        rad = v / w
        return px + rad * (np.sin(th1) - np.sin(th)), py - rad * (np.cos(th1) - np.cos(th)), th1
    rad = v / np.where(straight, 1.0, w)
    mid = th + 0.5 * dth
    vdt = v * dt
    x = np.where(straight, px + vdt * np.cos(mid), px + rad * (np.sin(th1) - np.sin(th)))
    y = np.where(straight, py + vdt * np.sin(mid), py - rad * (np.cos(th1) - np.cos(th)))
    return x, y, th1


class WheelActuatorLanes(_Lanes):
    """:class:`~archself_diffdrive.physical.WheelActuator` in N lanes (all of one side).

    State: the previous command ``prev`` (``has_prev`` where there is one), the
    healthy wheel's speed ``expected`` and ``command_error`` (NaN until known).
    """

    def load(self, lanes):
        mods = self._mods(lanes)
        sides = {m.index for m in self.modules}
        if len(sides) > 1:
            raise ValueError(f"{self.name}: the lanes of a wheel must drive the same side")
        self.index = sides.pop()
        self.main_output = self.modules[0].main_output
        self._read(lanes, "smoothing", [m.smoothing for m in mods])
        self._read(lanes, "response", [m.response for m in mods])
        self._read(lanes, "expected", [m.expected for m in mods])
        self._read(lanes, "error", [m.signals["command_error"] for m in mods])
        prev = [m.prev_cmd for m in mods]
        self._read(lanes, "prev", [math.nan if c is None else c for c in prev])
        if isinstance(lanes, slice):
            self.has_prev = np.array([c is not None for c in prev])
        else:
            self.has_prev[lanes] = [c is not None for c in prev]
        self._masks(responding=self.response > 0, smoothed=self.smoothing > 0)
        self._factors: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def store(self, lanes):
        for i, m in zip(self.indices(lanes), self._mods(lanes), strict=True):
            m.prev_cmd = float(self.prev[i]) if self.has_prev[i] else None
            m.expected = float(self.expected[i])
            m.signals["command_error"] = float(self.error[i])

    def state_rows(self, lanes):
        # prev_cmd, expected; a lane without a previous command has ``expected`` alone
        has = self.has_prev[lanes]
        if has.all():
            return np.column_stack((self.prev[lanes], self.expected[lanes]))
        return None if has.any() else self.expected[lanes][:, None].copy()

    def set_state_rows(self, x, lanes):
        has = self.has_prev[lanes]
        if x.shape[1] == 2 and has.all():
            self.prev[lanes] = x[:, 0]
        elif x.shape[1] != 1 or has.any():
            return False
        self.expected[lanes] = x[:, -1]
        return True

    def local_signals(self, lanes):
        return {"command_error": self.error[lanes].copy()}

    def step(self, t, dt, inputs, lanes):
        enc = inputs.get("encoder_speeds")
        if enc is not None:
            self._measure(np.asarray(enc, dtype=float), dt, lanes)
        cmd = inputs.get("wheel_cmd")
        if cmd is None:
            self.has_prev[lanes] = False
            self.prev[lanes] = math.nan
            return {self.main_output: None}
        cmd = np.asarray(cmd, dtype=float)
        c = cmd[:, self.index].copy()
        present = ~np.isnan(cmd[:, 0])
        self.has_prev[lanes] = present
        self.prev[lanes] = c
        if not present.all():
            c[~present] = math.nan
        return {self.main_output: self._screen(c, lanes)}

    def _measure(self, enc: np.ndarray, dt: float, lanes) -> None:
        """The command error of the lanes with a measurement and a previous command."""
        has = ~np.isnan(enc[:, 0]) & self.has_prev[lanes]
        if not has.any():
            return
        f = self._factors.get(dt)
        if f is None:
            f = self._factors[dt] = (_lag(dt, self.response), _lag(dt, self.smoothing))
        every = bool(has.all())
        m = enc[:, self.index]
        c = self.prev[lanes]
        last = self.error[lanes]
        resp, responds, all_respond = self._mask("responding", lanes)
        if responds:  # the lagged command a healthy wheel turns at
            old = self.expected[lanes]
            new = old + f[0][lanes] * (c - old)
            self.expected[lanes] = new if every and all_respond else np.where(has & resp, new, old)
            c = new if all_respond else np.where(resp, new, c)
        e = np.where(c >= 0, c - m, m - c)
        smooth, smooths, all_smooth = self._mask("smoothed", lanes)
        if smooths:  # averaged at the step rate where there is a value to average
            known = last == last
            avg = last + f[1][lanes] * (e - last)
            e = avg if all_smooth and known.all() else np.where(smooth & known, avg, e)
        self.error[lanes] = e if every else np.where(has, e, last)


class WheelEncodersLanes(_Drawing):
    """:class:`~archself_diffdrive.physical.WheelEncoders` in N lanes: speeds + noise."""

    def load(self, lanes):
        self._read(lanes, "noise", [m.noise for m in self._mods(lanes)])

    def step(self, t, dt, inputs, lanes):
        ws = inputs.get("wheel_speeds")
        if ws is None:
            return {"encoder_speeds": None}
        ws = np.asarray(ws, dtype=float)
        out = self._noisy(ws, self.noise[lanes], ~np.isnan(ws[:, 0]), lanes)
        return {"encoder_speeds": self._screen(out, lanes)}


class ImuLanes(_Drawing):
    """:class:`~archself_diffdrive.physical.Imu` in N lanes: heading + bias + noise, wrapped."""

    def load(self, lanes):
        mods = self._mods(lanes)
        self._read(lanes, "noise", [m.noise for m in mods])
        self._read(lanes, "bias", [m.bias for m in mods])

    def step(self, t, dt, inputs, lanes):
        pose = inputs.get("pose")
        if pose is None:
            return {"heading": None}
        th = np.asarray(pose, dtype=float)[:, 2]
        h = self._noisy(th + self.bias[lanes], self.noise[lanes], ~np.isnan(th), lanes)
        return {"heading": self._screen((h + math.pi) % _TWO_PI - math.pi, lanes)}


class GpsLanes(_Drawing):
    """:class:`~archself_diffdrive.physical.Gps` in N lanes: fixes at each lane's rate.

    State: ``next_fix`` (s) per lane. A lane draws two normals at a fix only.
    """

    def load(self, lanes):
        mods = self._mods(lanes)
        self._read(lanes, "period", [m.period for m in mods])
        self._read(lanes, "noise", [m.noise for m in mods])
        self._read(lanes, "next_fix", [m.next_fix for m in mods])

    def store(self, lanes):
        for i, m in zip(self.indices(lanes), self._mods(lanes), strict=True):
            m.next_fix = float(self.next_fix[i])

    def step(self, t, dt, inputs, lanes):
        pose = inputs.get("pose")
        if pose is None:
            return {"position": None}
        pose = np.asarray(pose, dtype=float)
        nxt = self.next_fix[lanes]
        fix = ~np.isnan(pose[:, 0]) & ~(t < nxt - 1e-9)
        if not fix.any():
            return {"position": None}
        period = self.period[lanes]
        after = nxt + period * np.maximum(1.0, np.floor((t - nxt) / period) + 1)
        self.next_fix[lanes] = after if fix.all() else np.where(fix, after, nxt)
        out = self._noisy(pose[:, :2], self.noise[lanes], fix, lanes)
        return {"position": self._screen(out, lanes)}
