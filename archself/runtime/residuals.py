"""The residual maths of one module (Eq. 12): filter gain, r_i, r_sat, the trust of a filter.

Pure functions and the one-module :class:`ResidualFilter`; the
:class:`~archself.runtime.monitor.Monitor` does the same arithmetic over arrays of
modules, operation for operation (tests/test_runtime_monitor.py). The rules
(normalization, trust, unavailable modules) are in :mod:`archself.runtime.monitor`.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = [
    "MAX_RESIDUAL",
    "ResidualFilter",
    "filter_confidence",
    "filter_gain",
    "is_own_failure",
    "module_residual",
    "to_float",
    "unavailable_residual",
]


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
        self.reset()

    def reset(self) -> None:
        """Start again from 0, with no sample."""
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
        return filter_confidence(self.samples, self.valid_time, self.time_constant)


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
