"""Tail fits of per-run maxima: the false-alarm statistics of ``archself calibrate``.

A run's critical scale S (:mod:`archself.calibration.bands`) is a maximum over its
cycles, so its upper tail is modelled as a Gumbel law's (:class:`TailFit`: a Gumbel
fit to all values and an exponential fit to the top 20 %, the heavier tail counts).
``rate_at`` is the empirical rate P(S ≥ s), ``empirical_level`` the smallest level
that at most ⌊N·p⌋ values reach, ``scale_for_rate`` and ``quantile_level`` the
(1 − p) level where both the fits and the sample stay ≤ p. Pure numpy/scipy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "TailFit", "band_of_level", "empirical_level", "quantile_level", "rate_at", "scale_for_rate",
]


@dataclass
class TailFit:
    """The distribution of per-run maxima S, fitted twice; the heavier tail counts.

    A point mass at 0 (runs without any signal) and at +inf (runs with a forced
    candidate) and, for the positive finite values:

    - a Gumbel law G fitted to all of them (maximum likelihood), the law of a
      maximum over many cycles;
    - an exponential law fitted to the excesses of the largest ``k`` values over
      the next one, u (k = the top 20 %, at least 5): the tail of a Gumbel law,
      fitted to the tail only, so that a narrow bulk (e.g. the same reference
      ramp in every run) cannot hide rare large values.

    ``predicted(s)`` is the larger of the two tail probabilities (the
    empirical rate where neither fit exists: fewer than 3, resp. 10, values).
    """

    values: np.ndarray
    f0: float
    finf: float
    loc: float | None
    scale: float | None
    tail_u: float | None = None
    tail_beta: float | None = None
    tail_share: float = 0.0

    @classmethod
    def fit(cls, values: np.ndarray) -> TailFit:
        v = np.asarray(values, dtype=float)
        n = max(v.size, 1)
        pos = np.sort(v[np.isfinite(v) & (v > 0)])
        f0 = float(np.sum(v <= 0)) / n
        finf = float(np.sum(np.isinf(v))) / n
        loc = scale = None
        spread = pos.size >= 3 and float(np.ptp(pos)) > 1e-12 * float(pos.max())
        if spread:
            from scipy.stats import gumbel_r

            loc_, scale_ = gumbel_r.fit(pos)
            if math.isfinite(loc_) and math.isfinite(scale_) and scale_ > 0:
                loc, scale = float(loc_), float(scale_)
        u = beta = None
        share = 0.0
        if spread and pos.size >= 10:
            k = max(5, int(math.ceil(0.2 * pos.size)))
            top, u_ = pos[-k:], float(pos[-k - 1])
            beta_ = float(np.mean(top - u_))
            if beta_ > 0:
                u, beta, share = u_, beta_, k / n
        return cls(v, f0, finf, loc, scale, u, beta, share)

    def _gumbel(self, s: float) -> float | None:
        if self.loc is None or self.scale is None:
            return None
        from scipy.stats import gumbel_r

        tail = float(gumbel_r.sf(s, self.loc, self.scale)) if s > 0 else 1.0
        return self.finf + (1.0 - self.finf - self.f0) * tail

    def _exponential(self, s: float) -> float | None:
        if self.tail_u is None or self.tail_beta is None:
            return None
        if s <= self.tail_u:
            return self.empirical(s)
        return self.finf + self.tail_share * math.exp(-(s - self.tail_u) / self.tail_beta)

    def predicted(self, s: float) -> float:
        """P(S ≥ s): the larger of the two fits (the empirical rate when there is no fit)."""
        fits = [f for f in (self._gumbel(s), self._exponential(s)) if f is not None]
        return max(fits) if fits else self.empirical(s)

    def empirical(self, s: float) -> float:
        """Share of the values ≥ s."""
        return rate_at(self.values, s)

    def quantile(self, p: float) -> float:
        """The smallest s with both fits' P(S ≥ s) ≤ p (inf when p ≤ f_inf; 0 without fits)."""
        if p <= self.finf:
            return math.inf
        out = 0.0
        body = 1.0 - self.finf - self.f0
        if self.loc is not None and self.scale is not None and body > 0:
            q = (p - self.finf) / body
            if q < 1.0:
                from scipy.stats import gumbel_r

                out = max(out, float(gumbel_r.isf(q, self.loc, self.scale)))
        if self.tail_u is not None and self.tail_beta is not None:
            q = p - self.finf
            if q < self.tail_share:
                out = max(out, self.tail_u + self.tail_beta * math.log(self.tail_share / q))
            else:
                out = max(out, empirical_level(self.values, p))
        return max(0.0, out)


def rate_at(values: np.ndarray, s: float) -> float:
    """Share of ``values`` that are ≥ s (the empirical false-alarm rate at scale s)."""
    v = np.asarray(values, dtype=float)
    return float(np.mean(v >= s)) if v.size else math.nan


def empirical_level(values: np.ndarray, p: float) -> float:
    """The smallest level s (just above a value) with at most ⌊N·p⌋ values ≥ s."""
    v = np.sort(np.asarray(values, dtype=float))[::-1]
    k = int(math.floor(v.size * p + 1e-9))  # allowed exceedances
    if k >= v.size:
        return 0.0
    top = float(v[k])
    if top <= 0:
        return 0.0
    return math.inf if math.isinf(top) else top * (1.0 + 1e-9)


def scale_for_rate(values: np.ndarray, p: float) -> tuple[float, TailFit]:
    """Scale s with predicted and empirical P(S ≥ s) both ≤ p; and the fit.

    The largest of the Gumbel and the exponential-tail (1 − p) quantiles and the
    empirical level.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> v = rng.gumbel(1.0, 0.1, 2000)
    >>> s, fit = scale_for_rate(v, 0.01)
    >>> round(fit.predicted(s), 3) <= 0.01 and fit.empirical(s) <= 0.01
    True
    """
    fit = TailFit.fit(values)
    return max(fit.quantile(p), empirical_level(values, p)), fit


def quantile_level(values: np.ndarray, p: float) -> float:
    """The (1 − p) level of per-run maxima: :func:`scale_for_rate` on them (0 if all 0)."""
    return scale_for_rate(values, p)[0]


def band_of_level(level: float, tau: float, gain: float) -> float:
    """The band n at which a signal at ``level`` raises max_i |z_i| = τ on its own.

    With only r_j ≠ 0, max_i |z_i| = gain·(x/n − 1), gain = c_j·σ_j (c_j the largest
    influence of a unit r_j), so x = n·(1 + τ/gain). A channel that cannot raise a
    candidate (gain 0) keeps its level.

    Examples
    --------
    >>> band_of_level(1.5, 0.5, 1.0)
    1.0
    """
    return level / (1.0 + tau / gain) if gain > 0 else level
