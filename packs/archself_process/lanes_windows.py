"""The observer's innovation window in N lanes (a ring buffer per lane).

:class:`LaneMeans` holds, for every lane, the items ``(t, v)`` that a per-run
:class:`~archself_process.tank.MeanWindow` holds in its deque, with its running total,
first and last time: one buffer capacity for all lanes with a head and a count per lane,
so lanes that add at other times (absent readings, a boosted start, a window per sweep
point) keep their own items, dropped by the per-run rule with the total kept in the
per-run order — the window's mean is the per-run float.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["LaneMeans"]


class LaneMeans:
    """Sliding-window means of a scalar in N lanes: :class:`~archself_process.tank.MeanWindow`.

    A ring buffer of one capacity for all lanes with a head and a count per lane
    (doubled when a lane fills it), so lanes that add at other times keep their own
    items. Adding drops the old items by the per-run rule and keeps the running total
    in the per-run order.

    Parameters
    ----------
    n : int
        Number of lanes.
    capacity : int
        Items per lane before the buffers double.

    Examples
    --------
    >>> w = LaneMeans(2)
    >>> w.window[:] = 4.0
    >>> both = np.array([0, 1])
    >>> for t, v in [(0.0, 1.0), (1.0, -1.0), (2.0, 3.0)]:
    ...     w.add(t, both, np.array([v, 2 * v]))
    >>> w.value(both).tolist()
    [1.0, 2.0]
    """

    def __init__(self, n: int, capacity: int = 64) -> None:
        self.window = np.full(n, math.nan)
        self.t = np.zeros((n, capacity))
        self.v = np.zeros((n, capacity))
        self.head = np.zeros(n, dtype=np.intp)
        self.count = np.zeros(n, dtype=np.intp)
        self.total = np.zeros(n)
        self.start = np.full(n, math.nan)  # NaN: None (no item since the last clear)
        self.last = np.zeros(n)

    def _ordered(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Lane ``i``'s items in time order: times and values."""
        slots = (self.head[i] + np.arange(self.count[i])) % self.t.shape[1]
        return self.t[i, slots], self.v[i, slots]

    def _grow(self, size: int) -> None:
        cap = self.t.shape[1]
        while cap < size:
            cap *= 2
        slots = (self.head[:, None] + np.arange(self.t.shape[1])) % self.t.shape[1]
        rows = np.arange(len(self.head))[:, None]
        t, v = self.t[rows, slots], self.v[rows, slots]
        self.t = np.zeros((len(rows), cap))
        self.v = np.zeros((len(rows), cap))
        self.t[:, : t.shape[1]] = t
        self.v[:, : v.shape[1]] = v
        self.head[:] = 0

    def add(self, t: float, idx: np.ndarray, v: np.ndarray) -> None:
        """Add the values ``v`` observed at ``t`` in lanes ``idx`` (``MeanWindow.add``)."""
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
        count = count + 1
        total = self.total[idx] + v
        head = self.head[idx]
        cut = t - self.window[idx]
        while True:  # drop the items at or before t − window, oldest first
            old = (count > 0) & (self.t[idx, head] <= cut)
            if not old.any():
                break
            total = np.where(old, total - self.v[idx, head], total)
            head = np.where(old, (head + 1) % cap, head)
            count = count - old
        self.count[idx] = count
        self.head[idx] = head
        self.total[idx] = total

    def value(self, idx: np.ndarray) -> np.ndarray:
        """``MeanWindow.value`` of lanes ``idx``: NaN until the items span half the window."""
        n = self.count[idx]
        start = self.start[idx]
        early = np.isnan(start) | (n == 0) | (self.last[idx] - start < 0.5 * self.window[idx])
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = self.total[idx] / n
        return np.where(early, math.nan, mean)

    # ------------------------------------------------------------------ per-run bridge
    def load(self, i: int, window: Any) -> None:
        """Lane ``i`` from a per-run ``MeanWindow``."""
        items = list(window.items)
        if len(items) > self.t.shape[1]:
            self._grow(len(items))
        self.window[i] = window.window_s
        self.head[i] = 0
        self.count[i] = len(items)
        if items:
            a = np.array(items, dtype=float)
            self.t[i, : len(items)] = a[:, 0]
            self.v[i, : len(items)] = a[:, 1]
        self.total[i] = window.total
        self.start[i] = math.nan if window.start is None else window.start
        self.last[i] = window.last

    def store(self, i: int, window: Any) -> None:
        """Lane ``i`` into a per-run ``MeanWindow``."""
        t, v = self._ordered(i)
        window.items.clear()
        window.items.extend(zip(t.tolist(), v.tolist(), strict=True))
        window.total = float(self.total[i])
        start = float(self.start[i])
        window.start = None if math.isnan(start) else start
        window.last = float(self.last[i])
