"""The physical blocks in N lanes: LTI plant, actuator, sensor, and the LTI model node.

:class:`StateSpacePlantLanes` (also ``generic.transfer_function``, a subclass),
:class:`ActuatorLanes`, :class:`SensorLanes` and :class:`LtiModelNodeLanes` are the
batched classes of :mod:`archself_blocks.lti`, :mod:`~archself_blocks.actuators` and
:mod:`~archself_blocks.sensors`. Each lane takes its parameters from its per-run
instance (a sweep keeps its values per lane), runs the per-run float operations in
their order and draws its noise from its own stream through
:class:`~archself.lanes.LaneNormals`, as many numbers as the per-run code draws and
only where it draws (a plant with process noise, a noisy sensor with a value). A
sensor lane with a dropout probability draws from its generator itself, through its
per-run instance (the uniform comes after the normal in one stream).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.errors import SimulationError
from archself.lanes.module import ALL, LaneNormals, lane_count
from archself_blocks.lanes_base import (
    BlockLanes,
    as_rows,
    factors,
    present,
    zoh,
)
from archself_blocks.lti import matvec

__all__ = ["ActuatorLanes", "LtiModelNodeLanes", "SensorLanes", "StateSpacePlantLanes"]


class StateSpacePlantLanes(BlockLanes):
    """:class:`~archself_blocks.lti.StateSpacePlant` in N lanes: ``x`` ``(N, n)``, ``u`` ``(N, m)``.

    A continuous lane steps ``Ad x + Bd u`` with its model's zero-order hold (the
    model object's cached ``discrete``); a discrete one samples ``u`` at the start of
    its period and updates at its end, as per run. The lanes' models must have the
    same sizes (one structure).
    """

    def __init__(self, modules) -> None:
        self.normals = LaneNormals([m.rng for m in modules])
        self._shared: dict[Any, Any] = {}
        super().__init__(modules)

    def load(self, lanes):
        if isinstance(lanes, slice):
            model = self.modules[0].model
            self.sizes = (model.n, model.m, model.p)
            n, m, p = self.sizes
            N = self.n
            self.x, self.u, self.u_sample = np.zeros((N, n)), np.zeros((N, m)), np.zeros((N, m))
            self.acc, self.period, self.noise = np.zeros(N), np.zeros(N), np.zeros((N, n))
            self.C, self.D = np.zeros((N, p, n)), np.zeros((N, p, m))
            self.models: list[Any] = [None] * N
        for i, mod in zip(self.indices(lanes), self._mods(lanes), strict=True):
            model = mod.model
            if (model.n, model.m, model.p) != self.sizes:
                raise SimulationError(f"{self.name}: the lanes' models differ in size")
            self.models[i] = model
            self.x[i], self.u[i], self.u_sample[i] = mod.x, mod.u, mod._u_sample
            self.acc[i], self.period[i], self.noise[i] = mod._acc, model.dt, mod.noise
            self.C[i], self.D[i] = model.C, model.D
        self.noisy = self.noise.any(axis=1)
        self.sampled = self.period > 0
        self._held: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def store(self, lanes):
        for i, mod in zip(self.indices(lanes), self._mods(lanes), strict=True):
            mod.x, mod.u = self.x[i].copy(), self.u[i].copy()
            mod._u_sample = self.u_sample[i].copy()
            mod._acc = float(self.acc[i])

    def state_rows(self, lanes):
        return np.concatenate((self.x[lanes], self.u[lanes]), axis=1)  # x, u

    def set_state_rows(self, x, lanes):
        n = self.sizes[0]
        if x.shape[1] != n + self.sizes[1]:
            return False
        self.x[lanes], self.u[lanes] = x[:, :n], x[:, n:]
        return True

    def _matrices(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(Ad, Bd)`` of every lane at ``dt`` (a discrete lane's own ``A``, ``B``)."""
        got = self._held.get(dt)
        if got is None:
            pairs = [zoh(m, dt, self._shared) for m in self.models]
            got = (np.array([a for a, _ in pairs]), np.array([b for _, b in pairs]))
            self._held[dt] = got
        return got

    def output(self, t, lanes):
        x, u = self.x[lanes], self.u[lanes]
        y = matvec(self.C[lanes], x) + matvec(self.D[lanes], u)
        self._screen(lanes, np.ones(len(x), dtype=bool), y, x, u)
        return {"y": y, "state": x.copy(), "u": u.copy()}

    def _input(self, value: Any, lanes) -> tuple[np.ndarray, np.ndarray]:
        """The summed input ``(L, m)`` (absent edges count 0) and the lanes that raised."""
        L = lane_count(self.n, lanes)
        m = self.sizes[1]
        total = np.zeros((L, m))
        raised = np.zeros(L, dtype=bool)
        for v in value if type(value) is tuple else (value,):
            rows = as_rows(v)
            if rows is None:
                continue
            ok = np.isfinite(rows).all(axis=1)
            if rows.shape[1] != m:  # the per-run plant raises where such a value is there
                raised |= ok
                continue
            total = np.where(ok[:, None], total + rows, total)
        if raised.any():
            for i in self.indices(lanes)[raised]:
                self.failed[int(i)] = "raised ValueError"
        return total, raised

    def step(self, t, dt, inputs, lanes):
        u, raised = self._input(inputs.get("u"), lanes)
        idx = self.indices(lanes)
        x = self.x[lanes]
        sampled = self.sampled[lanes]
        go = ~raised & ~sampled
        if go.any():
            Ad, Bd = self._matrices(dt)
            every = bool(go.all())
            sel = lanes if every else idx[go]
            new = matvec(Ad[sel], x if every else x[go]) + matvec(Bd[sel], u if every else u[go])
            noisy = self.noisy[sel]
            if noisy.any():
                scale = self.noise[sel][noisy] * math.sqrt(dt)
                new[noisy] = new[noisy] + scale * self.normals.take(
                    self.indices(sel)[noisy], self.sizes[0])
            if every:
                x = new
            else:
                x[go] = new
        if (~raised & sampled).any():
            self._sampled(dt, x, u, idx[~raised & sampled], np.flatnonzero(~raised & sampled))
        keep = ~raised
        if keep.all():
            self.x[lanes], self.u[lanes] = x, u
        else:
            self.x[idx[keep]], self.u[idx[keep]] = x[keep], u[keep]
        return {}

    def _sampled(self, dt, x, u, idx, rows) -> None:
        """The discrete lanes ``idx`` (rows ``rows`` of ``x``, ``u``): sample, then update."""
        acc = self.acc[idx]
        fresh = acc < 1e-9
        self.u_sample[idx[fresh]] = u[rows[fresh]]
        acc = acc + dt
        period = self.period[idx]
        A, B = self._matrices(dt)
        due = acc >= period - 1e-9
        while due.any():
            k, r = idx[due], rows[due]
            acc[due] = acc[due] - period[due]
            new = matvec(A[k], x[r]) + matvec(B[k], self.u_sample[k])
            noisy = self.noisy[k]
            if noisy.any():
                new[noisy] = new[noisy] + self.noise[k[noisy]] * self.normals.take(
                    k[noisy], self.sizes[0])
            x[r] = new
            due = acc >= period - 1e-9
        self.acc[idx] = acc


class ActuatorLanes(BlockLanes):
    """:class:`~archself_blocks.actuators.Actuator` in N lanes.

    State per lane: the rate-limited value ``v``, the lagged output ``x``, the last
    delivered output ``prev`` (NaN: None) and ``command_error`` (NaN until known).
    """

    def load(self, lanes):
        mods = self._mods(lanes)
        for attr in ("gain", "drive", "lo", "hi", "rate", "tau", "v", "x"):
            self._read(lanes, attr, [getattr(m, attr) for m in mods])
        self._read(lanes, "prev", [math.nan if m.prev is None else m.prev for m in mods])
        self._read(lanes, "error", [m.signals["command_error"] for m in mods])
        self._read(lanes, "channel", [m.channel for m in mods], dtype=int)
        widths = {m.width for m in self.modules}
        if len(widths) > 1:
            raise SimulationError(f"{self.name}: the lanes' outputs differ in width")
        self.width = widths.pop()
        self.lagged = self.tau > 0
        self._lags: dict[float, np.ndarray] = {}

    def store(self, lanes):
        for i, m in zip(self.indices(lanes), self._mods(lanes), strict=True):
            m.v, m.x = float(self.v[i]), float(self.x[i])
            m.prev = None if math.isnan(self.prev[i]) else float(self.prev[i])
            m.signals["command_error"] = float(self.error[i])

    def state_rows(self, lanes):
        return self._scalar_rows(lanes, "v", "x")

    def set_state_rows(self, x, lanes):
        return self._set_scalar_rows(x, lanes, "v", "x")

    def local_signals(self, lanes):
        return {"command_error": self.error[lanes].copy()}

    def step(self, t, dt, inputs, lanes):
        meas = as_rows(inputs.get("measurement"))
        if meas is not None:
            prev, gain = self.prev[lanes], self.gain[lanes]
            known = present(meas) & ~np.isnan(prev) & (gain != 0)
            if known.any():
                with np.errstate(divide="ignore", invalid="ignore"):
                    err = np.abs(prev / gain - meas[:, 0])
                self.error[lanes] = np.where(known, err, self.error[lanes])
        cmd = as_rows(inputs.get("command"))
        if cmd is None:
            self.prev[lanes] = math.nan
            return {"u": None}
        has = present(cmd)
        drive, v, x = self.drive[lanes], self.v[lanes], self.x[lanes]
        target = np.minimum(np.maximum(drive * cmd[:, 0], self.lo[lanes]), self.hi[lanes])
        step = self.rate[lanes] * dt
        v1 = v + np.minimum(np.maximum(target - v, -step), step)
        lag = self._lags.get(dt)
        if lag is None:
            lag = self._lags[dt] = factors(
                self.tau, lambda tau: 1.0 - math.exp(-dt / tau) if tau > 0 else 1.0)
        x1 = np.where(self.lagged[lanes], x + lag[lanes] * (v1 - x), v1)
        if not has.all():
            v1, x1 = np.where(has, v1, v), np.where(has, x1, math.nan)
            self.x[lanes] = np.where(has, x1, x)
        else:
            self.x[lanes] = x1
        self.v[lanes] = v1
        self.prev[lanes] = x1
        self._screen(lanes, has, x1)
        if self.width <= 1:
            return {"u": x1}
        out = np.zeros((len(x1), self.width))
        out[np.arange(len(x1)), self.channel[lanes]] = x1
        out[~has] = math.nan
        return {"u": out}


class SensorLanes(BlockLanes):
    """:class:`~archself_blocks.sensors.Sensor` in N lanes.

    The component ``index`` of ``y`` (or, in a lane without ``y``, of ``u``), times
    the gain, plus bias and drift, noise where the lane's ``noise`` ≠ 0, quantized
    where ``resolution`` > 0 (``numpy.rint``: halves to even, as :func:`round`), and
    clipped. A lane whose index lies outside its input fails (``raised IndexError``).
    """

    index: np.ndarray
    follows_smooth = False  # the per-run sensor drops its quantizer when smooth

    def __init__(self, modules) -> None:
        self.normals = LaneNormals([m.rng for m in modules])
        super().__init__(modules)

    def load(self, lanes):
        mods = self._mods(lanes)
        for attr in ("gain", "bias", "drift", "noise", "resolution", "lo", "hi", "p_drop"):
            self._read(lanes, attr, [getattr(m, attr) for m in mods])
        self._read(lanes, "index", [m.index for m in mods], dtype=int)
        self.noisy = self.noise != 0
        self.quantized = self.resolution > 0
        self.dropping = self.p_drop != 0

    def _component(self, value: Any, lanes) -> tuple[np.ndarray, np.ndarray] | None:
        """Component ``index`` per lane and the lanes with a value (None: no value)."""
        rows = as_rows(value)
        if rows is None:
            return None
        has = present(rows)
        index = self.index[lanes]
        outside = has & (index >= rows.shape[1])
        if outside.any():
            for i in self.indices(lanes)[outside]:
                self.failed[int(i)] = "raised IndexError"
            has = has & ~outside
        col = rows[np.arange(len(rows)), np.minimum(index, rows.shape[1] - 1)]
        return col, has

    def step(self, t, dt, inputs, lanes):
        got = self._component(inputs.get("y"), lanes)
        other = self._component(inputs.get("u"), lanes) if got is None or not got[1].all() else None
        if got is None:
            got = other
        elif other is not None:  # lanes without y read u
            got = np.where(got[1], got[0], other[0]), got[1] | other[1]
        if got is None:
            return {"measurement": None}
        x, has = got
        v = self.gain[lanes] * x + self.bias[lanes] + self.drift[lanes] * t
        idx = self.indices(lanes)
        drop = has & self.dropping[lanes]
        noisy = has & self.noisy[lanes] & ~drop
        if noisy.any():
            z = self.normals.take(idx[noisy], 1)[:, 0]
            v[noisy] = v[noisy] + self.noise[lanes][noisy] * z
        quantized = self.quantized[lanes]
        if quantized.any():
            res = self.resolution[lanes]
            v = np.where(quantized, res * np.rint(v / np.where(quantized, res, 1.0)), v)
        v = np.minimum(np.maximum(v, self.lo[lanes]), self.hi[lanes])
        v[~has] = math.nan
        for j in np.flatnonzero(drop):  # the per-run reading: its normal, then its uniform
            i = int(idx[j])
            self.normals.direct(i)
            got_one = self.modules[i].measure(t, float(x[j]))
            self.normals.resume(i)
            v[j] = math.nan if got_one is None else got_one
        self._screen(lanes, has & ~np.isnan(v), v)
        return {"measurement": v}


class LtiModelNodeLanes(BlockLanes):
    """:class:`~archself_blocks.lti.LtiModelNode` in N lanes: each lane's model object."""

    def load(self, lanes):
        self.objects = [m._out["model"] for m in self.modules]

    def output(self, t, lanes):
        if isinstance(lanes, slice) and lanes == ALL:
            return {"model": list(self.objects)}
        return {"model": [self.objects[i] for i in self.indices(lanes)]}
