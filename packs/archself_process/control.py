"""Functional modules of the liquid-level process: observer, level controllers, setpoint.

See :mod:`archself_process.tank` for the physics and the signals.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from archself.modules.base import Param, RuntimeModule
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

    A small gain ``L`` (``correction_gain``) trusts the model: noise is filtered,
    and a sensor that drifts away from what the flows say shows as a persistent
    innovation. For ``handover_s`` seconds after the start and after a hand-over the
    gain is ``handover_gain``, so the estimate converges fast to the own sensor; the
    innovation monitor ignores these seconds.

    Inputs ``level_measured``, ``flow_measured``, ``tank_model``; optional
    ``level_check``: a second transmitter on the same tank. Output ``level_estimate``
    (m). Residual signals ``innovation``: |window mean of ν| (m); zero-mean sensor
    noise averages out, a bias or drift does not; and ``disagreement``: the window
    mean of ``level_measured − level_check`` over its standard error (unitless; the
    noise measured from the window's own first differences, so one band holds at any
    transmitter noise). Two transmitters of the same level differ by their noise
    alone, so a bias or drift of either shows without the slow model error that the
    innovation carries; it does not say which of the two moved (the innovation does,
    weakly).

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

    state_fields = ("h",)  # boost_until is a timer

    parameters = {
        "correction_gain": Param(0.02, "1/s", "L", min=0.0, max=100.0),
        "innovation_window_s": Param(
            20.0, "s", "window of the innovation monitor", min=0.01, max=1e5
        ),
        "initial_level_m": Param(
            None, "m", "start estimate; None: the first measurement", min=0.0, max=100.0
        ),
        "handover_gain": Param(
            None, "1/s", "L after a start or hand-over; None: 5·L", min=0.0, max=100.0
        ),
        "handover_s": Param(15.0, "s", "length of that boost", min=0.0, max=1e5),
    }
    role = "estimator"
    inputs = ("level_measured", "flow_measured", "tank_model")
    optional_inputs = ("level_check",)
    outputs = ("level_estimate",)
    residual_signals = ("innovation", "disagreement")
    lanes = "archself_process.lanes_control:LevelObserverLanes"

    def __init__(self, name, params, rng):
        self.monitor = MeanWindow(math.nan)  # configure() sets the windows
        self.check = MeanWindow(math.nan)
        super().__init__(name, params, rng)
        h0 = self.params["initial_level_m"]
        self.h: float | None = None if h0 is None else float(h0)
        self.boost_until = -math.inf
        self._boost_pending = False
        self.signals = {"innovation": math.nan, "disagreement": math.nan}

    def configure(self) -> None:
        p = self.params
        self.gain = float(p["correction_gain"])
        self.monitor.window_s = self.check.window_s = float(p["innovation_window_s"])
        boost = p["handover_gain"]
        self.handover_gain = 5.0 * self.gain if boost is None else float(boost)
        self.handover_s = float(p["handover_s"])

    def step(self, t, dt, inputs):
        y = _f(inputs.get("level_measured"))
        q = _f(inputs.get("flow_measured"))
        model: TankModel = inputs.get("tank_model") or _DEFAULT_MODEL
        if self._boost_pending:
            self.boost_until = t + self.handover_s
            self._boost_pending = False
        other = _f(inputs.get("level_check"))
        if y is not None and other is not None:  # the transmitters' difference: no model
            self.check.add(t, y - other)
            self.signals["disagreement"] = self.check.t_value()
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
        self.check.clear()
        self.signals["innovation"] = self.signals["disagreement"] = math.nan


class PiController(RuntimeModule):
    """PI level controller with conditional-integration anti-windup.

    ``u = kp·e + ki·∫e dt`` with ``e = h_ref − ĥ``, clipped to [0, 1]; the
    integrator is frozen while the output saturates in the direction of the error.
    It assumes the valve delivers what it is told. The integrator starts at
    ``initial_output``, by default the opening that holds 1 m in the reference plant.

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

    state_fields = ("integral",)

    parameters: ClassVar[dict[str, Param]] = {
        "kp": Param(
            1.4, "1/m", "proportional gain (≥ 0: a wider opening raises the level)",
            min=0.0, max=1e4,
        ),
        "ki": Param(0.05, "1/(m·s)", "integral gain", min=0.0, max=1e4),
        "initial_output": Param(
            0.4, "", "initial integrator value as a valve opening", min=0.0, max=1.0
        ),
    }
    role = "controller"
    inputs: ClassVar[tuple[str, ...]] = ("setpoint", "level_estimate")
    optional_inputs: ClassVar[tuple[str, ...]] = ("tank_model",)
    outputs = ("valve_cmd",)
    residual_signals = ("tracking_error",)
    lanes = "archself_process.lanes_control:PiControllerLanes"

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self.model: TankModel = _DEFAULT_MODEL
        self.h_op = 1.0
        self.last_cmd: float | None = None
        self.signals = {"tracking_error": math.nan}
        u0 = float(self.params["initial_output"])
        self.integral = u0 / self.ki if self.ki > 0 else 0.0

    def configure(self) -> None:
        old = getattr(self, "ki", 0.0)
        self.kp = float(self.params["kp"])
        self.ki = float(self.params["ki"])
        if old > 0 and self.ki > 0 and hasattr(self, "integral"):
            # a gain update keeps the integral action ki·∫e: bumpless (the opening holds)
            self.integral *= old / self.ki

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
    and compensated, and the loop gain stays at its design value. ``kp`` and ``ki``
    are as in :class:`PiController`; the integrator only trims the feed-forward.

    Inputs ``setpoint``, ``level_estimate``, ``flow_measured``, ``tank_model``.
    """

    state_fields = ("integral",)  # the effectiveness estimate is frozen (docs/stability.md)

    parameters = {
        **PiController.parameters,
        "adaptation_time_s": Param(
            5.0, "s", "time constant of the effectiveness estimate", min=0.01, max=1e4
        ),
        "min_effectiveness": Param(0.3, "", "lower clip of η̂", min=0.01, max=1.0),
    }
    inputs = ("setpoint", "level_estimate", "flow_measured", "tank_model")
    optional_inputs = ()
    lanes = "archself_process.lanes_control:PiFeedforwardControllerLanes"

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self.eta = 1.0
        self._num = 0.0
        self._den = 0.0
        self._sent: float | None = None
        self._ff = 0.0
        self.integral = 0.0  # the feed-forward gives the operating opening

    def configure(self) -> None:
        super().configure()
        self.adaptation_time_s = max(float(self.params["adaptation_time_s"]), 1e-6)
        self.min_effectiveness = float(self.params["min_effectiveness"])

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
            lam = math.exp(-dt / self.adaptation_time_s)
            sent = self._sent * self.model.max_flow_m3_s
            self._num = lam * self._num + sent * q
            self._den = lam * self._den + sent * sent
            if self._den > 1e-9:
                self.eta = min(max(self._num / self._den, self.min_effectiveness), 1.0)
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

    ``steps`` is a list of ``[t_s, level_m]``: from time ``t_s`` on, the target is
    ``level_m`` (the first entry gives the start value). Output ``setpoint`` ``[h_ref, dh_ref/dt]``.

    Examples
    --------
    >>> sp = SetpointPlanner("s", {"steps": [[0, 1.0], [10, 1.2]], "max_rate_m_s": 0.01},
    ...                      np.random.default_rng(0))
    >>> [round(float(sp.reference(t)[0]), 3) for t in (5.0, 15.0, 40.0)]
    [1.0, 1.05, 1.2]
    """

    parameters = {
        "steps": Param(
            [[0.0, 1.0]], "[s, m]", "targets: [t_s, level_m] each (times ≤ 10⁷ s, levels ≥ 0)",
            min=0.0, max=1e7,
        ),
        "max_rate_m_s": Param(
            0.0, "m/s", "rate limit of the setpoint; 0: steps", min=0.0, max=100.0
        ),
    }
    role = "planner"
    outputs = ("setpoint",)
    output_sizes = {"setpoint": 2}  # h_ref, dh_ref/dt
    output_elements = {"setpoint": ("level", "rate")}
    lanes = "archself_process.lanes_control:SetpointPlannerLanes"

    def configure(self) -> None:
        self.steps = sorted((float(t), float(h)) for t, h in self.params["steps"])
        self.rate = float(self.params["max_rate_m_s"])

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
