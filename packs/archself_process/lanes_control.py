"""Lane-batched observer, level controllers and setpoint of the process pack.

:class:`LevelObserverLanes`, :class:`PiControllerLanes`,
:class:`PiFeedforwardControllerLanes` and :class:`SetpointPlannerLanes` are the
:class:`~archself.lanes.LaneModule` classes of the types of
:mod:`archself_process.control`: every lane computes what its per-run instance computes
from the same inputs, with the same floating-point operations in the same order (the
plain PI as the feed-forward one with ``ff = 0`` and ``η̂ = 1``, which changes no bit).
The tank model input is a list of model objects (one per lane, None where absent); the
observer uses each lane's object or the per-run default, the controllers keep the last
one per lane. The observer's innovation window is a
:class:`~archself_process.lanes_windows.LaneMeans` ring buffer per lane. Parameters
and state are read per lane from the per-run instances
(:meth:`~archself.lanes.LaneModule.load`) and written back to them
(:meth:`~archself.lanes.LaneModule.store`), so a hand-over and a parameter update go
through the per-run ``import_state`` and ``set_params``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from archself.lanes.module import ModelFields
from archself_process.lanes_tank import ProcessLanes, exp_factors, scalar
from archself_process.lanes_windows import LaneMeans
from archself_process.tank import _DEFAULT_MODEL

__all__ = [
    "LevelObserverLanes",
    "PiControllerLanes",
    "PiFeedforwardControllerLanes",
    "SetpointPlannerLanes",
]


class LevelObserverLanes(ProcessLanes):
    """:class:`~archself_process.control.LevelObserver` in N lanes.

    State: the estimate ``h`` (NaN: None, before the first reading), the end of the
    boosted gain ``boost_until``, a hand-over's ``pending`` boost, the innovation
    window (:class:`LaneMeans`), the transmitters' difference window and the residuals
    ``innovation`` and ``disagreement``.
    """

    def __init__(self, modules: Sequence[Any]) -> None:
        self.monitor = LaneMeans(len(modules))
        self.check = LaneMeans(len(modules))
        self.fields = ModelFields({f: float(getattr(_DEFAULT_MODEL, f))
                                   for f in ("area_m2", "outflow_coeff", "max_level_m")})
        super().__init__(modules)

    def load(self, lanes):
        mods = self._mods(lanes)
        self._read(lanes, "gain", [m.gain for m in mods])
        self._read(lanes, "boost_gain", [m.handover_gain for m in mods])
        self._read(lanes, "handover_s", [m.handover_s for m in mods])
        self._read(lanes, "h", [math.nan if m.h is None else m.h for m in mods])
        self._read(lanes, "boost_until", [m.boost_until for m in mods])
        self._read(lanes, "pending", [m._boost_pending for m in mods], dtype=bool)
        self._read(lanes, "innovation", [m.signals["innovation"] for m in mods])
        self._read(lanes, "disagreement", [m.signals["disagreement"] for m in mods])
        for i, m in zip(self.indices(lanes), mods, strict=True):
            self.monitor.load(int(i), m.monitor)
            self.check.load(int(i), m.check)
        self._gains: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def store(self, lanes):
        for i, m in zip(self.indices(lanes), self._mods(lanes), strict=True):
            h = float(self.h[i])
            m.h = None if math.isnan(h) else h
            m.boost_until = float(self.boost_until[i])
            m._boost_pending = bool(self.pending[i])
            m.signals["innovation"] = float(self.innovation[i])
            m.signals["disagreement"] = float(self.disagreement[i])
            self.monitor.store(int(i), m.monitor)
            self.check.store(int(i), m.check)

    def state_rows(self, lanes):
        return self._scalar_rows(lanes, "h")

    def set_state_rows(self, x, lanes):
        return self._set_scalar_rows(x, lanes, "h")

    def local_signals(self, lanes):
        return {"innovation": self.innovation[lanes].copy(),
                "disagreement": self.disagreement[lanes].copy()}

    def step(self, t, dt, inputs, lanes):
        idx = self.indices(lanes)
        n = len(idx)
        y = scalar(inputs.get("level_measured"), n)
        q = scalar(inputs.get("flow_measured"), n)
        area, k, h_max = self.fields(inputs.get("tank_model"), n)
        pending = self.pending[idx]
        if pending.any():  # a hand-over's boost starts now
            sel = idx[pending]
            self.boost_until[sel] = t + self.handover_s[sel]
            self.pending[sel] = False
        check = inputs.get("level_check")
        if check is not None:  # the transmitters' difference: no model
            other = scalar(check, n)
            both = ~np.isnan(y) & ~np.isnan(other)
            if both.any():
                sel = idx[both]
                self.check.add(t, sel, (y - other)[both])
                self.disagreement[sel] = self.check.t_values(sel)
        h0 = self.h[idx]
        h = np.minimum(np.maximum(h0 + dt * ((q - k * np.sqrt(np.maximum(h0, 0.0))) / area),
                                  0.0), h_max)
        has_q = ~np.isnan(q)
        if not has_q.all():  # no inflow measured: no prediction
            h = np.where(has_q, h, h0)
        gains = self._gains.get(dt)
        if gains is None:
            gains = self._gains[dt] = (np.minimum(self.boost_gain * dt, 1.0),
                                       np.minimum(self.gain * dt, 1.0))
        boost = t < self.boost_until[idx]
        nu = y - h
        h1 = h + np.where(boost, gains[0][idx], gains[1][idx]) * nu
        has_y = ~np.isnan(y)
        h = h1 if has_y.all() else np.where(has_y, h1, h)
        watch = has_y & ~boost
        fresh = np.isnan(h0)
        if fresh.any():  # no estimate yet: start from the first reading, boosted
            h = np.where(fresh, y, h)
            first = idx[fresh & has_y]
            self.boost_until[first] = t + self.handover_s[first]
            watch &= ~fresh
        self.h[idx] = h
        if watch.any():
            sel = idx[watch]
            self.monitor.add(t, sel, nu[watch])
            self.innovation[sel] = np.abs(self.monitor.value(sel))
        return {"level_estimate": self._screen(h, lanes)}


class PiControllerLanes(ProcessLanes):
    """:class:`~archself_process.control.PiController` in N lanes.

    State: the model object per lane (the last ``tank_model`` input), the operating
    level ``h_op``, the integrator, the last command (NaN: None) and the residual
    ``tracking_error``. A lane without a setpoint or an estimate repeats its last
    command.
    """

    # per-lane parameters and state, set by ``_read`` in ``load``
    area: np.ndarray
    h_op: np.ndarray
    integral: np.ndarray
    k: np.ndarray
    ki: np.ndarray
    kp: np.ndarray
    last_cmd: np.ndarray
    q_max: np.ndarray
    tracking_error: np.ndarray

    def __init__(self, modules: Sequence[Any]) -> None:
        self.models: list[Any] = [None] * len(modules)
        self._models_in: Any = None  # (lanes, objects) of the last model input taken
        super().__init__(modules)

    # ------------------------------------------------------------------ the per-run bridge
    def load(self, lanes):
        mods = self._mods(lanes)
        self._read(lanes, "kp", [m.kp for m in mods])
        self._read(lanes, "ki", [m.ki for m in mods])
        self._read(lanes, "h_op", [m.h_op for m in mods])
        self._read(lanes, "integral", [m.integral for m in mods])
        self._read(lanes, "last_cmd",
                   [math.nan if m.last_cmd is None else m.last_cmd for m in mods])
        self._read(lanes, "tracking_error", [m.signals["tracking_error"] for m in mods])
        self._read(lanes, "q_max", [m.model.max_flow_m3_s for m in mods])
        self._read(lanes, "area", [m.model.area_m2 for m in mods])
        self._read(lanes, "k", [m.model.outflow_coeff for m in mods])
        for i, m in zip(self.indices(lanes), mods, strict=True):
            self.models[i] = m.model
        self._models_in = None

    def store(self, lanes):
        for i, m in zip(self.indices(lanes), self._mods(lanes), strict=True):
            m.model = self.models[i]
            m.h_op = float(self.h_op[i])
            m.integral = float(self.integral[i])
            cmd = float(self.last_cmd[i])
            m.last_cmd = None if math.isnan(cmd) else cmd
            m.signals["tracking_error"] = float(self.tracking_error[i])

    def state_rows(self, lanes):
        return self._scalar_rows(lanes, "integral")

    def set_state_rows(self, x, lanes):
        return self._set_scalar_rows(x, lanes, "integral")

    def local_signals(self, lanes):
        return {"tracking_error": self.tracking_error[lanes].copy()}

    # ------------------------------------------------------------------ a step
    def _take_models(self, objs: list[Any] | None, idx: np.ndarray) -> None:
        """``model = input`` in the lanes with a model object (fields re-read on a change)."""
        if objs is None:
            return
        key = idx.tobytes()
        last = self._models_in
        if last is not None and last[0] == key and last[1] == objs:
            return
        for i, o in zip(idx.tolist(), objs, strict=True):
            if o is not None:
                self.models[i] = o
                self.q_max[i] = o.max_flow_m3_s
                self.area[i] = o.area_m2
                self.k[i] = o.outflow_coeff
        self._models_in = (key, list(objs))

    def _feedforward(self, ref: np.ndarray, idx: np.ndarray) -> np.ndarray | float:
        """The feed-forward opening of rows ``ref`` of lanes ``idx`` (none for the plain PI)."""
        return 0.0

    def _effectiveness(self, idx: np.ndarray) -> np.ndarray | float:
        """The valve effectiveness the lanes ``idx`` assume (1: healthy)."""
        return 1.0

    def _control(self, dt: float, ref: np.ndarray, est: np.ndarray, idx: np.ndarray
                 ) -> np.ndarray:
        """``PiController.control`` of rows ``ref``/``est`` of lanes ``idx``."""
        h_ref = ref[:, 0]
        e = h_ref - est
        self.h_op[idx] = h_ref
        self.tracking_error[idx] = np.abs(e)
        eff = self._effectiveness(idx)
        ff = self._feedforward(ref, idx)
        kp, ki = self.kp[idx], self.ki[idx]
        integral = self.integral[idx]
        raw = (ff + kp * e + ki * integral) / eff
        go = ((raw < 1.0) | (e < 0)) & ((raw > 0.0) | (e > 0))  # unless saturated that way
        integral = np.where(go, integral + e * dt, integral)
        self.integral[idx] = integral
        return np.minimum(np.maximum((ff + kp * e + ki * integral) / eff, 0.0), 1.0)

    def _command(self, dt: float, inputs: dict[str, Any], idx: np.ndarray) -> np.ndarray:
        """The commands of lanes ``idx`` (the last one where a lane lacks its inputs)."""
        self._take_models(inputs.get("tank_model"), idx)
        ref = inputs.get("setpoint")
        est = inputs.get("level_estimate")
        cmd = self.last_cmd[idx]
        if ref is None or est is None:
            return cmd
        ref = np.asarray(ref, dtype=float)
        est = scalar(est, len(idx))
        ok = ~(np.isnan(ref[:, 0]) | np.isnan(est))
        if ok.all():
            cmd = self._control(dt, ref, est, idx)
        elif ok.any():
            cmd[ok] = self._control(dt, ref[ok], est[ok], idx[ok])
        self.last_cmd[idx] = cmd
        return cmd

    def step(self, t, dt, inputs, lanes):
        return {"valve_cmd": self._screen(self._command(dt, inputs, self.indices(lanes)), lanes)}


class PiFeedforwardControllerLanes(PiControllerLanes):
    """:class:`~archself_process.control.PiFeedforwardController` in N lanes.

    Adds per lane the effectiveness estimate ``eta`` with its weighted sums ``num``,
    ``den``, the command sent in the last step ``sent`` (NaN: None) and the last
    feed-forward ``ff``.
    """

    # per-lane parameters and state, set by ``_read`` in ``load``
    den: np.ndarray
    emin: np.ndarray
    eta: np.ndarray
    num: np.ndarray
    sent: np.ndarray
    tau: np.ndarray

    def load(self, lanes):
        super().load(lanes)
        mods = self._mods(lanes)
        self._read(lanes, "tau", [m.adaptation_time_s for m in mods])
        self._read(lanes, "emin", [m.min_effectiveness for m in mods])
        self._read(lanes, "eta", [m.eta for m in mods])
        self._read(lanes, "num", [m._num for m in mods])
        self._read(lanes, "den", [m._den for m in mods])
        self._read(lanes, "sent", [math.nan if m._sent is None else m._sent for m in mods])
        self._read(lanes, "ff", [m._ff for m in mods])
        self._lams: dict[float, np.ndarray] = {}

    def store(self, lanes):
        super().store(lanes)
        for i, m in zip(self.indices(lanes), self._mods(lanes), strict=True):
            m.eta, m._num, m._den = float(self.eta[i]), float(self.num[i]), float(self.den[i])
            sent = float(self.sent[i])
            m._sent = None if math.isnan(sent) else sent
            m._ff = float(self.ff[i])

    def _feedforward(self, ref, idx):
        h_ref = ref[:, 0]
        dh = ref[:, 1] if ref.shape[1] > 1 else 0.0
        ff = (self.k[idx] * np.sqrt(np.maximum(h_ref, 0.0)) + self.area[idx] * dh) / self.q_max[idx]
        self.ff[idx] = ff
        return ff

    def _effectiveness(self, idx):
        return self.eta[idx]

    def step(self, t, dt, inputs, lanes):
        idx = self.indices(lanes)
        self._take_models(inputs.get("tank_model"), idx)
        q = inputs.get("flow_measured")
        if q is not None:
            q = scalar(q, len(idx))
            go = ~(np.isnan(q) | np.isnan(self.sent[idx]))
            if go.any():
                self._adapt(dt, q[go], idx[go])
        cmd = self._command(dt, inputs, idx)
        self.sent[idx] = cmd  # the command sent, or the last one repeated
        return {"valve_cmd": self._screen(cmd, lanes)}

    def _adapt(self, dt: float, q: np.ndarray, idx: np.ndarray) -> None:
        """The effectiveness estimate of lanes ``idx`` from the measured inflows ``q``."""
        lam = self._lams.get(dt)
        if lam is None:
            lam = self._lams[dt] = exp_factors(dt, self.tau)
        lam = lam[idx]
        sent = self.sent[idx] * self.q_max[idx]
        num = lam * self.num[idx] + sent * q
        den = lam * self.den[idx] + sent * sent
        self.num[idx], self.den[idx] = num, den
        with np.errstate(divide="ignore", invalid="ignore"):
            est = np.minimum(np.maximum(num / den, self.emin[idx]), 1.0)
        self.eta[idx] = np.where(den > 1e-9, est, self.eta[idx])


class SetpointPlannerLanes(ProcessLanes):
    """:class:`~archself_process.control.SetpointPlanner` in N lanes.

    Lanes with the same targets and rate form a group (a seed sweep has one); each
    group's reference comes from its first lane's per-run
    :meth:`~archself_process.control.SetpointPlanner.reference`.
    """

    def load(self, lanes):
        groups: dict[tuple, int] = {}
        group = [groups.setdefault((tuple(m.steps), m.rate), len(groups)) for m in self.modules]
        self.group = np.array(group)
        self.first = [self.modules[group.index(g)] for g in range(len(groups))]

    def step(self, t, dt, inputs, lanes):
        refs = np.array([m.reference(t) for m in self.first])
        return {"setpoint": refs[self.group[lanes]]}
