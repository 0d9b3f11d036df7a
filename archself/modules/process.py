"""Module types of a liquid-level process: a tank filled through a control valve.

The second reference system of archself (``architectures/process_plant.yaml``),
deliberately unlike the robot: a single slow, nonlinear, self-regulating state
(the level ``h``), redundant level sensors, a flow meter, model-based observers
and two alternative level controllers. Nothing here is known to the runtime; the
architecture file wires these types together.

Physics (Torricelli outflow through a free drain)::

    A · dh/dt = q_in − k · sqrt(h),       0 ≤ h ≤ h_max

with ``A`` the cross-section (m²), ``k`` the outflow coefficient (m^2.5/s) and
``q_in = η · q_max · u`` the inflow through a valve of opening ``u ∈ [0, 1]`` and
effectiveness ``η`` (1 when healthy; a scenario's ``effectiveness_loss`` on the
valve's ``inflow`` output lowers it). Linearized at ``h₀``::

    d(δh)/dt = −a δh + b δu,   a = k / (2 A sqrt(h₀)),   b = η q_max / A

Types
-----
==========================  ==========================================================
``plant.tank``              the tank (true level; non-feedthrough)
``actuator.valve``          inlet control valve; residual ``command_error``
``sensor.flow``             inflow meter
``sensor.level``            level transmitter (two redundant instances in the file)
``model.tank``              the tank model (A, k, q_max, h_max) shared by the users
``estimator.level_observer``  model-based level observer; residual ``innovation``
``controller.pi``           PI level controller (anti-windup), assumes a healthy valve
``controller.pi_feedforward``  model feed-forward + PI, with online valve-effectiveness
                            estimation and compensation
``planner.setpoint``        level setpoint: piecewise-constant targets, rate-limited
==========================  ==========================================================

Signals: ``level`` (true, 1-vector ``[h]``), ``inflow`` (m³/s), ``level_measured``
(m), ``flow_measured`` (m³/s), ``level_estimate`` (m), ``setpoint``
(``[h_ref, dh_ref/dt]``), ``valve_cmd`` (0..1), ``tank_model`` (:class:`TankModel`).

Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> tank = TankPlant("t", {"area_m2": 0.5, "outflow_coeff": 0.01, "initial_level_m": 1.0}, rng)
>>> _ = tank.step(0.0, 1.0, {"inflow": 0.01})     # inflow = outflow at h = 1 m
>>> round(float(tank.output(1.0)["level"][0]), 9)
1.0
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from archself.modules.base import RuntimeModule
from archself.registry import register

__all__ = [
    "TankModel",
    "TankPlant",
    "ControlValve",
    "FlowMeter",
    "LevelSensor",
    "TankModelNode",
    "LevelObserver",
    "PiController",
    "PiFeedforwardController",
    "SetpointPlanner",
    "MeanWindow",
    "pi_closed_loop",
    "tank_derivative",
]

_SENSOR_FAULTS = frozenset({"bias_drift", "bias", "noise_increase", "dropout", "stuck"})


# --------------------------------------------------------------------------- model
@dataclass(frozen=True)
class TankModel:
    """Model of the tank and its valve.

    Attributes
    ----------
    area_m2 : float
        Cross-section A (m²).
    outflow_coeff : float
        k of ``q_out = k·sqrt(h)`` (m^2.5/s).
    max_flow_m3_s : float
        Inflow of the fully open healthy valve, q_max (m³/s).
    max_level_m : float
        Height of the tank (overflow above it).
    """

    area_m2: float = 0.5
    outflow_coeff: float = 0.01
    max_flow_m3_s: float = 0.025
    max_level_m: float = 2.5

    def equilibrium_inflow(self, h: float) -> float:
        """Inflow that holds the level at ``h``: ``k·sqrt(h)`` (m³/s)."""
        return self.outflow_coeff * math.sqrt(max(h, 0.0))

    def linear(self, h: float, effectiveness: float = 1.0) -> tuple[float, float]:
        """``(a, b)`` of ``d(δh)/dt = −a δh + b δu`` at level ``h``.

        Examples
        --------
        >>> TankModel().linear(1.0)
        (0.01, 0.05)
        """
        h = max(float(h), 0.05)
        a = self.outflow_coeff / (2.0 * self.area_m2 * math.sqrt(h))
        b = effectiveness * self.max_flow_m3_s / self.area_m2
        return a, b


_DEFAULT_MODEL = TankModel()


def tank_derivative(h: float, q_in: float, area: float, k: float) -> float:
    """``dh/dt = (q_in − k·sqrt(h)) / A`` (h clipped at 0 inside the root).

    Examples
    --------
    >>> tank_derivative(1.0, 0.02, 0.5, 0.01)
    0.02
    """
    return (q_in - k * math.sqrt(max(h, 0.0))) / area


def pi_closed_loop(a: float, b: float, kp: float, ki: float) -> np.ndarray:
    """Closed-loop matrix of the linearized tank under PI control (Eq. 20).

    State ``[δh, ξ]`` with ``ξ' = −δh`` the integrated error (setpoint held) and
    ``δu = kp·(−δh) + ki·ξ``::

        A_cl = [[−a − b·kp, b·ki],
                [−1,        0   ]]

    Examples
    --------
    >>> A = pi_closed_loop(0.01, 0.05, 1.4, 0.05)
    >>> bool(np.linalg.eigvals(A).real.max() < 0)
    True
    """
    return np.array([[-a - b * kp, b * ki], [-1.0, 0.0]])


class MeanWindow:
    """Sliding-window mean of a scalar over ``window_s`` seconds.

    The value is NaN until the samples span at least half the window (a mean of a
    few noisy samples would look like a bias).

    Examples
    --------
    >>> w = MeanWindow(4.0)
    >>> for t, v in [(0.0, 1.0), (1.0, -1.0), (2.0, 3.0)]:
    ...     w.add(t, v)
    >>> w.value()
    1.0
    """

    def __init__(self, window_s: float) -> None:
        self.window_s = float(window_s)
        self.items: deque[tuple[float, float]] = deque()
        self.total = 0.0
        self.start: float | None = None
        self.last = 0.0

    def add(self, t: float, v: float) -> None:
        if self.start is None:
            self.start = t
        self.last = t
        self.items.append((t, v))
        self.total += v
        while self.items and self.items[0][0] <= t - self.window_s:
            self.total -= self.items.popleft()[1]

    def value(self) -> float:
        n = len(self.items)
        if n == 0 or self.start is None or self.last - self.start < 0.5 * self.window_s:
            return math.nan
        return self.total / n

    def clear(self) -> None:
        self.items.clear()
        self.total = 0.0
        self.start = None


def _f(x: Any) -> float | None:
    """A scalar from a float or a 1-vector; None stays None."""
    if x is None:
        return None
    if isinstance(x, np.ndarray):
        return float(x.ravel()[0])
    return float(x)


# --------------------------------------------------------------------------- M_P
@register("plant.tank")
class TankPlant(RuntimeModule):
    """Open tank with a free drain: ``A dh/dt = q_in − k sqrt(h)``, level in ``[0, h_max]``.

    Parameters (``params``)
    -----------------------
    area_m2 : float
        Cross-section A (m²).
    outflow_coeff : float
        k (m^2.5/s).
    max_level_m : float, optional
        Tank height; above it the tank overflows (default 2.5 m).
    initial_level_m : float, optional
        Level at t = 0 (default 1.0 m).
    substeps : int, optional
        Euler sub-steps per step (default 4).

    Input ``inflow`` (m³/s; None = valve closed). Outputs the true ``level``
    ``[h]`` (m) and ``inflow``: the inflow that entered during the last step
    (what a flow meter in the inlet line sees).
    """

    optional_params = ("initial_level_m", "area_m2", "outflow_coeff", "max_level_m", "substeps")
    role = "plant"
    inputs = ("inflow",)
    outputs = ("level", "inflow")
    direct_feedthrough = False

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self._configure()
        self.h = float(params.get("initial_level_m", 1.0))
        self.q_in = self.k * math.sqrt(max(self.h, 0.0))

    def _configure(self) -> None:
        p = self.params
        self.area = float(p.get("area_m2", 0.5))
        self.k = float(p.get("outflow_coeff", 0.01))
        self.h_max = float(p.get("max_level_m", 2.5))
        self.substeps = max(1, int(p.get("substeps", 4)))

    def set_params(self, values):
        super().set_params(values)
        self._configure()

    def output(self, t):
        return {"level": np.array([self.h]), "inflow": self.q_in}

    def step(self, t, dt, inputs):
        q = _f(inputs.get("inflow"))
        q = 0.0 if q is None else max(q, 0.0)
        self.q_in = q
        h = self.h
        d = dt / self.substeps
        for _ in range(self.substeps):
            h = min(max(h + d * tank_derivative(h, q, self.area, self.k), 0.0), self.h_max)
        self.h = h
        return {}

    def export_state(self):
        return {"level": self.h}

    def import_state(self, state):
        if "level" in state:
            self.h = float(state["level"])


@register("actuator.valve")
class ControlValve(RuntimeModule):
    """Inlet control valve: ``inflow = q_max · clip(valve_cmd, 0, 1)``.

    Parameters (``params``)
    -----------------------
    max_flow_m3_s : float
        Inflow when fully open (m³/s).

    Input ``valve_cmd`` (0..1); optional ``flow_measured`` (m³/s, from a flow
    meter). Output ``inflow``. Residual signal ``command_error`` = |q_max·u_prev −
    flow_measured| (m³/s): the flow the valve was commanded to pass in the last
    step minus the flow measured, near the flow-meter noise when healthy and a
    fraction of the flow when the valve loses effectiveness or sticks.

    Examples
    --------
    >>> v = ControlValve("v", {"max_flow_m3_s": 0.02}, np.random.default_rng(0))
    >>> v.step(0.0, 0.2, {"valve_cmd": 0.5})
    {'inflow': 0.01}
    >>> _ = v.step(0.2, 0.2, {"valve_cmd": 0.5, "flow_measured": 0.006})
    >>> round(v.local_signals()["command_error"], 6)
    0.004
    """

    optional_params = ("max_flow_m3_s",)
    role = "actuator"
    inputs = ("valve_cmd",)
    optional_inputs = ("flow_measured",)
    outputs = ("inflow",)
    residual_signals = ("command_error",)
    fault_kinds = frozenset(
        {"effectiveness_loss", "stuck", "dropout", "bias", "bias_drift", "noise_increase"}
    )
    main_output = "inflow"

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self.q_max = float(params.get("max_flow_m3_s", 0.025))
        self.prev_flow: float | None = None
        self.signals = {"command_error": math.nan}

    def set_params(self, values):
        super().set_params(values)
        self.q_max = float(self.params.get("max_flow_m3_s", 0.025))

    def step(self, t, dt, inputs):
        meas = _f(inputs.get("flow_measured"))
        if meas is not None and self.prev_flow is not None:
            self.signals["command_error"] = abs(self.prev_flow - meas)
        u = _f(inputs.get("valve_cmd"))
        if u is None:
            self.prev_flow = None
            return {"inflow": None}
        q = self.q_max * min(max(u, 0.0), 1.0)
        self.prev_flow = q
        return {"inflow": q}


@register("sensor.flow")
class FlowMeter(RuntimeModule):
    """Inlet flow meter (e.g. magnetic-inductive): true inflow + Gaussian noise.

    Parameters (``params``): ``noise_m3_s`` (standard deviation, m³/s).
    Input ``inflow`` (true, from the plant); output ``flow_measured``.
    """

    optional_params = ("noise_m3_s",)
    role = "sensor"
    inputs = ("inflow",)
    outputs = ("flow_measured",)
    fault_kinds = _SENSOR_FAULTS

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self._configure()

    def _configure(self):
        self.noise = float(self.params.get("noise_m3_s", 2e-4))
        self.noise_levels = {"flow_measured": self.noise}

    def set_params(self, values):
        super().set_params(values)
        self._configure()

    def step(self, t, dt, inputs):
        q = _f(inputs.get("inflow"))
        if q is None:
            return {"flow_measured": None}
        return {"flow_measured": q + self.noise * float(self.rng.standard_normal())}


@register("sensor.level")
class LevelSensor(RuntimeModule):
    """Level transmitter (radar/ultrasonic): true level + bias + Gaussian noise.

    Parameters (``params``)
    -----------------------
    noise_m : float
        Standard deviation of the noise (m).
    bias_m : float, optional
        Built-in calibration offset (default 0); a drifting bias comes from a
        scenario's ``bias_drift`` fault.

    Input ``level`` (true); output ``level_measured`` (m).
    """

    optional_params = ("noise_m", "bias_m")
    role = "sensor"
    inputs = ("level",)
    outputs = ("level_measured",)
    fault_kinds = _SENSOR_FAULTS

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self._configure()

    def _configure(self):
        self.noise = float(self.params.get("noise_m", 0.005))
        self.bias = float(self.params.get("bias_m", 0.0))
        self.noise_levels = {"level_measured": self.noise}

    def set_params(self, values):
        super().set_params(values)
        self._configure()

    def step(self, t, dt, inputs):
        h = _f(inputs.get("level"))
        if h is None:
            return {"level_measured": None}
        return {"level_measured": h + self.bias + self.noise * float(self.rng.standard_normal())}


# --------------------------------------------------------------------------- M_M
@register("model.tank")
class TankModelNode(RuntimeModule):
    """The tank model as a node: publishes a :class:`TankModel` as ``tank_model``.

    Parameters: ``area_m2``, ``outflow_coeff``, ``max_flow_m3_s``, ``max_level_m``.
    """

    optional_params = tuple(TankModel.__dataclass_fields__)
    role = "model"
    outputs = ("tank_model",)
    direct_feedthrough = False

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self._build()

    def _build(self) -> None:
        fields = TankModel.__dataclass_fields__
        kw = {k: float(v) for k, v in self.params.items() if k in fields}
        self._out = {"tank_model": TankModel(**kw)}

    def set_params(self, values):
        super().set_params(values)
        self._build()

    def output(self, t):
        return self._out


# --------------------------------------------------------------------------- M_F
@register("estimator.level_observer")
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


@register("controller.pi")
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


@register("controller.pi_feedforward")
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


@register("planner.setpoint")
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
