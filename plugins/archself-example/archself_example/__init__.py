"""Example archself plugin: a magnetometer heading sensor and a level controller.

Registered through the ``archself.modules`` entry point in this package's
pyproject.toml (name = type key, value = class); archself never imports a name
written in an architecture file.
"""

from __future__ import annotations

from typing import Any

from archself.modules.base import Param, RuntimeModule
from archself_example.level import ProportionalLevel

__all__ = ["Magnetometer", "ProportionalLevel"]


class Magnetometer(RuntimeModule):
    """Absolute heading from the Earth's field: noisy but free of drift.

    Inputs ``pose`` [x, y, θ]; output ``heading`` (rad).
    """

    parameters = {
        "noise_rad": Param(0.02, "rad", "standard deviation of the heading noise"),
        "offset_rad": Param(0.0, "rad", "constant hard-iron offset"),
    }
    role = "sensor"
    inputs = ("pose",)
    outputs = ("heading",)
    fault_kinds = frozenset({"bias", "bias_drift", "noise_increase", "dropout", "stuck"})

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        pose = inputs.get("pose")
        if pose is None:
            return {"heading": None}
        noise = float(self.params["noise_rad"])
        offset = float(self.params["offset_rad"])
        return {"heading": float(pose[2]) + offset + noise * float(self.rng.standard_normal())}
