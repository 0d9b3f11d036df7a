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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from archself.model import Architecture

__all__ = [
    "ModuleStatus",
    "Monitor",
    "Observation",
    "ResidualFilter",
    "filter_gain",
    "module_residual",
    "unavailable_residual",
]


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
        ``r_i``; 0 for a non-finite value.

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
        return float(sensitivity * abs(value))
    return float(sensitivity * max(0.0, abs(value) - nominal) / nominal)


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
    tau = getattr(runtime, "threshold", None)
    hyst = getattr(runtime, "hysteresis", None)
    if tau is None and hyst is not None:
        tau = hyst.on
    return float(max(1.0, 2.0 * float(tau or 0.0)))


def is_own_failure(reason: str | None) -> bool:
    """Whether an unavailability reason is the module's own (not a lost upstream input)."""
    return not (reason or "").startswith("lost input")


class ResidualFilter:
    """First-order low-pass filter ``y ← y + g·(s − y)`` holding on missing samples.

    Starts at 0 (a healthy module's nominal residual) so that one noisy first
    sample cannot raise an alarm.

    Parameters
    ----------
    time_constant : float
        T in seconds; 0 passes the signal through.
    """

    def __init__(self, time_constant: float) -> None:
        self.time_constant = float(time_constant)
        self.value = 0.0
        self.valid_time = 0.0
        self.samples = 0

    def update(self, sample: float, dt: float) -> float:
        """Feed one sample taken ``dt`` seconds after the previous one."""
        if math.isfinite(sample):
            if self.samples == 0 and self.time_constant <= 0:
                self.value = sample
            else:
                self.value += filter_gain(dt, self.time_constant) * (sample - self.value)
            self.samples += 1
            self.valid_time += max(dt, 0.0)
        return self.value

    @property
    def confidence(self) -> float:
        """How settled the filter is: ``1 − exp(−t_valid/T)`` (1 without smoothing)."""
        if self.samples == 0:
            return 0.0
        if self.time_constant <= 0:
            return 1.0
        return float(1.0 - math.exp(-self.valid_time / self.time_constant))

    def reset(self) -> None:
        self.value = 0.0
        self.valid_time = 0.0
        self.samples = 0


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


@dataclass
class Observation:
    """Everything the Monitor stage measured in one cycle."""

    t: float
    j_obs: float
    j_ref: float
    r_global: float
    r: np.ndarray
    signals: dict[str, float | None]
    kappa: dict[str, ModuleStatus]


def _finite(x: Any) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return math.nan
    return v


class Monitor:
    """Monitor stage: residual filters per module and the κ_i indicators.

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
        self.normalization = arch.runtime.normalization
        self.filters: dict[str, ResidualFilter] = {
            name: ResidualFilter(mod.residual.smoothing_s)
            for name, mod in arch.modules.items()
            if mod.residual is not None
        }
        self._t_prev: float | None = None
        self.r_sat = unavailable_residual(arch.runtime)

    def observe(self, system: Any, active: frozenset[str]) -> Observation:
        """Sample the system once (Algorithm 1, steps 1–2); never raises on bad signals."""
        t = float(system.t)
        dt = self.arch.runtime.period_s if self._t_prev is None else t - self._t_prev
        if dt <= 0:
            dt = self.arch.runtime.period_s
        self._t_prev = t

        try:
            j_obs = _finite(system.objective_error())
        except Exception:  # noqa: BLE001 - a failing objective must not stop the loop
            j_obs = math.nan
        j_ref = float(self.arch.runtime.objective.acceptable)
        r_global = j_ref - j_obs

        try:
            local = system.local_signals() or {}
        except Exception:  # noqa: BLE001
            local = {}
        try:
            avail = system.available() or {}
        except Exception:  # noqa: BLE001
            avail = {}
        health = getattr(system, "health", None)
        try:
            why = (health() or {}) if health is not None else {}
        except Exception:  # noqa: BLE001
            why = {}

        r = np.zeros(len(self.names))
        signals: dict[str, float | None] = {}
        kappa: dict[str, ModuleStatus] = {}
        for k, name in enumerate(self.names):
            mod = self.arch.modules[name]
            is_active = name in active
            status = ModuleStatus(active=is_active, available=bool(avail.get(name, True)))
            kappa[name] = status
            if is_active:
                status.violations = self._violations(name, active, local.get(name) or {})
                if not status.available:
                    reason = why.get(name)
                    status.reason = reason
                    if reason is not None and is_own_failure(reason):
                        r[k] = self.r_sat
            filt = self.filters.get(name)
            if filt is None:
                continue
            if not is_active:
                filt.reset()
                status.confidence = 0.0
                continue
            assert mod.residual is not None
            sample = _finite((local.get(name) or {}).get(mod.residual.signal, math.nan))
            ok = math.isfinite(sample) and status.available
            status.residual_ok = ok
            value = filt.update(sample if ok else math.nan, dt)
            status.confidence = filt.confidence
            if ok:
                signals[name] = float(value)
                r[k] = module_residual(
                    value, mod.residual.sensitivity, mod.residual.nominal, self.normalization
                )
            else:
                signals[name] = None
        return Observation(t, j_obs, j_ref, r_global, r, signals, kappa)

    def _violations(self, name: str, active: frozenset[str], local: dict) -> list[str]:
        """Constraint violations of k_i: requires/excludes and declared limits."""
        cons = self.arch.modules[name].constraints
        out = [f"requires {m} (inactive)" for m in cons.requires if m not in active]
        out += [f"excludes {m} (active)" for m in cons.excludes if m in active]
        for key, limit in cons.limits.items():
            for prefix, worse in (("max_", float.__gt__), ("min_", float.__lt__)):
                if key.startswith(prefix):
                    value = _finite(local.get(key[len(prefix) :], math.nan))
                    if math.isfinite(value) and worse(value, float(limit)):
                        out.append(f"{key} {limit:g} violated ({value:g})")
        return out
