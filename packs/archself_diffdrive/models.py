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

from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

from archself.modules.base import Param, RuntimeModule

__all__ = [
    "Kinematics",
    "Dynamics",
    "Actuation",
    "DiffDriveKinematicsModel",
    "DiffDriveDynamicsModel",
    "ActuatorModel",
    "parameters_of",
]


def _field(default: float, unit: str, doc: str, lo: float, hi: float) -> Any:
    """A model field with its unit, doc and physically meaningful range [lo, hi]."""
    return field(default=default, metadata={"unit": unit, "doc": doc, "min": lo, "max": hi})


@dataclass(frozen=True)
class Kinematics:
    """Kinematic model of a differential drive: wheel base and wheel radius (m)."""

    #: 0.01–100 m: a toy robot to a mining truck
    wheel_base_m: float = _field(0.5, "m", "distance between the wheels", 0.01, 100.0)
    wheel_radius_m: float = _field(0.1, "m", "wheel radius", 0.001, 10.0)


@dataclass(frozen=True)
class Dynamics:
    """Rigid-body and wheel-speed dynamics: mass, yaw inertia, wheel-speed lag."""

    mass_kg: float = _field(12.0, "kg", "mass", 0.01, 1e6)
    inertia_kg_m2: float = _field(0.6, "kg·m²", "yaw moment of inertia", 1e-6, 1e8)
    wheel_time_constant_s: float = _field(
        0.1, "s", "lag of the wheel speeds behind the commands (0: none)", 0.0, 100.0
    )


@dataclass(frozen=True)
class Actuation:
    """Actuator model: symmetric wheel-speed limit (rad/s) and nominal effectiveness."""

    max_wheel_speed_rad_s: float = _field(
        12.0, "rad/s", "symmetric wheel-speed limit", 0.01, 1e4
    )
    effectiveness: float = _field(1.0, "", "nominal effectiveness of the wheels", 0.0, 2.0)


def parameters_of(cls: type) -> dict[str, Param]:
    """The fields of the model dataclass ``cls`` as declared parameters (written once).

    Examples
    --------
    >>> parameters_of(Kinematics)["wheel_base_m"]  # doctest: +NORMALIZE_WHITESPACE
    Param(default=0.5, unit='m', doc='distance between the wheels', min=0.01, max=100.0,
          period=False)
    """
    return {
        f.name: Param(
            f.default,
            f.metadata.get("unit", ""),
            f.metadata.get("doc", ""),
            min=f.metadata.get("min"),
            max=f.metadata.get("max"),
        )
        for f in fields(cls)
    }


class _ModelNode(RuntimeModule):
    role = "model"
    finite_outputs = True  # constants (archself.system.live.needs_checks)
    direct_feedthrough = False
    _cls: ClassVar[type] = object
    _key: ClassVar[str] = ""
    lanes = "archself_diffdrive.lanes_planning:ModelNodeLanes"

    def configure(self) -> None:
        names = self.parameters or {}
        self._obj = self._cls(**{k: float(v) for k, v in self.params.items() if k in names})
        self._out = {self._key: self._obj}

    def output(self, t: float) -> dict[str, Any]:
        return self._out


class DiffDriveKinematicsModel(_ModelNode):
    """Unicycle kinematics (the fields of :class:`Kinematics`) → output ``kinematics``."""

    parameters = parameters_of(Kinematics)
    outputs = ("kinematics",)
    _cls = Kinematics
    _key = "kinematics"


class DiffDriveDynamicsModel(_ModelNode):
    """Dynamics (the fields of :class:`Dynamics`) → output ``dynamics``."""

    parameters = parameters_of(Dynamics)
    outputs = ("dynamics",)
    _cls = Dynamics
    _key = "dynamics"


class ActuatorModel(_ModelNode):
    """Actuator limits (the fields of :class:`Actuation`) → output ``actuation``."""

    parameters = parameters_of(Actuation)
    outputs = ("actuation",)
    _cls = Actuation
    _key = "actuation"
