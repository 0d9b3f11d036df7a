"""The PID controller and the reference generator in N lanes.

:class:`PidLanes` and :class:`ReferenceLanes` are the batched classes of
:class:`~archself_blocks.pid.Pid` and :class:`~archself_blocks.signals.Reference`:
every lane runs the per-run float operations in their order with its own
parameters (gains, limits, anti-windup mode, filter bandwidth; ``math.exp`` per lane,
as per run). A PID lane without a reference or a fed-back value repeats its last
command (absent before the first) and changes nothing else, as per run. The
reference's table lookup is the per-run ``target`` of one lane per distinct table
(a seed sweep has one), its rate limit runs on the lanes' arrays.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself_blocks.lanes_base import BlockLanes, as_rows, factors, present

__all__ = ["PidLanes", "ReferenceLanes"]

_MODES = {"clamp": 0, "back_calculation": 1, "none": 2}


class PidLanes(BlockLanes):
    """:class:`~archself_blocks.pid.Pid` in N lanes.

    State per lane: the integral, the derivative filter ``y_f`` and the last command
    (NaN: None), ``tracking_error`` and the model object last received.
    """

    def __init__(self, modules) -> None:
        self.models: list[Any] = [None] * len(modules)
        super().__init__(modules)

    def load(self, lanes):
        mods = self._mods(lanes)
        for attr in ("kp", "ki", "kd", "ff_gain", "ff_rate_gain", "ff_offset", "u_min", "u_max",
                     "tt", "integral"):
            self._read(lanes, attr, [getattr(m, attr) for m in mods])
        self._read(lanes, "bandwidth", [m.n for m in mods])  # (self.n counts the lanes)
        self._read(lanes, "mode", [_MODES[m.mode] for m in mods], dtype=int)
        self._read(lanes, "fi", [m.fi for m in mods], dtype=int)
        self._read(lanes, "ri", [m.ri for m in mods], dtype=int)
        self._read(lanes, "y_f", [math.nan if m.y_f is None else m.y_f for m in mods])
        self._read(lanes, "last", [math.nan if m.last is None else m.last for m in mods])
        self._read(lanes, "error", [m.signals["tracking_error"] for m in mods])
        for i, m in zip(self.indices(lanes).tolist(), mods, strict=True):
            self.models[i] = m.model
        self._alphas: dict[float, np.ndarray] = {}

    def store(self, lanes):
        for i, m in zip(self.indices(lanes).tolist(), self._mods(lanes), strict=True):
            m.integral = float(self.integral[i])
            m.y_f = None if math.isnan(self.y_f[i]) else float(self.y_f[i])
            m.last = None if math.isnan(self.last[i]) else float(self.last[i])
            m.signals["tracking_error"] = float(self.error[i])
            m.model = self.models[i]

    def state_rows(self, lanes):
        return self._scalar_rows(lanes, "integral", "y_f")

    def set_state_rows(self, x, lanes):
        return self._set_scalar_rows(x, lanes, "integral", "y_f")

    def local_signals(self, lanes):
        return {"tracking_error": self.error[lanes].copy()}

    def _pick(self, rows: np.ndarray | None, index: np.ndarray, fallback: bool) -> Any:
        """Component ``index`` per lane of ``rows`` and the lanes that have it.

        ``fallback``: component 0 where the vector is too short (the fed-back value);
        else such a lane raises (the reference), reported in ``failed``.
        """
        if rows is None:
            return None
        w = rows.shape[1]
        has = present(rows)
        short = index >= w
        if short.any() and not fallback:
            has = has & ~short
        col = rows[np.arange(len(rows)), np.where(short, 0, index)]
        return col, has, short

    def step(self, t, dt, inputs, lanes):
        idx = self.indices(lanes)
        objs = inputs.get("model")
        if objs is not None:
            for i, obj in zip(idx.tolist(), objs, strict=True):
                if obj is not None:
                    self.models[i] = obj
        last = self.last[lanes].copy()  # published: not a view of the state
        fi = self.fi[lanes]
        est = self._pick(as_rows(inputs.get("estimate")), fi, True)
        meas = self._pick(as_rows(inputs.get("measurement")), fi, True)
        if est is None or (meas is not None and not est[1].all()):
            est = meas if est is None else (np.where(est[1], est[0], meas[0]), est[1] | meas[1])
        ri = self.ri[lanes]
        ref = self._pick(as_rows(inputs.get("reference")), ri, False)
        if ref is None or est is None:
            return {"command": last}
        has = ref[1] & est[1]
        raised = ref[1] & ref[2] & est[1]  # r = ref[ri] outside the reference vector
        if raised.any():
            for i in idx[raised]:
                self.failed[int(i)] = "raised IndexError"
        if not has.any():
            return {"command": last}
        rows = as_rows(inputs.get("reference"))
        r, y = ref[0], est[0]
        rate_col = np.minimum(ri + 1, rows.shape[1] - 1)
        r_rate = np.where(ri + 1 < rows.shape[1], rows[np.arange(len(rows)), rate_col], 0.0)
        e = r - y
        y_f = self.y_f[lanes]
        y_f = np.where(np.isnan(y_f), y, y_f)
        kd = self.kd[lanes]
        d_term = np.where(kd != 0, -kd * self.bandwidth[lanes] * (y - y_f), 0.0)
        alpha = self._alphas.get(dt)
        if alpha is None:
            alpha = self._alphas[dt] = factors(self.bandwidth, lambda n: 1.0 - math.exp(-n * dt))
        y_f = y_f + alpha[lanes] * (y - y_f)
        ff = (self.ff_offset[lanes] + self.ff_gain[lanes] * r
              + self.ff_rate_gain[lanes] * r_rate)
        integral = self.integral[lanes]
        v = ff + self.kp[lanes] * e + integral + d_term
        lo, hi = self.u_min[lanes], self.u_max[lanes]
        u = np.minimum(np.maximum(v, lo), hi)
        mode = self.mode[lanes]
        ki = self.ki[lanes]
        held = (mode == 0) & (((v > hi) & (e > 0)) | ((v < lo) & (e < 0)))
        plain = integral + ki * e * dt
        back = integral + dt * (ki * e + (u - v) / self.tt[lanes])
        integral = np.where(mode == 1, back, np.where(held, integral, plain))
        for name, new in (("error", np.abs(e)), ("y_f", y_f), ("integral", integral),
                          ("last", u)):
            old = getattr(self, name)
            old[lanes] = new if has.all() else np.where(has, new, old[lanes])
        command = self.last[lanes].copy()
        self._screen(lanes, has, command)
        return {"command": command}


class ReferenceLanes(BlockLanes):
    """:class:`~archself_blocks.signals.Reference` in N lanes: ``[r, dr/dt]`` per lane.

    Lanes with the same table and interpolation share one per-run ``target`` call
    per step; the rate limit (``previous`` steps with ``max_rate`` > 0, after the
    first step) runs per lane on the lane's last value ``r`` (NaN: None).
    """

    def load(self, lanes):
        mods = self._mods(lanes)
        self._read(lanes, "rate", [m.rate for m in mods])
        self._read(lanes, "linear", [m.linear for m in mods], dtype=bool)
        self._read(lanes, "r", [math.nan if m.r is None else m.r for m in mods])
        keys: dict[bytes, int] = {}
        group = []
        for m in self.modules:  # the groups span every lane, whichever lanes are read
            key = m.times.tobytes() + m.values.tobytes() + bytes([m.linear])
            group.append(keys.setdefault(key, len(keys)))
        self.group = np.array(group)
        self.first = [self.modules[group.index(g)] for g in range(len(keys))]
        self.limited = (self.rate > 0) & ~self.linear

    def store(self, lanes):
        for i, m in zip(self.indices(lanes).tolist(), self._mods(lanes), strict=True):
            m.r = None if math.isnan(self.r[i]) else float(self.r[i])

    def step(self, t, dt, inputs, lanes):
        table = np.array([m.target(t) for m in self.first])[self.group[lanes]]
        value, slope = table[:, 0], table[:, 1]
        r = self.r[lanes]
        limit = self.limited[lanes] & ~np.isnan(r)
        if limit.any():
            step = self.rate[lanes] * dt
            d = np.minimum(np.maximum(value - r, -step), step)
            slope = np.where(limit, d / dt if dt > 0 else 0.0, slope)
            value = np.where(limit, r + d, value)
        self.r[lanes] = value
        out = np.column_stack([value, slope])
        self._screen(lanes, np.ones(len(out), dtype=bool), out)
        return {"reference": out}
