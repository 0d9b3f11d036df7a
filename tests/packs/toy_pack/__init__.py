"""A test pack of four scalar types, found through its own entry points.

The test puts this folder on ``sys.path`` (its ``toy_pack-0.1.dist-info`` holds
the entry points) and makes the shipped packs unimportable, so an architecture
of these types can only run if the core needs no pack.
"""

from __future__ import annotations

from typing import Any

from archself.modules.base import Param, RuntimeModule

_FAULTS = frozenset({"bias", "bias_drift", "noise_increase", "dropout", "stuck"})


class Integrator(RuntimeModule):
    """x' = u − leak·x; publishes ``x`` as a 1-vector."""

    role = "plant"
    inputs = ("u",)
    outputs = ("x",)
    direct_feedthrough = False
    parameters = {"leak": Param(0.1, "1/s")}

    def configure(self) -> None:
        self.x = getattr(self, "x", 0.0)

    def output(self, t: float) -> dict[str, Any]:
        return {"x": [self.x]}

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        u = inputs.get("u")
        self.x += dt * ((0.0 if u is None else float(u)) - self.params["leak"] * self.x)
        return {}


class Sensor(RuntimeModule):
    """Reads ``x`` with noise."""

    role = "sensor"
    inputs = ("x",)
    outputs = ("y",)
    fault_kinds = _FAULTS
    parameters = {"noise": Param(0.01)}

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        x = inputs.get("x")
        if x is None:
            return {"y": None}
        return {"y": float(x[0]) + self.params["noise"] * float(self.rng.standard_normal())}


class PController(RuntimeModule):
    """u = gain·(r − y); residual ``error`` = |r − y|."""

    role = "controller"
    inputs = ("y", "r")
    outputs = ("u",)
    residual_signals = ("error",)
    fault_kinds = frozenset({"effectiveness_loss"})
    parameters = {"gain": Param(1.0)}

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        y, r = inputs.get("y"), inputs.get("r")
        if y is None or r is None:
            return {"u": 0.0}
        e = float(r[0]) - float(y)
        self.signals["error"] = abs(e)
        return {"u": self.params["gain"] * e}


class Constant(RuntimeModule):
    """Publishes the reference ``r`` = [value]."""

    role = "planner"
    outputs = ("r",)
    parameters = {"value": Param(1.0)}

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        return {"r": [self.params["value"]]}
