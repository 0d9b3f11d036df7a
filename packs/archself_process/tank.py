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
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from archself.modules.base import Param, RuntimeModule

__all__ = [
    "TankModel",
    "MODEL_PARAMETERS",
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

    Each field's default and unit are also the parameters of ``model.tank``.
    """

    #: ranges: a 1 cm² standpipe to a 100 m × 100 m basin, at most 100 m high
    area_m2: float = field(
        default=0.5, metadata={"unit": "m²", "doc": "cross-section A", "min": 1e-4, "max": 1e4}
    )
    outflow_coeff: float = field(
        default=0.01,
        metadata={"unit": "m^2.5/s", "doc": "k of q_out = k·sqrt(h)", "min": 0.0, "max": 100.0},
    )
    max_flow_m3_s: float = field(
        default=0.025,
        metadata={"unit": "m³/s", "doc": "inflow of the fully open healthy valve",
                  "min": 1e-6, "max": 100.0},
    )
    max_level_m: float = field(
        default=2.5,
        metadata={"unit": "m", "doc": "tank height (overflow above it)", "min": 0.01, "max": 100.0},
    )

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

#: The fields of :class:`TankModel` as declared parameters (name, default, unit: written once).
MODEL_PARAMETERS: dict[str, Param] = {
    f.name: Param(
        f.default, f.metadata["unit"], f.metadata["doc"], min=f.metadata["min"],
        max=f.metadata["max"],
    )
    for f in fields(TankModel)
}


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
    """Sliding-window mean of a scalar over ``window_s`` seconds, and its t-statistic.

    The value is NaN until the samples span at least half the window (a mean of a
    few noisy samples would look like a bias). :meth:`t_value` divides the mean by
    its standard error, the noise measured from the same samples by their first
    differences (σ̂² = mean of Δv² / 2): white noise of any size gives the same
    statistic, a bias stands out by how many samples carry it.

    Examples
    --------
    >>> w = MeanWindow(4.0)
    >>> for t, v in [(0.0, 1.0), (1.0, -1.0), (2.0, 3.0)]:
    ...     w.add(t, v)
    >>> w.value(), round(w.t_value(), 3)
    (1.0, 0.775)
    """

    def __init__(self, window_s: float) -> None:
        self.window_s = float(window_s)
        self.items: deque[tuple[float, float]] = deque()
        self.total = 0.0
        self.steps = 0.0  # Σ (v_k − v_{k−1})² over the window's consecutive samples
        self.start: float | None = None
        self.last = 0.0

    def add(self, t: float, v: float) -> None:
        if self.start is None:
            self.start = t
        self.last = t
        items = self.items
        if items:
            self.steps += (v - items[-1][1]) ** 2
        items.append((t, v))
        self.total += v
        while items and items[0][0] <= t - self.window_s:
            old = items.popleft()[1]
            self.total -= old
            if items:
                self.steps -= (items[0][1] - old) ** 2

    def value(self) -> float:
        n = len(self.items)
        if n == 0 or self.start is None or self.last - self.start < 0.5 * self.window_s:
            return math.nan
        return self.total / n

    def t_value(self) -> float:
        """|mean| / (σ̂/√n), σ̂ from the first differences (NaN as :meth:`value`, or
        without noise)."""
        mean = self.value()
        n = len(self.items)
        var = self.steps / (2.0 * (n - 1)) if n > 1 else 0.0
        if math.isnan(mean) or var <= 0.0:
            return math.nan
        return abs(mean) / math.sqrt(var / n)

    def clear(self) -> None:
        self.items.clear()
        self.total = 0.0
        self.steps = 0.0
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

    Parameters: :data:`MODEL_PARAMETERS` but the valve's ``max_flow_m3_s``, the
    start level and the Euler sub-steps (see :attr:`parameters`).

    Input ``inflow`` (m³/s; None = valve closed). Outputs the true ``level``
    ``[h]`` (m) and ``inflow``: the inflow that entered during the last step
    (what a flow meter in the inlet line sees).

    Disturbances (the module's own random stream; 0 turns one off), each a
    first-order Gauss–Markov (Ornstein–Uhlenbeck) process with correlation time
    ``disturbance_time_s``:

    - **supply pressure** — the inflow through the valve varies by a relative
      ``supply_variation`` (standard deviation): upstream pressure fluctuations
      change the flow at a given opening. The flow meter sees it; the model does
      not;
    - **draw-off** — the outflow varies by a relative ``outflow_variation``
      (a downstream consumer, a partly blocked drain): unmeasured, it shows only in
      the level.

    docs/disturbances.md gives the shipped values and where they come from.
    """

    state_fields = ("h", "q_in")

    parameters = {
        **{k: v for k, v in MODEL_PARAMETERS.items() if k != "max_flow_m3_s"},
        "initial_level_m": Param(1.0, "m", "level at t = 0", min=0.0, max=100.0),
        "substeps": Param(4, "", "Euler sub-steps per step", min=1, max=1000),
        "supply_variation": Param(
            0.0, "", "relative std of the inflow (supply pressure)", min=0.0, max=1.0
        ),
        "outflow_variation": Param(
            0.0, "", "relative std of the outflow (draw-off)", min=0.0, max=1.0
        ),
        "disturbance_time_s": Param(
            30.0, "s", "correlation time of both disturbances", min=0.001, max=1e6
        ),
    }
    role = "plant"
    inputs = ("inflow",)
    outputs = ("level", "inflow")
    output_sizes = {"level": 1, "inflow": 1}
    direct_feedthrough = False
    lanes = "archself_process.lanes_tank:TankPlantLanes"

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self.h = float(self.params["initial_level_m"])
        self.q_in = self.k * math.sqrt(max(self.h, 0.0))

    def configure(self) -> None:
        p = self.params
        self.area = float(p["area_m2"])
        self.k = float(p["outflow_coeff"])
        self.h_max = float(p["max_level_m"])
        self.substeps = max(1, int(p["substeps"]))
        self.supply = float(p["supply_variation"])
        self.draw = float(p["outflow_variation"])
        self.t_dist = max(float(p["disturbance_time_s"]), 1e-9)
        self.d_in = getattr(self, "d_in", 0.0)
        self.d_out = getattr(self, "d_out", 0.0)

    def output(self, t):
        return {"level": np.array([self.h]), "inflow": self.q_in}

    def step(self, t, dt, inputs):
        q = _f(inputs.get("inflow"))
        q = 0.0 if q is None else max(q, 0.0)
        k = self.k
        if self.supply > 0 or self.draw > 0:
            self._disturb(dt)
            q *= max(1.0 + self.supply * self.d_in, 0.0)
            k *= max(1.0 + self.draw * self.d_out, 0.0)
        self.q_in = q
        h = self.h
        d = dt / self.substeps
        for _ in range(self.substeps):
            h = min(max(h + d * tank_derivative(h, q, self.area, k), 0.0), self.h_max)
        self.h = h
        return {}

    def _disturb(self, dt: float) -> None:
        """Advance the two unit-variance Gauss–Markov processes by ``dt`` (exact discretization)."""
        a = math.exp(-max(dt, 0.0) / self.t_dist)
        n = self.rng.standard_normal(2) * math.sqrt(1.0 - a * a)
        self.d_in = a * self.d_in + float(n[0])
        self.d_out = a * self.d_out + float(n[1])

    def export_state(self):
        return {"level": self.h}

    def import_state(self, state):
        if "level" in state:
            self.h = float(state["level"])


class ControlValve(RuntimeModule):
    """Inlet control valve: ``inflow = q_max · clip(valve_cmd, 0, 1)``.

    Parameter ``max_flow_m3_s``: q_max, the inflow when fully open (m³/s).

    Input ``valve_cmd`` (0..1); optional ``flow_measured`` (m³/s, from a flow
    meter). Output ``inflow``. Residual signal ``command_error`` = q_max·u_prev −
    flow_measured (m³/s, signed: the shortfall): the flow the valve was commanded
    to pass in the last step minus the flow measured, near 0 on average when
    healthy and a fraction of the flow when the valve loses effectiveness or
    sticks. ``error_smoothing_s`` > 0 averages it at every step, so that the
    Monitor (which samples once per MAPE-K period) sees the flow-meter noise
    averaged out.

    Examples
    --------
    >>> v = ControlValve("v", {"max_flow_m3_s": 0.02}, np.random.default_rng(0))
    >>> v.step(0.0, 0.2, {"valve_cmd": 0.5})
    {'inflow': 0.01}
    >>> _ = v.step(0.2, 0.2, {"valve_cmd": 0.5, "flow_measured": 0.006})
    >>> round(v.local_signals()["command_error"], 6)
    0.004
    """

    state_fields = ("prev_flow",)

    parameters = {
        "max_flow_m3_s": MODEL_PARAMETERS["max_flow_m3_s"],
        "error_smoothing_s": Param(
            0.0, "s", "time constant of the command_error average kept at every step (0: raw)",
            min=0.0, max=3600.0,
        ),
    }
    role = "actuator"
    inputs = ("valve_cmd",)
    optional_inputs = ("flow_measured",)
    outputs = ("inflow",)
    residual_signals = ("command_error",)
    fault_kinds = frozenset(
        {"effectiveness_loss", "stuck", "dropout", "bias", "bias_drift", "noise_increase"}
    )
    main_output = "inflow"
    lanes = "archself_process.lanes_tank:ControlValveLanes"

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self.prev_flow: float | None = None
        self.signals = {"command_error": math.nan}

    def configure(self) -> None:
        self.q_max = float(self.params["max_flow_m3_s"])
        self.smoothing = float(self.params["error_smoothing_s"])

    def step(self, t, dt, inputs):
        meas = _f(inputs.get("flow_measured"))
        if meas is not None and self.prev_flow is not None:
            e = self.prev_flow - meas
            last = self.signals["command_error"]
            if self.smoothing > 0 and last == last:  # average at the step rate
                e = last + (1.0 - math.exp(-dt / self.smoothing)) * (e - last)
            self.signals["command_error"] = e
        u = _f(inputs.get("valve_cmd"))
        if u is None:
            self.prev_flow = None
            return {"inflow": None}
        q = self.q_max * min(max(u, 0.0), 1.0)
        self.prev_flow = q
        return {"inflow": q}


class FlowMeter(RuntimeModule):
    """Inlet flow meter (e.g. magnetic-inductive): true inflow + Gaussian noise.

    Input ``inflow`` (true, from the plant); output ``flow_measured``.
    """

    parameters = {
        "noise_m3_s": Param(2e-4, "m³/s", "standard deviation of the noise", min=0.0, max=100.0),
    }
    role = "sensor"
    inputs = ("inflow",)
    outputs = ("flow_measured",)
    fault_kinds = _SENSOR_FAULTS
    lanes = "archself_process.lanes_tank:FlowMeterLanes"

    def configure(self) -> None:
        self.noise = float(self.params["noise_m3_s"])
        self.noise_levels = {"flow_measured": self.noise}

    def step(self, t, dt, inputs):
        q = _f(inputs.get("inflow"))
        if q is None:
            return {"flow_measured": None}
        return {"flow_measured": q + self.noise * float(self.rng.standard_normal())}


class LevelSensor(RuntimeModule):
    """Level transmitter (radar/ultrasonic): true level + bias + Gaussian noise.

    ``bias_m`` is a built-in calibration offset; a drifting bias comes from a
    scenario's ``bias_drift`` fault. Input ``level`` (true); output
    ``level_measured`` (m).
    """

    parameters = {
        "noise_m": Param(0.005, "m", "standard deviation of the noise", min=0.0, max=100.0),
        "bias_m": Param(0.0, "m", "built-in calibration offset", min=-100.0, max=100.0),
    }
    role = "sensor"
    inputs = ("level",)
    outputs = ("level_measured",)
    fault_kinds = _SENSOR_FAULTS
    lanes = "archself_process.lanes_tank:LevelSensorLanes"

    def configure(self) -> None:
        self.noise = float(self.params["noise_m"])
        self.bias = float(self.params["bias_m"])
        self.noise_levels = {"level_measured": self.noise}

    def step(self, t, dt, inputs):
        h = _f(inputs.get("level"))
        if h is None:
            return {"level_measured": None}
        return {"level_measured": h + self.bias + self.noise * float(self.rng.standard_normal())}


# --------------------------------------------------------------------------- M_M
class TankModelNode(RuntimeModule):
    """The tank model as a node: publishes a :class:`TankModel` as ``tank_model``.

    Parameters: the fields of :class:`TankModel` (:data:`MODEL_PARAMETERS`).

    Examples
    --------
    >>> node = TankModelNode("m", {"area_m2": 0.4}, np.random.default_rng(0))
    >>> node.output(0.0)["tank_model"]
    TankModel(area_m2=0.4, outflow_coeff=0.01, max_flow_m3_s=0.025, max_level_m=2.5)
    """

    parameters = MODEL_PARAMETERS
    role = "model"
    outputs = ("tank_model",)
    direct_feedthrough = False
    lanes = "archself_process.lanes_tank:TankModelNodeLanes"

    def configure(self) -> None:
        kw = {k: float(self.params[k]) for k in MODEL_PARAMETERS}
        self._out = {"tank_model": TankModel(**kw)}

    def output(self, t):
        return self._out
