"""The innovation windows of the pose estimators in N lanes.

:class:`LaneWindows` is the core's :class:`archself.lanes.windows.LaneWindows` of 2-D
innovations ``(ex, ey)``: the items a per-run
:class:`~archself_diffdrive.estimators.InnovationWindow` or
:class:`~archself_diffdrive.estimators.InnovationTrend` holds in its deque, dropped by
the same rule, the sums in the same order. The window's value (:meth:`LaneWindows.mean_norm`)
and the trend statistic (:meth:`LaneWindows.trend`, sums over the lanes' items with the
other slots masked) are the per-run numbers to the last bits of a sum's order.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.lanes.windows import LaneWindows as _Windows

__all__ = ["LaneWindows"]


class LaneWindows(_Windows):
    """Sliding windows of 2-D innovations in N lanes (ring buffers, a count per lane).

    The lane form of both :class:`~archself_diffdrive.estimators.InnovationWindow`
    (:meth:`mean_norm`, with its running sums, first and last time) and
    :class:`~archself_diffdrive.estimators.InnovationTrend` (:meth:`trend`).

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
        super().__init__(n, 2, capacity)

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
        t, e = self.ordered(idx, width)
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
    def load(self, i: int, window: Any) -> None:
        """Lane ``i`` from a per-run ``InnovationWindow`` or ``InnovationTrend``."""
        items = np.array(list(window.items), dtype=float).reshape(-1, 3)
        if hasattr(window, "sx"):
            self.put(i, items[:, 0].tolist(), items[:, 1:], np.array([window.sx, window.sy]),
                     window.start, window.last, window.window_s)
        else:  # the trend keeps no sums
            self.put(i, items[:, 0].tolist(), items[:, 1:], self.sums[i], None, self.last[i],
                     window.window_s)

    def store(self, i: int, window: Any) -> None:
        """Lane ``i`` into a per-run ``InnovationWindow`` or ``InnovationTrend``."""
        t, v, sums, start, last = self.get(i)
        rows = [(a, *b) for a, b in zip(t, v.tolist(), strict=True)]
        if not hasattr(window, "sx"):  # the trend
            window.items = rows
        else:
            window.items.clear()
            window.items.extend(rows)
            window.sx, window.sy = (float(x) for x in sums)
            window.start = start
            window.last = last
