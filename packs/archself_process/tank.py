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
from typing import Any

import numpy as np

from archself.modules.base import RuntimeModule

__all__ = [
    "TankModel",
    "TankPlant",
    "ControlValve",
    "FlowMeter",
    "LevelSensor",
    "TankModelNode",
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
