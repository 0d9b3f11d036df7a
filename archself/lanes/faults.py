"""A scenario's fault in every lane: one :class:`~archself.system.live.FaultInjector` per lane.

The kinds whose value depends only on time and the fault's numbers (``bias_drift``,
``bias``, ``effectiveness_loss``, ``dropout``) act on all lanes with array
operations; the others (``noise_increase`` with each lane's own stream, ``stuck``
with each lane's held value, ``nan``) go lane by lane through the lane's own
injector, so each lane sees exactly its per-run fault.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from archself.lanes.module import row

__all__ = ["LaneFault"]

#: Fault kinds applied to all lanes at once; the others go lane by lane.
VECTOR_KINDS = frozenset({"bias_drift", "bias", "effectiveness_loss", "dropout"})
_NONE = np.zeros(0, dtype=np.intp)


class LaneFault:
    """One fault of a scenario in N lanes.

    Parameters
    ----------
    signal : str
        The output signal it acts on.
    injectors : sequence of FaultInjector
        One per lane (their onsets and sizes may differ: sweep points).
    """

    def __init__(self, signal: str, injectors: Sequence[Any]) -> None:
        self.signal = signal
        self.injectors = list(injectors)
        first = self.injectors[0]
        self.kind = first.kind
        self.vector = first.kind in VECTOR_KINDS and all(
            i.kind == first.kind for i in self.injectors
        )
        self.onset = np.array([i.onset for i in self.injectors])
        self.end = np.array([i.end for i in self.injectors])
        self.magnitude = np.array([i.magnitude for i in self.injectors])

    def apply(self, t: float, value: Any, idx: np.ndarray) -> tuple[Any, np.ndarray]:
        """The faulty value of lanes ``idx`` at ``t`` and the lanes it made non-finite."""
        if type(value) is list:
            return value, _NONE
        if self.vector:
            return self._vector(t, value, idx), _NONE
        return self._one_by_one(t, value, idx)

    def _vector(self, t: float, value: Any, idx: np.ndarray) -> Any:
        onset = self.onset[idx]
        active = (onset <= t + 1e-9) & (t < self.end[idx] - 1e-9)
        if value is None or not active.any():
            return value
        out = np.array(value, dtype=float)
        kind = self.kind
        if kind == "dropout":
            out[active] = math.nan
            return None if np.isnan(out).all() else out
        mag = self.magnitude[idx][active]
        if kind == "bias_drift":
            add = mag * (t - onset[active])
            out[active] = out[active] + (add if out.ndim == 1 else add[:, None])
        elif kind == "bias":
            out[active] = out[active] + (mag if out.ndim == 1 else mag[:, None])
        else:  # effectiveness_loss
            f = 1.0 - mag
            out[active] = out[active] * (f if out.ndim == 1 else f[:, None])
        return out

    def _one_by_one(self, t: float, value: Any, idx: np.ndarray) -> tuple[Any, np.ndarray]:
        out = None if value is None else np.array(value, dtype=float)
        bad = []
        for j, i in enumerate(idx.tolist()):
            after = self.injectors[i].apply(t, row(value, j))
            arr = math.nan if after is None else np.asarray(after, dtype=float)
            if after is not None and not np.isfinite(arr).all():
                bad.append(i)
            elif out is not None:  # (no value before: none after, for these kinds)
                out[j] = arr
        return out, np.array(bad, dtype=np.intp)
