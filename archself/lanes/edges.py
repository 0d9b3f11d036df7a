"""What an edge does to a value in every lane: its latency line and its noise.

Lane values follow :mod:`archself.lanes.module` (NaN = absent in that lane).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.errors import SimulationError
from archself.lanes.module import LaneNormals, stack

__all__ = ["Delay", "add_noise"]


class Delay:
    """An edge's latency line in every lane: a ring of ``delay`` values per lane."""

    def __init__(self, n: int, delay: int) -> None:
        self.n, self.delay = n, delay
        self.buf: np.ndarray | None = None
        self.head = np.zeros(n, dtype=np.intp)

    @classmethod
    def resume(cls, n: int, lines: list[Any]) -> Delay:
        """The line of ``n`` lanes from the per-run lines (deques, oldest value first)."""
        line = cls(n, len(lines[0]))
        cols = [stack([ln[j] for ln in lines]) for j in range(line.delay)]
        first = next((c for c in cols if c is not None), None)
        if first is not None:
            if type(first) is list:
                raise SimulationError("an edge latency on a non-numeric signal cannot run in lanes")
            line.buf = np.full((line.delay,) + first.shape, math.nan)
            for j, c in enumerate(cols):
                if c is not None:
                    line.buf[j] = c
        return line

    def exchange(self, val: Any, idx: np.ndarray) -> Any:
        """Push ``val`` (lanes ``idx``) and return what entered ``delay`` steps before."""
        if type(val) is list:
            raise SimulationError("an edge latency on a non-numeric signal cannot run in lanes")
        if self.buf is None and val is not None:
            shape = (self.delay, self.n) + (() if val.ndim == 1 else (val.shape[1],))
            self.buf = np.full(shape, math.nan)
        h = self.head[idx]
        self.head[idx] = (h + 1) % self.delay
        if self.buf is None:
            return None
        out = self.buf[h, idx]
        self.buf[h, idx] = math.nan if val is None else val
        return None if np.isnan(out).all() else out


def add_noise(val: np.ndarray, idx: np.ndarray, unc: np.ndarray,
               normals: LaneNormals) -> np.ndarray:
    """``val + unc·N(0, 1)`` per lane of ``idx`` with a value (absent lanes draw nothing)."""
    width = 1 if val.ndim == 1 else val.shape[1]
    col = val if val.ndim == 1 else val[:, 0]
    u = unc[idx]
    present = ~np.isnan(col) & (u > 0)
    sel = np.flatnonzero(present)
    out = val.copy()
    if len(sel):
        z = normals.take(idx[sel], width)
        out[sel] = val[sel] + (u[sel, None] * z if val.ndim == 2 else u[sel] * z[:, 0])
    return out
