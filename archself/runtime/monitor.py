"""Monitor stage of Algorithm 1: J_obs, the residuals r and r_i, the status κ_i.

- Global residual (Eq. 11): ``r = J_ref − J_obs`` with ``J_obs`` =
  ``system.objective_error()`` and ``J_ref`` = ``runtime.objective.acceptable``.
  Negative ``r`` means performance is worse than acceptable.
- Module residuals (Eq. 12): ``r_i = (∂J/∂θ_i)·δθ_i``. The deviation δθ_i is
  approximated by the local signal the module declares (``residual.signal``),
  passed through a first-order low-pass filter with time constant
  ``residual.smoothing_s`` sampled at the MAPE-K period, and scaled by the
  sensitivity ``∂J/∂θ_i`` (``residual.sensitivity``). With
  ``runtime.normalization``:

  - ``nominal``: ``r_i = sensitivity · max(0, |s̄| − nominal) / nominal``, the
    excess of the filtered signal over its nominal noise level, in units of that
    level (so that channels of different physical units are comparable and a
    healthy module gives 0);
  - ``none``: ``r_i = sensitivity · |s̄|``.

  Inactive modules, modules without a ``residual`` block and modules whose signal
  is missing or not finite contribute ``r_i = 0``; the last are flagged in κ_i.
- Trust (a warm-up from statistics, per module): a residual counts only once its
  filter has settled, ``confidence = 1 − exp(−t_valid/T) ≥
  runtime.min_confidence`` (t_valid: time with usable samples since the filter
  last started); before that ``r_i = 0``. A module that becomes active starts a
  new filter, so it is trusted again only after it has settled. Exception
  (``runtime.trust_at_start``, off by default): a filter running since the run's
  first cycle counts from its first sample. Started at 0 (the healthy residual),
  after n samples it holds ``c_n·μ`` plus noise of variance ``≤`` the settled one
  (``c_n = 1 − (1 − g)^n ≤ 1``), so a healthy module crosses its band — a bound on
  the *settled* filter — no more often than later in the run, while a fault present
  from t = 0 shows as soon as it lifts the filter over the band. A filter restarted by
  a switch still waits: what it filters then is a hand-over transient, which the band
  does not cover.
- Unavailable modules (Eq. 12 with a total deviation): an active module the
  system reports unavailable for a reason of its own (it raised, gave NaN, fell
  silent or froze; not ``lost input``, which is an upstream failure) gets the
  saturated residual ``r_sat`` (:func:`unavailable_residual`), with or without a
  ``residual`` block. It is thereby a candidate, and the actions keyed to it
  (e.g. a fallback to a configuration that does not need it) are evaluated. The
  reason comes from ``system.health()``; a system without it (or without a
  reason for the module) leaves ``r_i = 0`` and unavailability only blocks
  target configurations in the Planner.
- Status indicators κ_i (:class:`ModuleStatus`): availability as the system
  reports it, whether the residual signal was usable, a confidence in [0, 1]
  (how settled the residual filter is) and violated module constraints.
- Cost per cycle (10^4 modules in a few ms): the residual filters live in numpy
  arrays over the residual-carrying modules and are updated together; κ_i is a
  :class:`StatusMap` that builds a :class:`ModuleStatus` only when one is looked
  up (the decision log looks up the modules with a finding); what depends only on
  the active set is computed once per set. The numbers are those of
  the first-written one-module filter and :func:`module_residual` exactly
  (tests/test_runtime_monitor.py keeps that reference).

The file holds the Monitor's whole concept, in this order: κ_i (the status
indicators of Eq. 17: :class:`ModuleStatus` is one module's κ, :class:`StatusMap`
κ of every module over the Monitor's arrays; :func:`limit_violations` judges a
module's declared ``max_<signal>`` / ``min_<signal>`` limits against its signals,
:func:`is_limit_violation` tells those lines from ``requires``/``excludes`` ones),
the residual maths of one module (Eq. 12: filter gain, r_i, r_sat, the trust of a
filter, as pure functions) and the per-active-set arrays (:class:`Layout`) with the
:class:`Monitor` that does the same arithmetic over arrays of modules, operation for
operation.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from archself.contracts import ManagedSystem
from archself.model.architecture import Architecture

__all__ = [
    "MAX_RESIDUAL",
    "ModuleStatus",
    "Monitor",
    "Observation",
    "StatusMap",
    "filter_confidence",
    "filter_gain",
    "is_limit_violation",
    "is_own_failure",
    "limit_violations",
    "module_residual",
    "to_float",
    "unavailable_residual",
]

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
        # trust at start: a filter running since the run's first layout needs no settling
        if monitor._layout is None and monitor.trust_at_start:
            monitor.from_start[self.res_on] = True
        monitor.from_start[self.res_off] = False
        self.trust_time = np.where(monitor.from_start[self.res_on], 0.0,
                                   monitor.trust_time[self.res_on])
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


def _reported(system: ManagedSystem, method: str) -> Any:
    """``system.<method>()``; {} if the system lacks the method, it gives None or it fails."""
    try:
        return getattr(system, method)() or {}
    except Exception:  # noqa: BLE001 - a failing report must not stop the loop
        return {}


def _violations(
    system: ManagedSystem, local: Mapping[str, Any], lay: Layout
) -> dict[str, list[str]]:
    """The constraint violations of the active modules, by module."""
    violations: dict[str, list[str]] = {}
    outputs = getattr(system, "outputs", None) or {}
    for _k, name, fixed, limits in lay.constrained:
        found = list(fixed)
        if limits:
            found += limit_violations(limits, local.get(name) or {}, outputs.get(name))
        if found:
            violations[name] = found
    return violations


@dataclass
class Observation:
    """Everything the Monitor stage measured in one cycle.

    Attributes
    ----------
    t, j_obs, j_ref, r_global : float
        Time, J_obs, J_ref and the global residual (Eq. 11).
    r : numpy.ndarray
        Module residuals r_i (Eq. 12) in index order.
    kappa : StatusMap
        κ_i of every module.
    signals : dict
        Filtered residual signal of each active module with a ``residual``
        block (None when the sample was unusable), in index order.
    """

    t: float
    j_obs: float
    j_ref: float
    r_global: float
    r: np.ndarray
    kappa: StatusMap
    signal_names: list[str] = field(default_factory=list, repr=False)
    signal_values: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    signal_ok: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool), repr=False)

    @property
    def signals(self) -> dict[str, float | None]:
        """name -> filtered residual signal, None where the sample was unusable."""
        return {
            n: (v if ok else None)
            for n, v, ok in zip(
                self.signal_names, self.signal_values.tolist(), self.signal_ok.tolist(), strict=True
            )
        }


class Monitor:
    """Monitor stage: residual filters per module and the κ_i indicators.

    The filters of all modules with a ``residual`` block are held in numpy arrays
    (value, valid time, sample count) and updated together; κ_i is a
    :class:`StatusMap`. What depends only on the set of active modules
    (which filters run, the ``requires``/``excludes`` checks) is computed once
    per set. The arithmetic is that of one filter per module and
    :func:`module_residual`, operation for operation, so the numbers are the same.

    Parameters
    ----------
    arch : Architecture
        The architecture (reads ``modules.*.residual``, ``runtime``).
    names : list of str
        Index order of the residual vector.
    """

    def __init__(self, arch: Architecture, names: list[str]) -> None:
        self.arch = arch
        self.names = list(names)
        self.index = {n: k for k, n in enumerate(self.names)}
        self.normalization = arch.runtime.normalization
        res = [
            (k, spec)
            for k, name in enumerate(self.names)
            if (spec := arch.modules[name].residual) is not None
        ]
        self.res_pos = np.array([k for k, _ in res], dtype=np.intp)
        self.res_signal = [spec.signal for _, spec in res]
        self.time_constant = np.array([float(spec.smoothing_s) for _, spec in res], dtype=float)
        self.sensitivity = np.array([float(spec.sensitivity) for _, spec in res], dtype=float)
        self.nominal = np.array([float(spec.nominal) for _, spec in res], dtype=float)
        tc_values, self.tc_slot = np.unique(self.time_constant, return_inverse=True)
        self.tc_values: list[float] = tc_values.tolist()
        # filter state of every residual-carrying module (see Layout for the active ones)
        self.value = np.zeros(len(res))
        self.valid_time = np.zeros(len(res))
        self.samples = np.zeros(len(res), dtype=np.int64)
        # trust: valid time a filter needs before its residual counts (min_confidence)
        c_min = float(arch.runtime.min_confidence)
        tc = self.time_constant
        self.trust_time = np.where(tc > 0, -tc * math.log1p(-c_min), 0.0)
        # runtime.trust_at_start: the filters running since the first cycle count at once
        self.trust_at_start = bool(arch.runtime.trust_at_start)
        self.from_start = np.zeros(len(res), dtype=bool)
        self.constrained = [
            (k, n)
            for k, n in enumerate(self.names)
            if (c := arch.modules[n].constraints).requires or c.excludes or c.limits
        ]
        self._true = np.ones(len(self.names), dtype=bool)  # shared, never written
        self._layout: Layout | None = None
        self._t_prev: float | None = None
        self.r_sat = unavailable_residual(arch.runtime)

    def bands(self, names: Any) -> np.ndarray:
        """The current ``residual.nominal`` of ``names`` (modules with a residual block)."""
        slot = {self.names[k]: j for j, k in enumerate(self.res_pos.tolist())}
        return self.nominal[[slot[n] for n in names]].copy()

    def set_nominal(self, name: str, value: float) -> None:
        """Set the band of ``name`` from the next cycle on (online bands, runtime/knowledge.py)."""
        j = int(np.flatnonzero(self.res_pos == self.index[name])[0])
        self.nominal[j] = float(value)
        if self._layout is not None:
            self._layout.nominal = self.nominal[self._layout.res_on]

    def layout(self, active: frozenset[str]) -> Layout:
        """The layout of ``active`` (rebuilt, carrying the filter state, when the set changes)."""
        lay = self._layout
        if lay is None or (lay.key is not active and lay.key != active):
            if lay is not None:
                lay.store(self)
            lay = self._layout = Layout(self, frozenset(active))
        return lay

    def observe(self, system: ManagedSystem, active: frozenset[str]) -> Observation:
        """Sample the system once (Algorithm 1, steps 1–2); never raises on bad signals.

        Plan → run → collect: the time step and the active set's layout, then
        availability, constraint violations and the residual filters, then the
        modules with a finding and κ_i.
        """
        t = float(system.t)
        dt = self._step(t)
        j_obs, j_ref = self._objective(system)
        local = _reported(system, "local_signals")
        lay = self.layout(active)
        r = np.zeros(len(self.names))
        available, reasons, down_names = self._availability(system, lay, r)
        violations = _violations(system, local, lay)
        ok, residual_ok = self._filters(lay, local, available, dt, r)
        flagged = self._flagged(lay, available, residual_ok, violations)
        kappa = StatusMap(self.names, self.index, lay.active, available, residual_ok,
                          confidence_reader(lay), violations, reasons, flagged, down_names)
        return Observation(t, j_obs, j_ref, j_ref - j_obs, r, kappa, lay.on_names, lay.value, ok)

    def _step(self, t: float) -> float:
        """The time since the last sample (the period on the first or a non-advancing one)."""
        dt = self.arch.runtime.period_s if self._t_prev is None else t - self._t_prev
        if dt <= 0:
            dt = self.arch.runtime.period_s
        self._t_prev = t
        return dt

    def _objective(self, system: ManagedSystem) -> tuple[float, float]:
        """``(J_obs, J_ref)``; J_obs is NaN when the objective raises."""
        try:
            j_obs = to_float(system.objective_error())
        except Exception:  # noqa: BLE001 - a failing objective must not stop the loop
            j_obs = math.nan
        return j_obs, float(self.arch.runtime.objective.acceptable)

    def _availability(
        self, system: ManagedSystem, lay: Layout, r: np.ndarray
    ) -> tuple[np.ndarray, dict[str, str | None], set[str]]:
        """Availability (κ), the reasons of the active modules that are down and the
        saturated residual of their own failures (written into ``r``).

        Returns ``(available, reasons, down_names)``; ``available`` is the shared
        all-true mask when every module is up.
        """
        avail = _reported(system, "available")
        reasons: dict[str, str | None] = {}
        if all(avail.values()):
            return self._true, reasons, set()
        names, index = self.names, self.index
        down_names = {m for m, ok in avail.items() if not ok and m in index}
        down = [index[m] for m in down_names]
        available = self._true.copy()
        available[down] = False
        down_active = sorted(k for k in down if lay.active[k])
        if down_active:
            why = _reported(system, "health")
            for k in down_active:
                reason = why.get(names[k])
                reasons[names[k]] = reason
                if reason is not None and is_own_failure(reason):
                    r[k] = self.r_sat
        return available, reasons, down_names

    def _filters(
        self, lay: Layout, local: Mapping[str, Any], available: np.ndarray, dt: float, r: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The residual filters of the active modules, ``y ← y + g·(s − y)`` where the
        sample is usable (r_i written into ``r``).

        Returns ``(ok, residual_ok)``: the usable-sample mask over the residual
        modules and over all modules (the shared masks when every sample was usable).
        """
        if not lay.pairs:
            return lay.all_ok, self._true
        raw = [(local.get(m) or {}).get(sig, math.nan) for m, sig in lay.pairs]
        avail_on = available[lay.on_pos] if available is not self._true else None
        ok = self._update(lay, raw, avail_on, dt, r)
        if ok is lay.all_ok:
            return ok, self._true
        residual_ok = self._true.copy()
        residual_ok[lay.on_pos] = ok
        return ok, residual_ok

    def _flagged(
        self, lay: Layout, available: np.ndarray, residual_ok: np.ndarray, violations: dict
    ) -> np.ndarray:
        """Positions of the active modules with a finding (down, unusable sample or a
        violated constraint)."""
        if available is self._true and residual_ok is self._true and not violations:
            return np.zeros(0, dtype=np.intp)
        finding = ~available | ~residual_ok
        if violations:
            finding[[k for k, name, *_ in lay.constrained if name in violations]] = True
        finding &= lay.active
        return finding.nonzero()[0]

    def _update(
        self, lay: Layout, raw: list[Any], avail_on: np.ndarray | None, dt: float, r: np.ndarray
    ) -> np.ndarray:
        """Filter update ``y ← y + g·(s − y)`` and r_i of the active residual modules.

        The operations of one first-order filter per module and
        :func:`module_residual`, elementwise. Returns the usable-sample mask
        (``lay.all_ok`` when every sample was usable).
        """
        x = as_floats(raw)
        with np.errstate(all="ignore"):
            ok = np.isfinite(x)
            if avail_on is not None:
                ok &= avail_on
            gain = lay.gains(self, dt)
            upd: Any
            if ok.all():
                upd, s, ok = slice(None), x, lay.all_ok
            else:
                upd = ok.nonzero()[0]
                s = x[upd]
            if not s.size:
                return ok
            v = lay.value[upd]
            new = v + gain[upd] * (s - v)
            if lay.any_instant:  # T = 0: the first sample is taken as is
                first = lay.instant[upd] & (lay.samples[upd] == 0)
                if first.any():
                    new = np.where(first, s, new)
            if isinstance(upd, slice):
                lay.value = new
                lay.samples = lay.samples + 1
                lay.valid_time = lay.valid_time + max(dt, 0.0)
            else:  # new arrays, so that earlier observations keep theirs
                lay.value = lay.value.copy()
                lay.value[upd] = new
                lay.samples = lay.samples.copy()
                lay.samples[upd] += 1
                lay.valid_time = lay.valid_time.copy()
                lay.valid_time[upd] += max(dt, 0.0)
            res = self._residuals(new, lay.sensitivity[upd], lay.nominal[upd])
            # trust: no residual before the filter has settled
            untrusted = lay.valid_time[upd] < lay.trust_time[upd]
            if untrusted.any():
                res = np.where(untrusted, 0.0, res)
            r[lay.on_pos[upd]] = res
        return ok

    def _residuals(self, value: np.ndarray, sens: np.ndarray, nom: np.ndarray) -> np.ndarray:
        """:func:`module_residual` of filtered values, elementwise."""
        if self.normalization == "none":
            out = sens * np.abs(value)
        else:  # max(0, |s̄| − nominal); never −0.0 since nominal > 0
            out = sens * np.maximum(np.abs(value) - nom, 0.0) / nom
        out = np.minimum(out, MAX_RESIDUAL)
        fin = np.isfinite(value)
        return out if fin.all() else np.where(fin, out, 0.0)


@dataclass
class ModuleStatus:
    """κ_i: status indicators of one module (Eq. 17)."""

    active: bool
    available: bool = True
    residual_ok: bool = True
    confidence: float = 1.0
    violations: list[str] = field(default_factory=list)
    reason: str | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "active": self.active,
            "available": self.available,
            "residual_ok": self.residual_ok,
            "confidence": float(self.confidence),
            "violations": list(self.violations),
        }
        if self.reason is not None:
            out["reason"] = self.reason
        return out


@dataclass(eq=False, repr=False)
class StatusMap(Mapping[str, ModuleStatus]):
    """κ of every module (Eq. 17) as a read-only mapping, built on demand.

    The Monitor keeps the status of all modules in arrays; a
    :class:`ModuleStatus` is only created when a module is looked up (and then
    kept, so repeated look-ups give the same object). :meth:`findings` lists the
    modules with something to report without touching the others, which is what
    keeps a cycle on 10^4 modules cheap.

    Parameters
    ----------
    names : list of str
        All modules, in index order (iteration order of the mapping).
    index : dict
        name -> position in ``names``.
    active, available, residual_ok : numpy.ndarray of bool
        Per position.
    confidence : callable
        position -> confidence of the module's residual filter.
    violations : dict
        name -> violated constraints (active modules with at least one).
    reasons : dict
        name -> reason of an active unavailable module (may be None).
    finding : numpy.ndarray of int
        Positions of the active modules that are unavailable, have an unusable
        residual signal or violate a constraint, ascending.
    unavailable : set of str
        The names where ``available`` is False.
    """

    _names: list[str]
    _index: dict[str, int]
    _active: np.ndarray
    _available: np.ndarray
    _residual_ok: np.ndarray
    _confidence: Callable[[int], float]
    _violations: dict[str, list[str]]
    _reasons: dict[str, str | None]
    _finding: np.ndarray
    _down: set[str]
    _built: dict[str, ModuleStatus] = field(default_factory=dict, init=False)

    def __getitem__(self, name: str) -> ModuleStatus:
        status = self._built.get(name)
        if status is None:
            k = self._index[name]
            status = ModuleStatus(
                active=bool(self._active[k]),
                available=bool(self._available[k]),
                residual_ok=bool(self._residual_ok[k]),
                confidence=self._confidence(k),
                violations=list(self._violations.get(name, ())),
                reason=self._reasons.get(name),
            )
            self._built[name] = status
        return status

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)

    def findings(self) -> list[tuple[str, ModuleStatus]]:
        """``(name, κ)`` of the active modules with a finding, in index order.

        A finding is: unavailable, residual signal unusable, or a violated
        constraint (what the decision log records).
        """
        names = self._names
        return [(names[k], self[names[k]]) for k in self._finding.tolist()]

    def unavailable(self) -> set[str]:
        """Names of the modules the system reports unavailable (active or not)."""
        return self._down


def limit_violations(
    limits: Mapping[str, Any], local: Mapping[str, Any], outputs: Mapping[str, Any] | None = None
) -> list[str]:
    """Declared ``max_<signal>``/``min_<signal>`` limits the module's signals break (e).

    The signal is a local (residual) signal, else a scalar output the module published
    this step; a limit on anything else (a parameter, θ) is judged by the planner.
    Each line starts with the limit's key (:func:`is_limit_violation`).
    """
    out = []
    for key, limit in limits.items():
        for prefix, worse in (("max_", float.__gt__), ("min_", float.__lt__)):
            if key.startswith(prefix):
                name = key[len(prefix) :]
                if name in local:
                    raw = local[name]
                else:
                    raw = outputs.get(name) if outputs else None
                    if isinstance(raw, np.ndarray):
                        raw = raw.item() if raw.size == 1 else None
                value = to_float(math.nan if raw is None else raw)
                if math.isfinite(value) and worse(value, float(limit)):
                    out.append(f"{key} {limit:g} violated ({value:g})")
    return out


def is_limit_violation(text: str) -> bool:
    """True for a κ violation line of a measured limit (not ``requires``/``excludes``)."""
    return text.startswith(("max_", "min_"))


#: r_i is capped here: a finite but huge signal (1e308 over a nominal of 0.1) would
#: overflow to inf, which the influence solve cannot take; any band is far below.
MAX_RESIDUAL = 1e12


def filter_gain(dt: float, time_constant: float) -> float:
    """Gain ``1 − exp(−dt/T)`` of a first-order filter sampled every ``dt`` (1 if T = 0).

    Examples
    --------
    >>> filter_gain(1.0, 0.0)
    1.0
    >>> round(filter_gain(1.0, 10.0), 4)
    0.0952
    """
    if time_constant <= 0:
        return 1.0
    return float(1.0 - math.exp(-max(dt, 0.0) / time_constant))


def module_residual(
    value: float, sensitivity: float, nominal: float, normalization: str = "nominal"
) -> float:
    """Local residual r_i (Eq. 12) from a (filtered) local signal value.

    Parameters
    ----------
    value : float
        The filtered local signal s̄.
    sensitivity : float
        ∂J/∂θ_i.
    nominal : float
        The signal's nominal noise level (> 0).
    normalization : {"nominal", "none"}
        See the module docstring.

    Returns
    -------
    float
        ``r_i``, at most :data:`MAX_RESIDUAL`; 0 for a non-finite value.

    Examples
    --------
    >>> module_residual(0.375, 1.0, 0.25)   # 50 % above nominal
    0.5
    >>> module_residual(0.1, 1.0, 0.2)      # inside the noise band
    0.0
    >>> module_residual(-0.3, 2.0, 0.2, "none")
    0.6
    """
    if not math.isfinite(value):
        return 0.0
    if normalization == "none":
        return float(min(sensitivity * abs(value), MAX_RESIDUAL))
    return float(min(sensitivity * max(0.0, abs(value) - nominal) / nominal, MAX_RESIDUAL))


def unavailable_residual(runtime: Any) -> float:
    """``r_sat``: the residual of an unavailable module, ``max(1, 2·τ)``.

    τ is ``runtime.threshold`` (or ``hysteresis.on``), so an unavailable module
    is always a candidate (z_i ≥ r_i with non-negative weights); 1 is "a
    deviation as large as the nominal level" under ``nominal`` normalization.

    Examples
    --------
    >>> from types import SimpleNamespace as NS
    >>> unavailable_residual(NS(threshold=0.55, hysteresis=None))
    1.1
    >>> unavailable_residual(NS(threshold=None, hysteresis=None))
    1.0
    """
    tau = runtime.threshold
    if tau is None and runtime.hysteresis is not None:
        tau = runtime.hysteresis.on
    return float(max(1.0, 2.0 * float(tau or 0.0)))


def is_own_failure(reason: str | None) -> bool:
    """Whether an unavailability reason is the module's own (not a lost upstream input)."""
    return not (reason or "").startswith("lost input")


def filter_confidence(samples: int, valid_time: float, time_constant: float) -> float:
    """``1 − exp(−t_valid/T)`` of a residual filter (0 before a sample, 1 without smoothing)."""
    if samples == 0:
        return 0.0
    if time_constant <= 0:
        return 1.0
    return float(1.0 - math.exp(-valid_time / time_constant))


def to_float(x: Any) -> float:
    """``float(x)``, NaN when ``x`` is no number."""
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan
