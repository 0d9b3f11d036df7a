"""Functional modules of the liquid-level process: observer, level controllers, setpoint.

See :mod:`archself_process.tank` for the physics and the signals.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from archself.modules.base import RuntimeModule
from archself_process.tank import (
    _DEFAULT_MODEL,
    MeanWindow,
    TankModel,
    _f,
    pi_closed_loop,
    tank_derivative,
)

__all__ = ["LevelObserver", "PiController", "PiFeedforwardController", "SetpointPlanner"]


# --------------------------------------------------------------------------- M_F
class LevelObserver(RuntimeModule):
    """Model-based level observer (Luenberger) on the nonlinear tank model.

    Predict with the measured inflow, correct with one level measurement::

        ĥ⁻ = ĥ + dt·(q_meas − k·sqrt(ĥ))/A,   ν = y − ĥ⁻,   ĥ = ĥ⁻ + L·dt·ν

    A small gain ``L`` trusts the model: noise is filtered, and a sensor that
    drifts away from what the flows say shows as a persistent innovation.

    Parameters (``params``)
    -----------------------
    correction_gain : float
        L (1/s).
    innovation_window_s : float, optional
        Window of the innovation monitor (default 20 s).
    initial_level_m : float, optional
        Start estimate; by default the first measurement.
    handover_gain : float, optional
        L used for ``handover_s`` seconds after the start and after a hand-over
        (default 5·L), so the estimate converges fast to the own sensor; the
        innovation monitor ignores these seconds.
    handover_s : float, optional
        Length of that boost (default 15 s).

    Inputs ``level_measured``, ``flow_measured``, ``tank_model``. Output
    ``level_estimate`` (m). Residual signal ``innovation``: |window mean of ν| (m);
    zero-mean sensor noise averages out, a bias or drift does not.

    Examples
    --------
    >>> obs = LevelObserver("o", {"correction_gain": 0.05}, np.random.default_rng(0))
    >>> m = TankModel()
    >>> for k in range(200):
    ...     out = obs.step(0.2 * k, 0.2, {"level_measured": 1.0, "flow_measured": 0.01,
    ...                                  "tank_model": m})
    >>> round(out["level_estimate"], 6), round(obs.local_signals()["innovation"], 6)
    (1.0, 0.0)
    """

    optional_params = (
        "initial_level_m",
        "correction_gain",
        "innovation_window_s",
        "handover_gain",
        "handover_s",
    )
    role = "estimator"
    inputs = ("level_measured", "flow_measured", "tank_model")
    outputs = ("level_estimate",)
    residual_signals = ("innovation",)

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        h0 = params.get("initial_level_m")
        self.h: float | None = None if h0 is None else float(h0)
        self.boost_until = -math.inf
        self._boost_pending = False
        self._configure()
        self.monitor = MeanWindow(self.window_s)
        self.signals = {"innovation": math.nan}

    def _configure(self) -> None:
        p = self.params
        self.gain = float(p.get("correction_gain", 0.02))
        self.window_s = float(p.get("innovation_window_s", 20.0))
        self.handover_gain = float(p.get("handover_gain", 5.0 * self.gain))
        self.handover_s = float(p.get("handover_s", 15.0))

    def set_params(self, values):
        super().set_params(values)
        self._configure()
        self.monitor.window_s = self.window_s

    def step(self, t, dt, inputs):
        y = _f(inputs.get("level_measured"))
        q = _f(inputs.get("flow_measured"))
        model: TankModel = inputs.get("tank_model") or _DEFAULT_MODEL
        if self._boost_pending:
            self.boost_until = t + self.handover_s
            self._boost_pending = False
        if self.h is None:
            if y is None:
                return {"level_estimate": None}
            self.h = y  # start from the first reading, converge with the boosted gain
            self.boost_until = t + self.handover_s
            return {"level_estimate": self.h}
        h = self.h
        if q is not None:
            h = h + dt * tank_derivative(h, q, model.area_m2, model.outflow_coeff)
            h = min(max(h, 0.0), model.max_level_m)
        if y is not None:
            nu = y - h
            if t < self.boost_until:  # converging: the innovation says nothing yet
                h = h + min(self.handover_gain * dt, 1.0) * nu
            else:
                h = h + min(self.gain * dt, 1.0) * nu
                self.monitor.add(t, nu)
                self.signals["innovation"] = abs(self.monitor.value())
        self.h = h
        return {"level_estimate": h}

    def export_state(self):
        return {} if self.h is None else {"level": self.h}

    def import_state(self, state):
        if "level" in state:
            self.h = float(state["level"])
            self._boost_pending = True
        self.monitor.clear()
        self.signals["innovation"] = math.nan


class PiController(RuntimeModule):
    """PI level controller with conditional-integration anti-windup.

    ``u = kp·e + ki·∫e dt`` with ``e = h_ref − ĥ``, clipped to [0, 1]; the
    integrator is frozen while the output saturates in the direction of the error.
    It assumes the valve delivers what it is told.

    Parameters (``params``)
    -----------------------
    kp : float
        Proportional gain (1/m).
    ki : float
        Integral gain (1/(m·s)).
    initial_output : float, optional
        Initial integrator value as a valve opening (default 0.4, the opening
        that holds 1 m in the reference plant).

    Inputs ``setpoint``, ``level_estimate``; optional ``tank_model`` (for
    :meth:`linearization`). Output ``valve_cmd``. Residual signal
    ``tracking_error`` = |h_ref − ĥ| (m).

    Examples
    --------
    >>> c = PiController("c", {"kp": 1.0, "ki": 0.1, "initial_output": 0.0},
    ...                  np.random.default_rng(0))
    >>> out = c.step(0.0, 1.0, {"setpoint": np.array([1.2, 0.0]), "level_estimate": 1.0})
    >>> round(out["valve_cmd"], 6)
    0.22
    """

    optional_params: ClassVar[tuple[str, ...] | None] = ("kp", "ki", "initial_output")
    role = "controller"
    inputs: ClassVar[tuple[str, ...]] = ("setpoint", "level_estimate")
    optional_inputs: ClassVar[tuple[str, ...]] = ("tank_model",)
    outputs = ("valve_cmd",)
    residual_signals = ("tracking_error",)

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self.model: TankModel = _DEFAULT_MODEL
        self.h_op = 1.0
        self.last_cmd: float | None = None
        self.signals = {"tracking_error": math.nan}
        self._configure()
        u0 = float(params.get("initial_output", 0.4))
        self.integral = u0 / self.ki if self.ki > 0 else 0.0

    def _configure(self) -> None:
        self.kp = float(self.params.get("kp", 1.4))
        self.ki = float(self.params.get("ki", 0.05))

    def set_params(self, values):
        super().set_params(values)
        self._configure()

    def effectiveness(self) -> float:
        """The valve effectiveness the controller assumes (1: healthy)."""
        return 1.0

    def linearization(self) -> np.ndarray:
        """Closed-loop ``A`` of the tank + PI at the current operating level."""
        a, b = self.model.linear(self.h_op)
        return pi_closed_loop(a, b, self.kp, self.ki)

    def feedforward(self, ref: np.ndarray) -> float:
        """Feed-forward part of the opening (none for the plain PI)."""
        return 0.0

    def control(self, t, dt, ref, est) -> float:
        h_ref = float(ref[0])
        e = h_ref - est
        self.h_op = h_ref
        self.signals["tracking_error"] = abs(e)
        eff = self.effectiveness()
        ff = self.feedforward(ref)
        raw = (ff + self.kp * e + self.ki * self.integral) / eff
        if (raw < 1.0 or e < 0) and (raw > 0.0 or e > 0):
            self.integral += e * dt  # integrate unless saturated in the error's direction
        return min(max((ff + self.kp * e + self.ki * self.integral) / eff, 0.0), 1.0)

    def step(self, t, dt, inputs):
        m = inputs.get("tank_model")
        if m is not None:
            self.model = m
        ref = inputs.get("setpoint")
        est = _f(inputs.get("level_estimate"))
        if ref is None or est is None:
            return {"valve_cmd": self.last_cmd}
        u = self.control(t, dt, np.asarray(ref, dtype=float), est)
        self.last_cmd = u
        return {"valve_cmd": u}

    def opening(self) -> float:
        """The valve opening the controller holds at zero error (for a bumpless hand-over)."""
        return self.ki * self.integral

    def export_state(self):
        return {"opening": self.opening(), "model": self.model, "level_op": self.h_op}

    def import_state(self, state):
        if "model" in state:
            self.model = state["model"]
        if "level_op" in state:
            self.h_op = float(state["level_op"])
        if "opening" in state and self.ki > 0:  # bumpless transfer: same physical opening
            self.integral = float(state["opening"]) / self.ki


class PiFeedforwardController(PiController):
    """Model feed-forward + PI, with online valve-effectiveness estimation.

    The opening is ``u = (u_ff + kp·e + ki·∫e) / η̂`` with the model feed-forward
    ``u_ff = (k·sqrt(h_ref) + A·dh_ref/dt) / q_max`` and ``η̂`` the exponentially
    weighted least-squares ratio of measured to commanded inflow (time constant
    ``adaptation_time_s``), clipped to ``[min_effectiveness, 1]``. A valve that
    lost part of its effectiveness is thereby seen through its flow measurements
    and compensated, and the loop gain stays at its design value.

    Parameters (``params``)
    -----------------------
    kp, ki : float
        As :class:`PiController` (the integrator only trims the feed-forward).
    adaptation_time_s : float
        Time constant of the effectiveness estimate (s).
    min_effectiveness : float
        Lower clip of η̂.

    Inputs ``setpoint``, ``level_estimate``, ``flow_measured``, ``tank_model``.
    """

    optional_params = (
        *(PiController.optional_params or ()),
        "adaptation_time_s",
        "min_effectiveness",
    )
    inputs = ("setpoint", "level_estimate", "flow_measured", "tank_model")
    optional_inputs = ()

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self.eta = 1.0
        self._num = 0.0
        self._den = 0.0
        self._sent: float | None = None
        self._ff = 0.0
        self.integral = 0.0  # the feed-forward gives the operating opening

    def effectiveness(self) -> float:
        return self.eta

    def feedforward(self, ref: np.ndarray) -> float:
        m = self.model
        h_ref = float(ref[0])
        dh = float(ref[1]) if ref.size > 1 else 0.0
        self._ff = (m.equilibrium_inflow(h_ref) + m.area_m2 * dh) / m.max_flow_m3_s
        return self._ff

    def linearization(self) -> np.ndarray:
        """Closed-loop ``A``: the compensated valve acts with gain ``b·η/η̂ ≈ b``."""
        a, b = self.model.linear(self.h_op)
        return pi_closed_loop(a, b, self.kp, self.ki)

    def step(self, t, dt, inputs):
        q = _f(inputs.get("flow_measured"))
        m = inputs.get("tank_model")
        if m is not None:
            self.model = m
        if q is not None and self._sent is not None:
            lam = math.exp(-dt / max(float(self.params.get("adaptation_time_s", 5.0)), 1e-6))
            sent = self._sent * self.model.max_flow_m3_s
            self._num = lam * self._num + sent * q
            self._den = lam * self._den + sent * sent
            if self._den > 1e-9:
                emin = float(self.params.get("min_effectiveness", 0.3))
                self.eta = min(max(self._num / self._den, emin), 1.0)
        out = super().step(t, dt, inputs)
        self._sent = out["valve_cmd"]
        return out

    def opening(self) -> float:
        return (self._ff + self.ki * self.integral) / self.eta

    def export_state(self):
        return {**super().export_state(), "effectiveness": self.eta}

    def import_state(self, state):
        if "model" in state:
            self.model = state["model"]
        if "level_op" in state:
            self.h_op = float(state["level_op"])
        if "effectiveness" in state:
            self.eta = float(state["effectiveness"])
        # The predecessor's opening is not taken over: a controller that does not know
        # the valve's effectiveness has folded its loss into the integrator, which
        # the effectiveness estimate would then compensate a second time. The
        # feed-forward gives the operating opening; the integrator restarts at 0 and
        # only trims model error.
        self._ff = self.model.equilibrium_inflow(self.h_op) / self.model.max_flow_m3_s
        self.integral = 0.0


class SetpointPlanner(RuntimeModule):
    """Level setpoint: piecewise-constant targets approached at a limited rate.

    Parameters (``params``)
    -----------------------
    steps : list of [t_s, level_m]
        From time ``t_s`` on, the target is ``level_m`` (the first entry gives the
        start value).
    max_rate_m_s : float
        Rate limit of the setpoint (m/s); 0 = steps.

    Output ``setpoint`` ``[h_ref, dh_ref/dt]``.

    Examples
    --------
    >>> sp = SetpointPlanner("s", {"steps": [[0, 1.0], [10, 1.2]], "max_rate_m_s": 0.01},
    ...                      np.random.default_rng(0))
    >>> [round(float(sp.reference(t)[0]), 3) for t in (5.0, 15.0, 40.0)]
    [1.0, 1.05, 1.2]
    """

    optional_params = ("steps", "max_rate_m_s")
    role = "planner"
    outputs = ("setpoint",)

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self._configure()

    def _configure(self) -> None:
        steps = [(float(t), float(h)) for t, h in self.params.get("steps", [[0.0, 1.0]])]
        steps.sort()
        self.steps = steps
        self.rate = float(self.params.get("max_rate_m_s", 0.0))

    def set_params(self, values):
        super().set_params(values)
        self._configure()

    def reference(self, t: float) -> np.ndarray:
        """``[h_ref, dh_ref/dt]`` at time ``t`` (closed form of the rate-limited steps)."""
        h = self.steps[0][1]
        for (t0, target), nxt in zip(self.steps[1:], [*self.steps[2:], None], strict=False):
            if t < t0:
                break
            if self.rate <= 0:
                h = target
                continue
            t_end = nxt[0] if nxt is not None else math.inf
            span = min(t, t_end) - t0
            dist = target - h
            need = abs(dist) / self.rate
            if span >= need:
                h = target
                if t < t_end:
                    return np.array([h, 0.0])
            else:
                h = h + math.copysign(self.rate * span, dist)
                if t < t_end:
                    return np.array([h, math.copysign(self.rate, dist)])
        return np.array([h, 0.0])

    def step(self, t, dt, inputs):
        return {"setpoint": self.reference(t)}
