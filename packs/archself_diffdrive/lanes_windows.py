"""The innovation windows of the pose estimators in N lanes (ring buffers).

:class:`LaneWindows` holds, for every lane, the items ``(t, ex, ey)`` that a per-run
:class:`~archself_diffdrive.estimators.InnovationWindow` or
:class:`~archself_diffdrive.estimators.InnovationTrend` holds in its deque: a ring
buffer of one capacity for all lanes with a head and a count per lane (doubled when
a lane fills it), so lanes whose fixes differ (dropouts, a window per sweep point)
keep their own items. Adding drops the old items by the per-run rule and keeps the
running sums in the per-run order; the window's value (:meth:`LaneWindows.mean_norm`)
and the trend statistic (:meth:`LaneWindows.trend`, sums over the lanes' items with
the other slots masked) are the per-run numbers to the last bits of a sum's order.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["LaneWindows"]


class LaneWindows:
    """Sliding windows of 2-D innovations in N lanes (ring buffers, a count per lane).

    The lane form of both :class:`~archself_diffdrive.estimators.InnovationWindow`
    (:meth:`mean_norm`, with its running sums, first and last time) and
    :class:`~archself_diffdrive.estimators.InnovationTrend` (:meth:`trend`): the same
    items, dropped by the same rule, the sums accumulated in the same order.

    Parameters
    ----------
    n : int
        Number of lanes.
    capacity : int
        Items per lane before the buffers double.

    Examples
    --------
    >>> w = LaneWindows(2)
    >>> w.window[:] = 4.0
    >>> for t, e in ((0.0, 1.0), (1.0, -1.0), (2.0, 3.0)):
    ...     w.add(t, np.array([0, 1]), np.array([[e, 0.0], [0.0, e]]))
    >>> w.mean_norm(np.array([0, 1])).tolist()
    [1.0, 1.0]
    """

    def __init__(self, n: int, capacity: int = 32) -> None:
        self.window = np.full(n, math.nan)
        self.t = np.zeros((n, capacity))
        self.e = np.zeros((n, capacity, 2))
        self.head = np.zeros(n, dtype=int)
        self.count = np.zeros(n, dtype=int)
        self.sums = np.zeros((n, 2))
        self.start = np.full(n, math.nan)  # NaN: None (no item since the last clear)
        self.last = np.zeros(n)

    def _ordered(self, idx: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
        """The first ``width`` slots of lanes ``idx`` in time order: times and innovations."""
        slots = (self.head[idx, None] + np.arange(width)) % self.t.shape[1]
        return self.t[idx[:, None], slots], self.e[idx[:, None], slots]

    def _grow(self, size: int) -> None:
        cap = self.t.shape[1]
        while cap < size:
            cap *= 2
        every = np.arange(len(self.head))
        t, e = self._ordered(every, self.t.shape[1])
        self.t = np.zeros((len(every), cap))
        self.e = np.zeros((len(every), cap, 2))
        self.t[:, : t.shape[1]] = t
        self.e[:, : e.shape[1]] = e
        self.head[:] = 0

    def add(self, t: float, idx: np.ndarray, e: np.ndarray) -> None:
        """Add innovations ``e`` (``(len(idx), 2)``) observed at ``t`` in lanes ``idx``."""
        count = self.count[idx]
        if (count >= self.t.shape[1]).any():
            self._grow(int(count.max()) + 1)
        cap = self.t.shape[1]
        start = self.start[idx]
        self.start[idx] = np.where(np.isnan(start), t, start)
        self.last[idx] = t
        slot = (self.head[idx] + count) % cap
        self.t[idx, slot] = t
        self.e[idx, slot] = e
        self.count[idx] = count + 1
        self.sums[idx] = self.sums[idx] + e
        cut = t - self.window[idx]
        while True:
            head = self.head[idx]
            old = (self.count[idx] > 0) & (self.t[idx, head] <= cut)
            if not old.any():
                return
            k, h = idx[old], head[old]
            self.sums[k] = self.sums[k] - self.e[k, h]
            self.head[k] = (h + 1) % cap
            self.count[k] -= 1

    def mean_norm(self, idx: np.ndarray) -> np.ndarray:
        """``InnovationWindow.value`` of lanes ``idx``."""
        n = self.count[idx]
        start = self.start[idx]
        early = np.isnan(start) | (n == 0) | (self.last[idx] - start < 0.5 * self.window[idx])
        with np.errstate(divide="ignore", invalid="ignore"):
            s = self.sums[idx]
            value = np.hypot(s[:, 0] / n, s[:, 1] / n)
        return np.where(early, math.nan, value)

    def trend(self, idx: np.ndarray) -> np.ndarray:
        """``InnovationTrend.value`` of lanes ``idx``: ‖slope‖ / its standard error."""
        out = np.full(len(idx), math.nan)
        n = self.count[idx]
        width = int(n.max()) if len(n) else 0
        if width < 5:
            return out
        t, e = self._ordered(idx, width)
        span = t[np.arange(len(idx)), np.maximum(n - 1, 0)] - t[:, 0]
        ok = (n >= 5) & ~(span < 0.5 * self.window[idx])
        if not ok.any():
            return out
        t, e, n = t[ok], e[ok], n[ok]
        valid = np.arange(width) < n[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            tt = np.where(valid, t - (np.where(valid, t, 0.0).sum(1) / n)[:, None], 0.0)
            stt = (tt * tt).sum(1)
            d = np.diff(e, axis=1)
            var = np.where(valid[:, 1:, None], d * d, 0.0).sum((1, 2)) / (2 * (n - 1)) / 2.0
            mean = np.where(valid[:, :, None], e, 0.0).sum(1) / n[:, None]
            dev = np.where(valid[:, :, None], e - mean[:, None], 0.0)
            slope = (tt[:, :, None] * dev).sum(1) / stt[:, None]
            value = np.hypot(slope[:, 0], slope[:, 1]) / np.sqrt(var / stt)
        out[ok] = np.where((stt > 0.0) & (var > 0.0), value, math.nan)
        return out

    # ------------------------------------------------------------------ per-run bridge
    def items(self, i: int) -> list[tuple[float, ...]]:
        """Lane ``i``'s items ``(t, ex, ey)``, oldest first (the per-run deque's)."""
        t, e = self._ordered(np.array([i]), int(self.count[i]))
        return [(a, *b) for a, b in zip(t[0].tolist(), e[0].tolist(), strict=True)]

    def load(self, i: int, window: Any) -> None:
        """Lane ``i`` from a per-run ``InnovationWindow`` or ``InnovationTrend``."""
        items = list(window.items)
        if len(items) > self.t.shape[1]:
            self._grow(len(items))
        self.window[i] = window.window_s
        self.head[i] = 0
        self.count[i] = len(items)
        if items:
            a = np.array(items, dtype=float)
            self.t[i, : len(items)] = a[:, 0]
            self.e[i, : len(items)] = a[:, 1:]
        if hasattr(window, "sx"):
            self.sums[i] = (window.sx, window.sy)
            self.start[i] = math.nan if window.start is None else window.start
            self.last[i] = window.last

    def store(self, i: int, window: Any) -> None:
        """Lane ``i`` into a per-run ``InnovationWindow`` or ``InnovationTrend``."""
        window.items.clear()
        window.items.extend(self.items(i))
        if hasattr(window, "sx"):
            window.sx, window.sy = (float(s) for s in self.sums[i])
            start = float(self.start[i])
            window.start = None if math.isnan(start) else start
            window.last = float(self.last[i])
