"""Fault injection, generic over fault kinds.

A fault of a scenario (``scenarios.<s>.faults[*]``) transforms one output signal
of one module between ``onset_s`` and ``end_s`` (default: forever). The
transformation knows nothing about the module; it acts on floats and numpy
arrays (every component of a vector signal). ``None`` ("no value this step")
passes through unchanged.

==================  =====================================================
kind                value seen downstream
==================  =====================================================
bias_drift          ``y + magnitude · (t − onset)``
bias                ``y + magnitude``
effectiveness_loss  ``y · (1 − magnitude)``
noise_increase      ``y + n``, ``n ~ N(0, σ²)``: if the module declares its
                    nominal noise ``σ₀`` for the signal (``noise_levels``),
                    ``σ = σ₀ √(magnitude² − 1)`` so the total noise is
                    ``magnitude · σ₀``; otherwise ``σ = magnitude`` (absolute)
dropout             ``None``
stuck               the first value at or after onset, held (steps where the
                    module gives ``None`` stay ``None``)
nan                 NaN (every component of a vector); ``None`` stays ``None``
==================  =====================================================

Examples
--------
>>> import numpy as np
>>> f = FaultInjector("bias_drift", onset_s=10.0, magnitude=0.1)
>>> f.apply(5.0, 1.0), round(f.apply(20.0, 1.0), 6)
(1.0, 2.0)
>>> FaultInjector("effectiveness_loss", onset_s=0.0, magnitude=0.2).apply(1.0, 5.0)
4.0
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["FAULT_KINDS", "FaultInjector", "default_signal"]

FAULT_KINDS = frozenset(
    {"bias_drift", "bias", "effectiveness_loss", "noise_increase", "dropout", "stuck", "nan"}
)


def default_signal(module: Any) -> str | None:
    """The signal a fault without ``signal`` acts on: ``module.main_output`` or ``outputs[0]``."""
    main = getattr(module, "main_output", None)
    if main:
        return str(main)
    outs = getattr(module, "outputs", ())
    return outs[0] if outs else None


class FaultInjector:
    """One fault acting on one output signal.

    Parameters
    ----------
    kind : str
        One of :data:`FAULT_KINDS`.
    onset_s : float
        Start of the fault (s).
    magnitude : float
        Size of the fault (units depend on ``kind``).
    end_s : float, optional
        When the fault clears (default never).
    signal : str, optional
        The output signal it acts on (informational; the system routes it).
    rng : numpy.random.Generator, optional
        Noise source for ``noise_increase``.
    base_noise : float, optional
        Nominal noise standard deviation of the signal, if the module declares it.
    """

    def __init__(
        self,
        kind: str,
        onset_s: float,
        magnitude: float = 0.0,
        end_s: float | None = None,
        signal: str | None = None,
        rng: np.random.Generator | None = None,
        base_noise: float | None = None,
    ) -> None:
        if kind not in FAULT_KINDS:
            raise ValueError(
                f"unknown fault kind {kind!r}; known: {', '.join(sorted(FAULT_KINDS))}"
            )
        self.kind = kind
        self.onset = float(onset_s)
        self.end = math.inf if end_s is None else float(end_s)
        self.magnitude = float(magnitude)
        self.signal = signal
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.sigma = 0.0  # of the added noise (noise_increase)
        if kind == "noise_increase":
            self.sigma = (base_noise * math.sqrt(max(self.magnitude**2 - 1.0, 0.0))
                          if base_noise is not None and base_noise > 0 else abs(self.magnitude))
        self.held: Any = None

    def active(self, t: float) -> bool:
        """Whether the fault acts at time ``t``."""
        return self.onset <= t + 1e-9 and t < self.end - 1e-9

    def apply(self, t: float, value: Any) -> Any:
        """The faulty version of ``value`` at time ``t``."""
        if not self.active(t):
            self.held = None
            return value
        kind = self.kind
        if kind == "dropout" or value is None:
            return None
        if kind == "bias_drift":
            return value + self.magnitude * (t - self.onset)
        if kind == "bias":
            return value + self.magnitude
        if kind == "effectiveness_loss":
            return value * (1.0 - self.magnitude)
        if kind == "nan":
            if isinstance(value, np.ndarray):
                return np.full(value.shape, math.nan)
            return math.nan
        if kind == "noise_increase":
            if isinstance(value, np.ndarray):
                return value + self.sigma * self.rng.standard_normal(value.shape)
            return value + self.sigma * float(self.rng.standard_normal())
        # stuck
        if self.held is None:
            self.held = value.copy() if isinstance(value, np.ndarray) else value
        return self.held.copy() if isinstance(self.held, np.ndarray) else self.held
