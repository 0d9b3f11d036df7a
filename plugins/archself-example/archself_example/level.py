"""A proportional level controller with model feed-forward: a plugin controller.

It shows everything a controller type gives archself: declared signals, parameters
with defaults, a residual signal for the monitor (Eq. 12) and a linearization for the
eigenvalue stability filter (Eq. 21).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.modules.base import Param, RuntimeModule


class ProportionalLevel(RuntimeModule):
    """``u = u_ff(h_ref) + kp·(h_ref − ĥ)``, clipped to a valve opening in [0, 1].

    Inputs ``setpoint`` ([h_ref, ...]) and ``level_estimate``; optional ``tank_model``
    (the model node's object with ``equilibrium_inflow(h)``, ``linear(h)`` and
    ``max_flow_m3_s``). Output ``valve_cmd``. Residual signal ``tracking_error``.
    """

    parameters = {"kp": Param(3.0, "1/m", "proportional gain")}
    role = "controller"
    inputs = ("setpoint", "level_estimate")
    optional_inputs = ("tank_model",)
    outputs = ("valve_cmd",)
    residual_signals = ("tracking_error",)

    def __init__(self, name: str, params: dict[str, Any], rng: np.random.Generator) -> None:
        super().__init__(name, params, rng)
        self.model: Any = None
        self.h_op = 1.0
        self.signals = {"tracking_error": math.nan}

    def configure(self) -> None:
        self.kp = float(self.params["kp"])  # after construction and every set_params

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        self.model = inputs.get("tank_model", self.model)
        ref, est = inputs.get("setpoint"), inputs.get("level_estimate")
        if ref is None or est is None or self.model is None:
            return {"valve_cmd": None}  # degrade: the executor holds the last good output
        h_ref = float(np.atleast_1d(ref)[0])
        error = h_ref - float(est)
        self.h_op = h_ref
        self.signals["tracking_error"] = abs(error)
        u_ff = self.model.equilibrium_inflow(h_ref) / self.model.max_flow_m3_s
        u = u_ff + self.kp * error
        return {"valve_cmd": min(max(u, 0.0), 1.0)}

    def linearization(self) -> np.ndarray | None:
        """Closed loop of ``d(δh)/dt = −a δh + b δu`` with ``δu = −kp δh``: ``[[−a − b·kp]]``."""
        if self.model is None:
            return None
        a, b = self.model.linear(self.h_op)
        return np.array([[-a - b * self.kp]])
