"""Lane-batched tank, valve, instruments and model node of the process pack.

The batched counterparts (:class:`archself.lanes.LaneModule`) of the per-run types of
:mod:`archself_process.tank` (the observer, the controllers and the setpoint are in
:mod:`archself_process.lanes_control`): each holds one module's state in N lanes (runs)
with a leading lane axis and steps them with numpy operations written in the per-run
code's order, so a lane computes the same floats as its per-run instance (the
exponential factors come from :func:`math.exp`, per lane, cached per step size).
Parameters are read per lane in :meth:`~archself.lanes.LaneModule.load` (a sweep keeps
each point's values); random draws come from each lane's own stream through
:class:`archself.lanes.LaneNormals`, as many and in the order the per-run code draws
them (an instrument only where its input is present, the tank's disturbances only
where one is on). :meth:`~archself.lanes.LaneModule.store` writes a lane's state back
into its per-run instance (the per-run API — ``export_state``, snapshots — then sees
it). A lane whose output goes non-finite is reported in ``failed`` (the per-run
executor's "non-finite output") and published as absent.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.lanes.module import LaneModule, LaneNormals, lane_count

__all__ = [
    "ControlValveLanes",
    "FlowMeterLanes",
    "LevelSensorLanes",
    "TankModelNodeLanes",
    "TankPlantLanes",
]


def scalar(value: Any, n: int) -> np.ndarray:
    """A scalar lane value (``(L,)`` or a 1-vector ``(L, 1)``) as ``(n,)``, NaN where absent.

    Examples
    --------
    >>> scalar(np.array([[1.0], [np.nan]]), 2).tolist(), scalar(None, 2).tolist()
    ([1.0, nan], [nan, nan])
    """
    if value is None:
        return np.full(n, math.nan)
    arr = np.asarray(value, dtype=float)
    return arr[:, 0] if arr.ndim == 2 else arr


def exp_factors(dt: float, tau: np.ndarray) -> np.ndarray:
    """``math.exp(-dt / τ)`` per lane (the per-run modules' float, not ``np.exp``'s)."""
    return np.array([math.exp(-dt / x) for x in tau.tolist()])


class ProcessLanes(LaneModule):
    """The batched process types: the non-finite screen (``_read``, ``_mask``: the core's)."""

    def _screen(self, value: np.ndarray, lanes: slice | np.ndarray) -> np.ndarray:
        """``value`` with present non-finite entries made absent and their lanes failed.

        A finite sum clears every lane at once; an absent lane (NaN) is not reported.
        """
        if math.isfinite(value.sum()):
            return value
        bad = np.isinf(value) if value.ndim == 1 else np.isinf(value).any(axis=1)
        if bad.any():
            for i in self.indices(lanes)[bad]:
                self.failed[int(i)] = "non-finite output"
            value = value.copy()
            value[bad] = math.nan
        return value


class _Drawing(ProcessLanes):
    """A batched type that draws normals from each lane's own stream."""

    def __init__(self, modules) -> None:
        super().__init__(modules)
        self.normals = LaneNormals([m.rng for m in self.modules])

    def _noisy(self, base: np.ndarray, scale: np.ndarray, lanes) -> np.ndarray:
        """``base + scale·N(0, 1)`` where ``base`` is present (the lanes that draw), else NaN."""
        present = ~np.isnan(base)
        if present.all():
            return base + scale * self.normals.take(lanes, 1)[:, 0]
        out = np.full(base.shape, math.nan)
        if present.any():
            z = self.normals.take(self.indices(lanes)[present], 1)[:, 0]
            out[present] = base[present] + scale[present] * z
        return out


class TankPlantLanes(_Drawing):
    """:class:`~archself_process.tank.TankPlant` in N lanes.

    State: the level ``h``, the last inflow ``q_in`` and the two Gauss–Markov
    disturbances ``d_in``, ``d_out`` per lane. A lane with a disturbance on draws its
    two normals every step (whether an inflow came or not), then integrates its own
    number of Euler sub-steps.
    """

    # per-lane parameters and state, set by ``_read`` in ``load``
    d_in: np.ndarray
    d_out: np.ndarray
    t_dist: np.ndarray

    def load(self, lanes):
        mods = self._mods(lanes)
        self._read(lanes, "area", [m.area for m in mods])
        self._read(lanes, "k", [m.k for m in mods])
        self._read(lanes, "h_max", [m.h_max for m in mods])
        self._read(lanes, "substeps", [m.substeps for m in mods], dtype=np.int64)
        self._read(lanes, "supply", [m.supply for m in mods])
        self._read(lanes, "draw", [m.draw for m in mods])
        self._read(lanes, "t_dist", [m.t_dist for m in mods])
        self._read(lanes, "h", [m.h for m in mods])
        self._read(lanes, "q_in", [m.q_in for m in mods])
        self._read(lanes, "d_in", [m.d_in for m in mods])
        self._read(lanes, "d_out", [m.d_out for m in mods])
        self._masks(disturbed=(self.supply > 0) | (self.draw > 0))
        self._decay: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def store(self, lanes):
        for i, m in zip(self.indices(lanes), self._mods(lanes), strict=True):
            m.h, m.q_in = float(self.h[i]), float(self.q_in[i])
            m.d_in, m.d_out = float(self.d_in[i]), float(self.d_out[i])

    def state_rows(self, lanes):
        return self._scalar_rows(lanes, "h", "q_in")

    def set_state_rows(self, x, lanes):
        return self._set_scalar_rows(x, lanes, "h", "q_in")

    def output(self, t, lanes):
        return {
            "level": self._screen(self.h[lanes][:, None].copy(), lanes),  # not a view
            "inflow": self._screen(self.q_in[lanes].copy(), lanes),
        }

    def step(self, t, dt, inputs, lanes):
        q = scalar(inputs.get("inflow"), lane_count(self.n, lanes))
        q = np.where(np.isnan(q), 0.0, np.maximum(q, 0.0))
        k = self.k[lanes]
        mask, some, every = self._mask("disturbed", lanes)
        if some:
            self._disturb(dt, lanes, mask, every)
            # 1 + 0·d is 1 exactly: the undisturbed lanes keep q and k as they are
            q = q * np.maximum(1.0 + self.supply[lanes] * self.d_in[lanes], 0.0)
            k = k * np.maximum(1.0 + self.draw[lanes] * self.d_out[lanes], 0.0)
        self.q_in[lanes] = q
        h = self.h[lanes]
        area, h_max = self.area[lanes], self.h_max[lanes]
        subs = self.substeps[lanes]
        d = dt / subs
        fewest = int(subs.min())
        for s in range(int(subs.max())):  # lanes with fewer sub-steps stop at theirs
            nxt = np.minimum(np.maximum(h + d * ((q - k * np.sqrt(np.maximum(h, 0.0))) / area),
                                        0.0), h_max)
            h = nxt if s < fewest else np.where(s < subs, nxt, h)
        self.h[lanes] = h
        return {}

    def _disturb(self, dt: float, lanes, mask: np.ndarray, every: bool) -> None:
        """Advance both Gauss–Markov processes of the disturbed lanes by ``dt``."""
        decay = self._decay.get(dt)
        if decay is None:
            a = exp_factors(max(dt, 0.0), self.t_dist)
            decay = self._decay[dt] = (a, np.sqrt(1.0 - a * a))
        sel = self.indices(lanes) if every else self.indices(lanes)[mask]
        a, s = decay[0][sel], decay[1][sel]
        z = self.normals.take(lanes if every else sel, 2)
        self.d_in[sel] = a * self.d_in[sel] + z[:, 0] * s
        self.d_out[sel] = a * self.d_out[sel] + z[:, 1] * s


class ControlValveLanes(ProcessLanes):
    """:class:`~archself_process.tank.ControlValve` in N lanes.

    State: the flow commanded in the last step ``prev`` (NaN: none) and the residual
    ``command_error`` (NaN until known), averaged at the step rate in the lanes with
    ``error_smoothing_s > 0`` once it has a value.
    """

    # per-lane parameters and state, set by ``_read`` in ``load``
    error: np.ndarray
    prev: np.ndarray
    smoothing: np.ndarray

    def load(self, lanes):
        mods = self._mods(lanes)
        self._read(lanes, "q_max", [m.q_max for m in mods])
        self._read(lanes, "smoothing", [m.smoothing for m in mods])
        self._read(lanes, "prev", [math.nan if m.prev_flow is None else m.prev_flow for m in mods])
        self._read(lanes, "error", [m.signals["command_error"] for m in mods])
        self._masks(smoothed=self.smoothing > 0)
        self._factors: dict[float, np.ndarray] = {}

    def store(self, lanes):
        for i, m in zip(self.indices(lanes), self._mods(lanes), strict=True):
            prev = float(self.prev[i])
            m.prev_flow = None if math.isnan(prev) else prev
            m.signals["command_error"] = float(self.error[i])

    def state_rows(self, lanes):
        return self._scalar_rows(lanes, "prev")  # prev_flow

    def set_state_rows(self, x, lanes):
        return self._set_scalar_rows(x, lanes, "prev")

    def local_signals(self, lanes):
        return {"command_error": self.error[lanes].copy()}

    def step(self, t, dt, inputs, lanes):
        meas = inputs.get("flow_measured")
        if meas is not None:
            self._measure(scalar(meas, lane_count(self.n, lanes)), dt, lanes)
        u = inputs.get("valve_cmd")
        if u is None:
            self.prev[lanes] = math.nan
            return {"inflow": None}
        u = scalar(u, lane_count(self.n, lanes))
        q = self.q_max[lanes] * np.minimum(np.maximum(u, 0.0), 1.0)
        self.prev[lanes] = q  # NaN where the command is absent (and stays absent)
        return {"inflow": self._screen(q, lanes)}

    def _measure(self, meas: np.ndarray, dt: float, lanes) -> None:
        """The command error of the lanes with a measurement and a previous command."""
        prev = self.prev[lanes]
        has = ~(np.isnan(meas) | np.isnan(prev))
        if not has.any():
            return
        e = prev - meas
        last = self.error[lanes]
        smooth, smooths, _ = self._mask("smoothed", lanes)
        if smooths:
            f = self._factors.get(dt)
            if f is None:
                tau = np.where(self.smoothing > 0, self.smoothing, 1.0)
                f = self._factors[dt] = 1.0 - exp_factors(dt, tau)
            avg = last + f[lanes] * (e - last)
            e = np.where(smooth & (last == last), avg, e)
        self.error[lanes] = e if has.all() else np.where(has, e, last)


class FlowMeterLanes(_Drawing):
    """:class:`~archself_process.tank.FlowMeter` in N lanes: inflow + noise where present."""

    def load(self, lanes):
        self._read(lanes, "noise", [m.noise for m in self._mods(lanes)])

    def step(self, t, dt, inputs, lanes):
        q = inputs.get("inflow")
        if q is None:
            return {"flow_measured": None}
        out = self._noisy(scalar(q, lane_count(self.n, lanes)), self.noise[lanes], lanes)
        return {"flow_measured": self._screen(out, lanes)}


class LevelSensorLanes(_Drawing):
    """:class:`~archself_process.tank.LevelSensor` in N lanes: level + bias + noise."""

    def load(self, lanes):
        mods = self._mods(lanes)
        self._read(lanes, "noise", [m.noise for m in mods])
        self._read(lanes, "bias", [m.bias for m in mods])

    def step(self, t, dt, inputs, lanes):
        h = inputs.get("level")
        if h is None:
            return {"level_measured": None}
        h = scalar(h, lane_count(self.n, lanes))
        y = self._noisy(h + self.bias[lanes], self.noise[lanes], lanes)
        return {"level_measured": self._screen(y, lanes)}


class TankModelNodeLanes(ProcessLanes):
    """:class:`~archself_process.tank.TankModelNode` in N lanes: each lane's model object."""

    def load(self, lanes):
        self.objects = [m._out["tank_model"] for m in self.modules]

    def output(self, t, lanes):
        if isinstance(lanes, slice):
            return {"tank_model": list(self.objects)}
        return {"tank_model": [self.objects[i] for i in lanes]}
