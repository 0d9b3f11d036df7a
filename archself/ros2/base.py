"""What every part of the bridge shares: its error and the import of rclpy."""

from __future__ import annotations

from typing import Any

from archself.errors import ArchselfError

__all__ = ["INSTALL_HINT", "Ros2Error", "require_rclpy"]

INSTALL_HINT = "rclpy is not installed; install the ROS 2 wheels: pip install 'archself[ros2]'"


class Ros2Error(ArchselfError):
    """The ROS 2 bridge cannot do what it was asked (one-line message)."""


def require_rclpy() -> Any:
    """Import :mod:`rclpy` or raise :class:`Ros2Error` naming the extra to install."""
    try:
        import rclpy
    except ImportError:
        raise Ros2Error(INSTALL_HINT) from None
    return rclpy
