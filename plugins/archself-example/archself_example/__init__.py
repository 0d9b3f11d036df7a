"""Example archself plugin: a magnetometer heading sensor and a level controller.

Registered through the ``archself.modules`` entry point in this package's
pyproject.toml (name = type key, value = class); archself never imports a name
written in an architecture file.
"""

from __future__ import annotations

from typing import Any

from archself.modules.base import RuntimeModule
from archself_example.level import ProportionalLevel

__all__ = ["Magnetometer", "ProportionalLevel"]


class Magnetometer(RuntimeModule):
    """Absolute heading from the Earth's field: noisy but free of drift.

    Parameters (``params`` in the file)
    -----------------------------------
    noise_rad : float
        Standard deviation of the heading noise (rad), default 0.02.
    offset_rad : float
        Constant hard-iron offset (rad), default 0.

    Inputs ``pose`` [x, y, θ]; output ``heading`` (rad).
    """

    optional_params = ("noise_rad", "offset_rad")
    role = "sensor"
    inputs = ("pose",)
    outputs = ("heading",)
    fault_kinds = frozenset({"bias", "bias_drift", "noise_increase", "dropout", "stuck"})

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        pose = inputs.get("pose")
        if pose is None:
            return {"heading": None}
        noise = float(self.params.get("noise_rad", 0.02))
        offset = float(self.params.get("offset_rad", 0.0))
        return {"heading": float(pose[2]) + offset + noise * float(self.rng.standard_normal())}
