"""Lane-batched diff-drive planner and model nodes (issue 16).

:class:`SplinePlannerLanes` (lanes with the same path share its lookup table) and
:class:`ModelNodeLanes` (each lane's model object) on the base of
:mod:`archself_diffdrive.lanes_physical`.
"""

from __future__ import annotations

import numpy as np

from archself.lanes.module import ALL, lane_count
from archself_diffdrive.lanes_physical import _Lanes

__all__ = ["ModelNodeLanes", "SplinePlannerLanes"]


class SplinePlannerLanes(_Lanes):
    """:class:`~archself_diffdrive.planner.SplinePlanner` in N lanes.

    Lanes with the same waypoints and resolution share one lookup table, and lanes
    that also share the speed one reference: with a few such groups (a seed sweep
    has one) each group's reference comes from its first lane's per-run
    :meth:`~archself_diffdrive.planner.SplinePlanner.reference`, else the lookup
    runs vectorized over the lanes.
    """

    #: At most this many groups of lanes are computed one by one.
    few_groups = 4

    @staticmethod
    def _key(m) -> bytes:
        wp = np.asarray(m.params["waypoints"], dtype=float)
        return wp.tobytes() + str((wp.shape, m.ds, m.speed)).encode()

    def load(self, lanes):
        mods = self.modules  # the groups span every lane, whichever lanes are read
        if not isinstance(lanes, slice) and all(  # a lane moved, its path unchanged
            self._keys[i] == self._key(mods[i]) for i in lanes.tolist()
        ):
            return
        self._keys = [self._key(m) for m in mods]
        tables: dict[bytes, int] = {}  # (waypoints, resolution) -> first row in self.table
        groups: dict[tuple[int, float], int] = {}
        parts: list[np.ndarray] = []
        start, group = [], []
        for m in mods:
            wp = np.asarray(m.params["waypoints"], dtype=float)
            key = wp.tobytes() + str((wp.shape, m.ds)).encode()
            if key not in tables:
                tables[key] = sum(len(p) for p in parts)
                parts.append(np.array(m._table.xytk).T)
            start.append(tables[key])
            group.append(groups.setdefault((tables[key], m.speed), len(groups)))
        self.table = np.concatenate(parts)  # x, y, θ, κ per row
        self.start = np.array(start)
        self.group = np.array(group)
        self.first = [mods[group.index(g)] for g in range(len(groups))]
        self._read(ALL, "speed", [m.speed for m in mods])
        self._read(ALL, "ds", [m.ds for m in mods])
        self._read(ALL, "length", [m.length for m in mods])
        self.last = np.array([m._n for m in mods]) - 1

    def step(self, t, dt, inputs, lanes):
        if len(self.first) <= self.few_groups:
            out = np.array([m.reference(t) for m in self.first])[self.group[lanes]]
        else:
            out = self._lookup(t, lanes)
        return {"reference": self._screen(out, lanes)}

    def _lookup(self, t: float, lanes) -> np.ndarray:
        """:meth:`SplinePlanner.reference` of every lane in ``lanes``, vectorized."""
        speed = self.speed[lanes]
        start, last = self.start[lanes], self.last[lanes]
        s = speed * t
        f = np.maximum(s, 0.0) / self.ds[lanes]
        i = np.minimum(np.floor(f), last - 1)
        a = np.minimum(f - i, 1.0)
        b = 1.0 - a
        row = start + i.astype(np.intp)
        t0, t1 = self.table[row], self.table[row + 1]
        out = np.empty((lane_count(self.n, lanes), 5))
        out[:, :3] = b[:, None] * t0[:, :3] + a[:, None] * t1[:, :3]
        out[:, 3] = speed
        out[:, 4] = (b * t0[:, 3] + a * t1[:, 3]) * speed
        done = s >= self.length[lanes]
        if done.any():  # stopped at the end of the path
            out[done, :3] = self.table[(start + last)[done], :3]
            out[done, 3:] = 0.0
        return out


class ModelNodeLanes(_Lanes):
    """A model node (:mod:`archself_diffdrive.models`) in N lanes: each lane's object."""

    def load(self, lanes):
        self.key = self.modules[0]._key
        self.objects = [m._out[self.key] for m in self.modules]

    def output(self, t, lanes):
        if isinstance(lanes, slice):
            return {self.key: list(self.objects)}
        return {self.key: [self.objects[i] for i in lanes]}
