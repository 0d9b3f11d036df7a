"""The observer's innovation window in N lanes.

:class:`LaneMeans` is the core's :class:`archself.lanes.windows.LaneWindows` of scalars:
for every lane, the items ``(t, v)`` that a per-run :class:`~archself_process.tank.MeanWindow`
holds in its deque, dropped by the per-run rule with the running total kept in the
per-run order — the window's mean is the per-run float.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from archself.lanes.windows import LaneWindows

__all__ = ["LaneMeans"]


class LaneMeans(LaneWindows):
    """Sliding-window means (and t-values) of a scalar in N lanes: ``MeanWindow``.

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
    >>> w.value(both).tolist(), w.t_values(both).round(3).tolist()
    ([1.0, 2.0], [0.775, 0.775])
    """

    def __init__(self, n: int, capacity: int = 64) -> None:
        super().__init__(n, 1, capacity, diffs=True)

    def add(self, t: float, idx: np.ndarray, v: np.ndarray) -> None:
        """Add the values ``v`` (``(len(idx),)``) observed at ``t`` in lanes ``idx``."""
        super().add(t, idx, np.asarray(v)[:, None])

    def value(self, idx: np.ndarray) -> np.ndarray:
        """``MeanWindow.value`` of lanes ``idx``: NaN until the items span half the window."""
        return self.mean(idx)[:, 0]

    def t_values(self, idx: np.ndarray) -> np.ndarray:
        """``MeanWindow.t_value`` of lanes ``idx``."""
        return self.t_value(idx)[:, 0]

    # ------------------------------------------------------------------ per-run bridge
    def load(self, i: int, window: Any) -> None:
        """Lane ``i`` from a per-run ``MeanWindow``."""
        items = np.array(list(window.items), dtype=float).reshape(-1, 2)
        self.put(i, items[:, 0].tolist(), items[:, 1:], np.array([window.total]), window.start,
                 window.last, window.window_s, window.steps)

    def store(self, i: int, window: Any) -> None:
        """Lane ``i`` into a per-run ``MeanWindow``."""
        t, v, total, start, last = self.get(i)
        window.items.clear()
        window.items.extend(zip(t, v[:, 0].tolist(), strict=True))
        window.total = float(total[0])
        window.steps = float(self.steps[i, 0])
        window.start = start
        window.last = last
