"""The estimators' innovation windows in N lanes: :class:`~archself_blocks.estimators.MeanWindow`.

:class:`LaneMeanWindows` is the core's :class:`archself.lanes.windows.LaneWindows` of
vectors: for every lane, the items ``(t, v)`` its per-run window holds in its deque,
dropped by the per-run rule, the running total in the per-run order, so the window
means are the per-run numbers bit for bit. (The per-run total is None before the first
item and after a clear — exactly when ``start`` is None.)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from archself.lanes.windows import LaneWindows

__all__ = ["LaneMeanWindows"]


class LaneMeanWindows(LaneWindows):
    """Sliding-window means of ``width``-vectors over each lane's window.

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
    >>> w.window[:] = 4.0
    >>> for t, v in ((0.0, 1.0), (1.0, -1.0), (2.0, 3.0)):
    ...     w.add(t, np.array([0, 1]), np.array([[v], [2 * v]]))
    >>> w.value(np.array([0, 1])).tolist()
    [[1.0], [2.0]]
    """

    def __init__(self, n: int, width: int, capacity: int = 64) -> None:
        super().__init__(n, width, capacity)

    def value(self, idx: np.ndarray) -> np.ndarray:
        """``MeanWindow.value()`` of lanes ``idx``: ``(len(idx), width)``, NaN rows for None."""
        return self.mean(idx)

    # ------------------------------------------------------------------ per-run bridge
    def load(self, i: int, window: Any) -> None:
        """Lane ``i`` from a per-run ``MeanWindow``."""
        items = list(window.items)
        width = self.v.shape[2]
        v = np.array([b for _, b in items], dtype=float).reshape(len(items), width)
        total = np.zeros(width) if window.total is None else window.total
        self.put(i, [a for a, _ in items], v, total, window.start, window.last, window.window_s)

    def store(self, i: int, window: Any) -> None:
        """Lane ``i`` into a per-run ``MeanWindow``."""
        t, v, total, start, last = self.get(i)
        window.items.clear()
        window.items.extend((a, b.copy()) for a, b in zip(t, v, strict=True))
        window.total = None if start is None else total
        window.start = start
        window.last = last
