"""Topic names, lockstep messages and the lifecycle view of a configuration (no rclpy).

=====================================  ==============================  =================
topic                                  type                            what
=====================================  ==============================  =================
``/archself/<module>/<output>``        ``std_msgs/Float64MultiArray``  a module output;
                                                                       a scalar has no
                                                                       layout dims, a
                                                                       matrix one dim per
                                                                       axis
``/archself/<module>/residual/<sig>``  ``std_msgs/Float64``            the module's
                                                                       ``residual.signal``
                                                                       (NaN: not usable)
``/archself/<module>/health``          ``std_msgs/String``             "" when available,
                                                                       else the reason
``/archself/decisions``                ``std_msgs/String``             one decision record
                                                                       per cycle (JSON)
``/archself/mode``                     ``std_msgs/String``             each command as
                                                                       system_modes names
                                                                       (JSON)
``/archself/tick``, ``/archself/ack``  ``std_msgs/String``             lockstep plant ↔ loop
                                                                       (JSON, ``--clock
                                                                       tick``)
=====================================  ==============================  =================

Names that ROS 2 does not allow in a topic (anything but letters, digits and ``_``)
become ``_``.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from typing import Any

from archself.model.architecture import Architecture
from archself.registry import get
from archself.reports.export import _ros_value

PREFIX = "/archself"
DECISIONS = f"{PREFIX}/decisions"
MODE = f"{PREFIX}/mode"
TICK = f"{PREFIX}/tick"
ACK = f"{PREFIX}/ack"


def ros_name(name: str) -> str:
    """``name`` as a ROS 2 name token (letters, digits, ``_``; not starting with a digit).

    Examples
    --------
    >>> ros_name("wheel-left.2")
    'wheel_left_2'
    """
    out = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return f"_{out}" if out[:1].isdigit() else out


def output_topic(module: str, signal: str) -> str:
    """The topic of output ``signal`` of ``module``.

    Examples
    --------
    >>> output_topic("chassis", "pose")
    '/archself/chassis/pose'
    """
    return f"{PREFIX}/{ros_name(module)}/{ros_name(signal)}"


def residual_topic(module: str, signal: str) -> str:
    """The topic of the residual signal ``signal`` of ``module``."""
    return f"{PREFIX}/{ros_name(module)}/residual/{ros_name(signal)}"


def health_topic(module: str) -> str:
    """The topic of the health of ``module`` ("" when available)."""
    return f"{PREFIX}/{ros_name(module)}/health"


def measured_signals(arch: Architecture) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    """``(outputs, residuals)``: every ``(module, signal)`` the loop may be sent.

    The outputs are those the module types declare (``outputs``); the residual
    signals are each module's ``residual.signal``.
    """

    outputs = [(m, str(s)) for m, mod in arch.modules.items()
               for s in getattr(get(mod.type), "outputs", ())]
    residuals = [(m, mod.residual.signal) for m, mod in arch.modules.items()
                 if mod.residual is not None]
    return outputs, residuals


def node_sets(arch: Architecture, nodes: Iterable[str]) -> dict[str, frozenset[str]]:
    """configuration → the nodes it has active."""
    nodes = set(nodes)
    return {c: frozenset(set(conf.modules) & nodes) for c, conf in arch.configurations.items()}


def configuration_of(
    arch: Architecture, states: Mapping[str, str], current: str | None = None
) -> str | None:
    """The configuration the lifecycle states show, or None when they show none or several.

    ``states`` maps each lifecycle node to its state label (``"active"``,
    ``"inactive"``, ``"unconfigured"``, …). Configurations whose active nodes are
    the active ones match; among several (they differ only in wiring) ``current``
    is kept when it is one of them.

    Examples
    --------
    >>> from archself.model.loader import load_architecture
    >>> from archself.resources import data_dir
    >>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
    >>> states = {"planner": "active", "odometry": "inactive", "ekf": "active",
    ...           "lqr": "inactive", "lqr_fused": "active", "asym_lqr": "inactive"}
    >>> configuration_of(arch, states)
    'a2'
    """
    active = frozenset(n for n, s in states.items() if s == "active")
    matches = [c for c, on in node_sets(arch, states).items() if on == active]
    if current in matches:
        return current
    return matches[0] if len(matches) == 1 else None


def transitions(
    arch: Architecture, nodes: Iterable[str], states: Mapping[str, str], target: str
) -> list[tuple[str, str]]:
    """``(node, "activate" | "deactivate" | "configure")`` that bring ``states`` to ``target``.

    A node to activate that is still unconfigured is configured first. Activations
    come before deactivations (the new path runs before the old one stops).
    """
    want = node_sets(arch, nodes)[target]
    out: list[tuple[str, str]] = []
    for n in nodes:
        state = states.get(n, "unconfigured")
        if n in want and state != "active":
            if state == "unconfigured":
                out.append((n, "configure"))
            out.append((n, "activate"))
    for n in nodes:
        state = states.get(n, "unconfigured")
        if n not in want and state == "active":
            out.append((n, "deactivate"))
        elif n not in want and state == "unconfigured":
            out.append((n, "configure"))
    return out


def parameter_value(v: Any) -> Any:
    """A value a ROS 2 parameter can hold (numbers as float, flat lists, else JSON text)."""

    v = _ros_value(v)
    if isinstance(v, int) and not isinstance(v, bool):
        return float(v)
    if isinstance(v, list) and v and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                         for x in v):
        return [float(x) for x in v]
    return v
