"""Sliding windows in N lanes: the lane form of a per-run deque with running sums.

A windowed residual (a mean innovation over the last W seconds) keeps, per run, a deque
of ``(t, value)`` items, a running sum and its first and last time. :class:`LaneWindows`
holds that for N lanes at once: one ring buffer capacity for all lanes with a head and a
count per lane (doubled when a lane fills it), so lanes that add at other times (absent
readings, dropouts, a window per sweep point) keep their own items. Adding drops the old
items by the per-run rule (``t_item ≤ t − window``) and keeps the sum in the per-run
order — plus the new value, then minus each dropped one, oldest first — so the window's
mean is the per-run float. The packs' batched estimators build on it (their per-run
windows differ only in how the value is read out: the bridge is theirs).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["LaneWindows"]


class LaneWindows:
    """Sliding windows of ``width``-vectors in N lanes: ring buffers with running sums.

    Parameters
    ----------
    n : int
        Number of lanes.
    width : int
        Numbers per item.
    capacity : int
        Items per lane before the buffers double.
    diffs : bool
        Also keep ``steps``, the sum of the squared differences of consecutive items
        (the noise estimate of :meth:`t_value`).

    Attributes
    ----------
    window : (n,) array
        Each lane's window length (s); NaN until set.
    sums : (n, width) array
        The running sum of each lane's items.
    start, last : (n,) arrays
        The time of the first item since the last clear (NaN: none) and of the last one.
    steps : (n, width) array
        With ``diffs``: Σ (v_k − v_{k−1})² over each lane's consecutive items.

    Examples
    --------
    >>> w = LaneWindows(2)
    >>> w.window[:] = 4.0
    >>> both = np.array([0, 1])
    >>> for t, v in ((0.0, 1.0), (1.0, -1.0), (2.0, 3.0)):
    ...     w.add(t, both, np.array([[v], [2 * v]]))
    >>> w.mean(both).tolist()
    [[1.0], [2.0]]
    """

    def __init__(self, n: int, width: int = 1, capacity: int = 32, diffs: bool = False
                 ) -> None:
        self.diffs = diffs
        self.steps = np.zeros((n, width))
        self.window = np.full(n, math.nan)
        self.t = np.zeros((n, capacity))
        self.v = np.zeros((n, capacity, width))
        self.head = np.zeros(n, dtype=np.intp)
        self.count = np.zeros(n, dtype=np.intp)
        self.sums = np.zeros((n, width))
        self.start = np.full(n, math.nan)
        self.last = np.zeros(n)

    def ordered(self, idx: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
        """The first ``size`` slots of lanes ``idx`` in time order: times and items."""
        slots = (self.head[idx, None] + np.arange(size)) % self.t.shape[1]
        return self.t[idx[:, None], slots], self.v[idx[:, None], slots]

    def _grow(self, size: int) -> None:
        cap = self.t.shape[1]
        while cap < size:
            cap *= 2
        t, v = self.ordered(np.arange(len(self.head)), self.t.shape[1])
        self.t = np.zeros((len(self.head), cap))
        self.v = np.zeros((len(self.head), cap, self.v.shape[2]))
        self.t[:, : t.shape[1]] = t
        self.v[:, : v.shape[1]] = v
        self.head[:] = 0

    def add(self, t: float, idx: np.ndarray, v: np.ndarray) -> None:
        """Add items ``v`` (``(len(idx), width)``) observed at ``t`` in lanes ``idx``."""
        count = self.count[idx]
        if (count >= self.t.shape[1]).any():
            self._grow(int(count.max()) + 1)
        cap = self.t.shape[1]
        start = self.start[idx]
        self.start[idx] = np.where(np.isnan(start), t, start)
        self.last[idx] = t
        head = self.head[idx]
        if self.diffs:  # (v − the last item)² where there is one, in the per-run order
            step = v - self.v[idx, (head + count - 1) % cap]
            steps = np.where((count > 0)[:, None], self.steps[idx] + step * step,
                             self.steps[idx])
        self.t[idx, (head + count) % cap] = t
        self.v[idx, (head + count) % cap] = v
        count = count + 1
        sums = self.sums[idx] + v
        cut = t - self.window[idx]
        old = self.t[idx, head] <= cut  # (the new item is never dropped: window > 0)
        while old.any():
            gone = self.v[idx, head]
            sums = np.where(old[:, None], sums - gone, sums)
            head = np.where(old, (head + 1) % cap, head)
            count = count - old
            if self.diffs:
                step = self.v[idx, head] - gone
                steps = np.where((old & (count > 0))[:, None], steps - step * step, steps)
            old = (count > 0) & (self.t[idx, head] <= cut)
        self.head[idx] = head
        self.count[idx] = count
        self.sums[idx] = sums
        if self.diffs:
            self.steps[idx] = steps

    def mean(self, idx: np.ndarray) -> np.ndarray:
        """The mean item of lanes ``idx``, ``(len(idx), width)``; NaN rows until the items
        span half the window."""
        n = self.count[idx]
        start = self.start[idx]
        early = np.isnan(start) | (n == 0) | (self.last[idx] - start < 0.5 * self.window[idx])
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = self.sums[idx] / n[:, None]
        mean[early] = math.nan
        return mean

    def t_value(self, idx: np.ndarray) -> np.ndarray:
        """|mean| over its standard error, per lane and number (``diffs`` needed): the noise
        σ̂² = steps / (2 (n − 1)); NaN where :meth:`mean` is or without noise."""
        n = self.count[idx][:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            var = np.where(n > 1, self.steps[idx] / (2.0 * (n - 1)), 0.0)
            z = np.abs(self.mean(idx)) / np.sqrt(var / n)
        return np.where(var > 0.0, z, math.nan)

    def clear(self, idx: np.ndarray) -> None:
        """Forget the items of lanes ``idx`` (``last`` stays, as per run)."""
        self.count[idx] = 0
        self.sums[idx] = 0.0
        self.steps[idx] = 0.0
        self.start[idx] = math.nan

    # ------------------------------------------------------------------ per-run bridge
    def put(self, i: int, t: list[float], v: np.ndarray, sums: np.ndarray, start: float | None,
            last: float, window: float, steps: np.ndarray | float = 0.0) -> None:
        """Set lane ``i``: its items' times ``t`` and values ``v`` (``(len(t), width)``),
        oldest first, running sum, first and last time (``start`` None: no item), window
        and (``diffs``) the sum of squared steps."""
        if len(t) > self.t.shape[1]:
            self._grow(len(t))
        self.window[i] = window
        self.head[i] = 0
        self.count[i] = len(t)
        self.t[i, : len(t)] = t
        self.v[i, : len(t)] = np.reshape(v, (len(t), self.v.shape[2]))
        self.sums[i] = sums
        self.steps[i] = steps
        self.start[i] = math.nan if start is None else start
        self.last[i] = last

    def get(self, i: int) -> tuple[list[float], np.ndarray, np.ndarray, float | None, float]:
        """Lane ``i``'s ``(t, v, sums, start, last)`` as :meth:`put` takes them."""
        t, v = self.ordered(np.array([i]), int(self.count[i]))
        start = float(self.start[i])
        return (t[0].tolist(), v[0], self.sums[i].copy(), None if math.isnan(start) else start,
                float(self.last[i]))
