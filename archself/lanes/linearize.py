"""The whole-loop linearization of one lane with its perturbed copies stepped as lanes.

:func:`archself.system.linearizing.numerical_loop` steps one snapshot per perturbation
(the nominal copy, then +h and −h of every column group: 29 copies of the diff-drive's
a2) for ``steps`` steps each, one per-run step at a time. :func:`lane_loop` makes the
same copies (:func:`~archself.system.linearizing.loop_probes`) and steps them together
as the lanes of a :class:`~archself.lanes.system.LaneSystem` resumed from them
(:meth:`LaneSystem.resume`), then stores each lane's state back into its copy, so the
same :meth:`~archself.system.linearizing.LoopProbes.assemble` makes A. The lane classes
compute what the per-run classes compute (docs/lanes.md), so the slopes are the
per-run path's (to the rounding of the few operations a lane class orders otherwise,
divided by 2h).
"""

from __future__ import annotations

from typing import Any

from archself.lanes.module import ALL
from archself.lanes.system import LaneSystem
from archself.linear.closed_loop import WholeLoop
from archself.system.linearizing import loop_probes

__all__ = ["lane_loop"]


def lane_loop(system: Any, configuration: str | None = None, steps: int = 1) -> WholeLoop:
    """:func:`~archself.system.linearizing.numerical_loop` of the per-run ``system``, its
    perturbed copies stepped as lanes.

    Parameters
    ----------
    system : LiveSystem
        A running per-run system (a lane's, materialized); never changed.
    configuration : str, optional
        The configuration to linearize (default: the active one).
    steps : int
        Steps of the map.
    """
    probes = loop_probes(system, configuration, steps)
    active = probes.probe.base._plan.active  # what the copies step: nothing else is copied
    copies = [probes.probe.copy(shift, active) for shift in probes.shifts]
    lanes = LaneSystem.resume(copies, smooth=True)
    for _ in range(steps):
        lanes.step()
    lanes.store(ALL)
    for i in range(lanes.n):
        probes.probe.raised({n: lanes.health.reason(n, i) for n in lanes.health.why})
    return probes.assemble(copies)
