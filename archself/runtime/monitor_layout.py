"""What the Monitor precomputes for one set of active modules, and its residual filters' state.

:class:`Layout` is rebuilt by :meth:`archself.runtime.monitor.Monitor.layout` when
the active set changes (carrying the filter state over): the active residual
modules' slots, sensitivities, nominal levels, time constants and trust times, the
``requires``/``excludes`` findings, and the filter values as compact arrays.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from archself.runtime.residuals import filter_confidence, filter_gain, to_float

if TYPE_CHECKING:
    from archself.runtime.monitor import Monitor

__all__ = ["Layout", "as_floats", "confidence_reader"]


def as_floats(values: list[Any]) -> np.ndarray:
    """``[to_float(v) for v in values]`` as a float array; one numpy call for plain numbers."""
    try:
        a = np.array(values)
    except (TypeError, ValueError):
        a = None
    if a is not None and a.ndim == 1 and a.dtype.kind in "fiub":
        return a.astype(float, copy=False)
    return np.array([to_float(v) for v in values], dtype=float)


def confidence_reader(lay: Layout) -> Callable[[int], float]:
    """κ_i's confidence of module ``k`` from ``lay``'s residual filters as they are now."""
    samples, valid_time, tc, slot = lay.samples, lay.valid_time, lay.time_constant, lay.slot

    def confidence(k: int) -> float:
        j = int(slot[k])
        if j < 0:
            return 1.0 if j == -1 else 0.0  # no residual block / filter reset
        return filter_confidence(int(samples[j]), float(valid_time[j]), float(tc[j]))

    return confidence


class Layout:
    """What the Monitor precomputes for one set of active modules, and its filter state.

    The residual filters of the active modules are held here in compact arrays
    (one entry per active module with a ``residual`` block), replaced by new
    arrays at every update so that an :class:`Observation` can keep them.
    """

    def __init__(self, monitor: Monitor, active: frozenset[str]) -> None:
        names = monitor.names
        n = len(names)
        self.key = active
        self.active = np.fromiter((m in active for m in names), dtype=bool, count=n)
        on = self.active[monitor.res_pos]
        self.res_on = np.flatnonzero(on)  # residual slots of the active modules
        self.res_off = np.flatnonzero(~on)
        self.on_pos = monitor.res_pos[self.res_on]  # their positions in names
        self.on_names = [names[k] for k in self.on_pos.tolist()]
        self.pairs = [
            (names[k], monitor.res_signal[j])
            for j, k in zip(self.res_on.tolist(), self.on_pos.tolist(), strict=True)
        ]
        self.sensitivity = monitor.sensitivity[self.res_on]
        self.nominal = monitor.nominal[self.res_on]
        self.time_constant = monitor.time_constant[self.res_on]
        self.instant = self.time_constant <= 0
        self.any_instant = bool(self.instant.any())
        self.tc_slot = monitor.tc_slot[self.res_on]
        self.all_ok = np.ones(self.res_on.size, dtype=bool)  # shared, never written
        # position in names -> -1 (no residual block), -2 (inactive), else compact slot
        self.slot = np.full(n, -1, dtype=np.intp)
        self.slot[monitor.res_pos] = -2
        self.slot[self.on_pos] = np.arange(self.res_on.size, dtype=np.intp)
        # filter state: the inactive filters restart from 0 (a reset), the others go on
        monitor.value[self.res_off] = 0.0
        monitor.valid_time[self.res_off] = 0.0
        monitor.samples[self.res_off] = 0
        self.trust_time = monitor.trust_time[self.res_on]
        self.value = monitor.value[self.res_on]
        self.valid_time = monitor.valid_time[self.res_on]
        self.samples = monitor.samples[self.res_on]
        self._gain_dt: float | None = None
        self._gain = np.ones(self.res_on.size)
        # requires/excludes depend on the active set only; limits are read every cycle
        self.constrained: list[tuple[int, str, list[str], Mapping[str, Any]]] = []
        for k, name in monitor.constrained:
            if name not in active:
                continue
            cons = monitor.arch.modules[name].constraints
            fixed = [f"requires {m} (inactive)" for m in cons.requires if m not in active]
            fixed += [f"excludes {m} (active)" for m in cons.excludes if m in active]
            self.constrained.append((k, name, fixed, cons.limits))

    def store(self, monitor: Monitor) -> None:
        """Write the filter state back to the Monitor's arrays (before a new layout)."""
        monitor.value[self.res_on] = self.value
        monitor.valid_time[self.res_on] = self.valid_time
        monitor.samples[self.res_on] = self.samples

    def gains(self, monitor: Monitor, dt: float) -> np.ndarray:
        """:func:`filter_gain` of every active filter for the sampling interval ``dt``."""
        if dt != self._gain_dt:
            per_tc = np.array([filter_gain(dt, tc) for tc in monitor.tc_values], dtype=float)
            self._gain = per_tc[self.tc_slot]
            self._gain_dt = dt
        return self._gain
