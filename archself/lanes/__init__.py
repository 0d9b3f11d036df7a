"""Lane-batched simulation: many runs of one architecture stepped together.

========================  ==========================================================
name                      what it is
========================  ==========================================================
:class:`LaneModule`       the batched module interface a type opts in with (``lanes =``)
:class:`PerLane`          any type in N lanes, lane by lane (the fallback)
:class:`LaneNormals`      per-lane random streams drawn in blocks, in the per-run order
:class:`LaneWindows`      per-lane sliding windows (ring buffers with running sums)
:class:`ModelFields`      float fields of a model input's per-lane objects, cached
:class:`LaneSystem`       the executor: N per-run systems stepped as one
:func:`simulate_lanes`    N fixed runs of a scenario → N ``RunResult`` s
========================  ==========================================================

See ``docs/lanes.md`` for the interface and how to add batching to a plugin.
"""

from __future__ import annotations

from archself.lanes.batching import lane_module
from archself.lanes.module import ALL, LaneModule, LaneNormals, ModelFields, PerLane, row, stack
from archself.lanes.run import simulate_lanes
from archself.lanes.system import LaneSystem
from archself.lanes.windows import LaneWindows

__all__ = [
    "ALL",
    "LaneModule",
    "LaneNormals",
    "LaneSystem",
    "LaneWindows",
    "ModelFields",
    "PerLane",
    "lane_module",
    "row",
    "simulate_lanes",
    "stack",
]
