"""Model nodes (M_M): constant model objects that functional modules consume.

A model node has no inputs and publishes one immutable object every step
(``direct_feedthrough = False``: its output depends on its parameters only).
Functional modules read the numbers they need from it (wheel base and radius
from the kinematic model, wheel limits from the actuator model, the wheel lag
from the dynamic model), so a parameter update of a model node reaches every
user through the edges of the architecture.

Examples
--------
>>> import numpy as np
>>> m = DiffDriveKinematicsModel("km", {"wheel_base_m": 0.5, "wheel_radius_m": 0.1},
...                              np.random.default_rng(0))
>>> m.output(0.0)["kinematics"]
Kinematics(wheel_base_m=0.5, wheel_radius_m=0.1)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from archself.modules.base import RuntimeModule

__all__ = [
    "Kinematics",
    "Dynamics",
    "Actuation",
    "DiffDriveKinematicsModel",
    "DiffDriveDynamicsModel",
    "ActuatorModel",
]


@dataclass(frozen=True)
class Kinematics:
    """Kinematic model of a differential drive: wheel base and wheel radius (m)."""

    wheel_base_m: float = 0.5
    wheel_radius_m: float = 0.1


@dataclass(frozen=True)
class Dynamics:
    """Rigid-body and wheel-speed dynamics: mass, yaw inertia, wheel-speed lag."""

    mass_kg: float = 12.0
    inertia_kg_m2: float = 0.6
    wheel_time_constant_s: float = 0.1


@dataclass(frozen=True)
class Actuation:
    """Actuator model: symmetric wheel-speed limit (rad/s) and nominal effectiveness."""

    max_wheel_speed_rad_s: float = 12.0
    effectiveness: float = 1.0


class _ModelNode(RuntimeModule):
    role = "model"
    direct_feedthrough = False
    _cls: type = object
    _key = ""

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self._build()

    def _build(self) -> None:
        fields = self._cls.__dataclass_fields__  # type: ignore[attr-defined]
        kw = {k: float(v) for k, v in self.params.items() if k in fields}
        self._obj = self._cls(**kw)
        self._out = {self._key: self._obj}

    def output(self, t: float) -> dict[str, Any]:
        return self._out

    def set_params(self, values: dict[str, Any]) -> None:
        super().set_params(values)
        self._build()


class DiffDriveKinematicsModel(_ModelNode):
    """Unicycle kinematics (``wheel_base_m``, ``wheel_radius_m``) → output ``kinematics``."""

    optional_params = tuple(Kinematics.__dataclass_fields__)
    outputs = ("kinematics",)
    _cls = Kinematics
    _key = "kinematics"


class DiffDriveDynamicsModel(_ModelNode):
    """Dynamics (``mass_kg``, ``inertia_kg_m2``, ``wheel_time_constant_s``) → ``dynamics``."""

    optional_params = tuple(Dynamics.__dataclass_fields__)
    outputs = ("dynamics",)
    _cls = Dynamics
    _key = "dynamics"


class ActuatorModel(_ModelNode):
    """Actuator limits (``max_wheel_speed_rad_s``, ``effectiveness``) → ``actuation``."""

    optional_params = tuple(Actuation.__dataclass_fields__)
    outputs = ("actuation",)
    _cls = Actuation
    _key = "actuation"
