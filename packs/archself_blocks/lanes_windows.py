"""The estimators' innovation windows in N lanes: :class:`~archself_blocks.estimators.MeanWindow`.

:class:`LaneMeanWindows` holds, for every lane, the items ``(t, v)`` its per-run
window holds in its deque, in a ring buffer with a head and a count per lane (the
buffers double when a lane fills them), and the running total in the per-run
order (the first item's copy, then ``+ v`` per item added and ``− v`` per item
dropped), so the window means are the per-run numbers bit for bit.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["LaneMeanWindows"]


class LaneMeanWindows:
    """Sliding-window means of ``width``-vectors over each lane's ``window_s`` seconds.

    Parameters
    ----------
    n : int
        Number of lanes.
    width : int
        Length of the vectors.
    capacity : int
        Items per lane before the buffers double.

    Examples
    --------
    >>> w = LaneMeanWindows(2, 1)
    >>> w.window_s[:] = 4.0
    >>> for t, v in ((0.0, 1.0), (1.0, -1.0), (2.0, 3.0)):
    ...     w.add(t, np.array([0, 1]), np.array([[v], [2 * v]]))
    >>> w.value(np.array([0, 1])).tolist()
    [[1.0], [2.0]]
    """

    def __init__(self, n: int, width: int, capacity: int = 64) -> None:
        self.window_s = np.full(n, 10.0)
        self.t = np.zeros((n, capacity))
        self.v = np.zeros((n, capacity, width))
        self.head = np.zeros(n, dtype=np.intp)
        self.count = np.zeros(n, dtype=np.intp)
        self.total = np.zeros((n, width))
        self.has_total = np.zeros(n, dtype=bool)  # False: the per-run total is None
        self.start = np.full(n, math.nan)  # NaN: None
        self.last = np.zeros(n)

    def _ordered(self, idx: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
        """The first ``size`` items of lanes ``idx`` in time order: times and vectors."""
        slots = (self.head[idx, None] + np.arange(size)) % self.t.shape[1]
        return self.t[idx[:, None], slots], self.v[idx[:, None], slots]

    def _grow(self, size: int) -> None:
        cap = self.t.shape[1]
        while cap < size:
            cap *= 2
        every = np.arange(len(self.head))
        t, v = self._ordered(every, self.t.shape[1])
        self.t = np.zeros((len(every), cap))
        self.v = np.zeros((len(every), cap, self.v.shape[2]))
        self.t[:, : t.shape[1]] = t
        self.v[:, : v.shape[1]] = v
        self.head[:] = 0

    def add(self, t: float, idx: np.ndarray, v: np.ndarray) -> None:
        """``MeanWindow.add(t, v)`` in lanes ``idx`` (``v``: one row per lane)."""
        count = self.count[idx]
        if (count >= self.t.shape[1]).any():
            self._grow(int(count.max()) + 1)
        cap = self.t.shape[1]
        start = self.start[idx]
        self.start[idx] = np.where(np.isnan(start), t, start)
        self.last[idx] = t
        slot = (self.head[idx] + count) % cap
        self.t[idx, slot] = t
        self.v[idx, slot] = v
        self.count[idx] = count + 1
        had = self.has_total[idx]
        self.total[idx] = np.where(had[:, None], self.total[idx] + v, v)
        self.has_total[idx] = True
        cut = t - self.window_s[idx]
        while True:
            head = self.head[idx]
            old = (self.count[idx] > 0) & (self.t[idx, head] <= cut)
            if not old.any():
                return
            k, h = idx[old], head[old]
            self.total[k] = self.total[k] - self.v[k, h]
            self.head[k] = (h + 1) % cap
            self.count[k] -= 1

    def value(self, idx: np.ndarray) -> np.ndarray:
        """``MeanWindow.value()`` of lanes ``idx``: ``(len(idx), width)``, NaN rows for None."""
        start = self.start[idx]
        early = (~self.has_total[idx] | np.isnan(start)
                 | (self.last[idx] - start < 0.5 * self.window_s[idx]))
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = self.total[idx] / self.count[idx][:, None]
        mean[early] = math.nan
        return mean

    def clear(self, idx: np.ndarray) -> None:
        """``MeanWindow.clear()`` in lanes ``idx`` (``last`` stays, as per run)."""
        self.count[idx] = 0
        self.has_total[idx] = False
        self.start[idx] = math.nan

    # ------------------------------------------------------------------ per-run bridge
    def load(self, i: int, window: Any) -> None:
        """Lane ``i`` from a per-run ``MeanWindow``."""
        items = list(window.items)
        if len(items) > self.t.shape[1]:
            self._grow(len(items))
        self.window_s[i] = window.window_s
        self.head[i] = 0
        self.count[i] = len(items)
        for j, (t, v) in enumerate(items):
            self.t[i, j] = t
            self.v[i, j] = v
        self.has_total[i] = window.total is not None
        if window.total is not None:
            self.total[i] = window.total
        self.start[i] = math.nan if window.start is None else window.start
        self.last[i] = window.last

    def store(self, i: int, window: Any) -> None:
        """Lane ``i`` into a per-run ``MeanWindow``."""
        t, v = self._ordered(np.array([i]), int(self.count[i]))
        window.items.clear()
        window.items.extend((a, b.copy()) for a, b in zip(t[0].tolist(), v[0], strict=True))
        window.total = self.total[i].copy() if self.has_total[i] else None
        start = float(self.start[i])
        window.start = None if math.isnan(start) else start
        window.last = float(self.last[i])
