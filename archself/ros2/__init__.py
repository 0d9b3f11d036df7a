"""The MAPE-K loop as a ROS 2 node (docs/ros2.md; ``pip install 'archself[ros2]'``).

The bridge is another transport for :class:`archself.live.LiveLoop`: measurements
arrive on topics (one per module output and residual signal, :mod:`.topics`),
structural actions go to the lifecycle services of the nodes, parameter updates to
their parameter services, and the decision log and the mode changes are published.
Nothing here imports :mod:`rclpy` until a bridge or the demo is made:
:func:`require_rclpy` turns a missing installation into one line.

=====================  ======================================================
name                   what it is
=====================  ======================================================
``Ros2Bridge``         the loop's node (:mod:`archself.ros2.bridge`)
``run_bridge``         spin a bridge until the plant ends or falls silent
``DemoPlant``          a compiled simulated system stepped as a ROS 2 plant
                       with its functional modules as lifecycle nodes
                       (:mod:`archself.ros2.demo`)
``Ros2Error``          what the bridge refuses (an ``ArchselfError``)
=====================  ======================================================
"""

from __future__ import annotations

from typing import Any

from archself.ros2.base import INSTALL_HINT, Ros2Error, require_rclpy

__all__ = [
    "INSTALL_HINT", "DemoPlant", "Ros2Bridge", "Ros2Error", "require_rclpy", "run_bridge",
]


def __getattr__(name: str) -> Any:
    if name in ("Ros2Bridge", "run_bridge"):
        from archself.ros2 import bridge

        return getattr(bridge, name)
    if name == "DemoPlant":
        from archself.ros2.demo import DemoPlant

        return DemoPlant
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
