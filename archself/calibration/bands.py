"""Bands from nominal residuals: the arithmetic of ``archself calibrate``.

Notation (docs/calibrate.md): for a run in configuration c, cycle t after the
warm-up and module j with a ``residual`` block, x_tj = |s̄_j| is the filtered
residual signal (:mod:`archself.calibration.runs`). With bands n_j
(``residual.nominal``) the runtime forms r_j = σ_j·max(0, x_j − n_j)/n_j
(σ_j = ``residual.sensitivity``), z = (I − Wᵀ)⁻¹ r over the active edges of c
(W normalized as the runtime does) and raises a candidate when
max_i |z_i| ≥ τ. A *false alarm* is a nominal run with a candidate in any cycle
after the warm-up — an upper bound on its false switches (a candidate switches
only if an admissible action scores above 0).

Bands are n_j = s·b_j: a *shape* b and one common *scale* s.

- Shape: b_j is the band at which module j's residual *alone* raises a
  candidate in a share p/K of the runs (K the channels active in the cell; or
  p·w_j/Σw with weights w, a weighted Bonferroni split): the (1 − p/K) quantile
  of its per-run maximum of x_j (the larger of a Gumbel fit's and the empirical
  one) divided by its alarm factor 1 + τ/(c_j·σ_j), c_j its largest influence
  (:func:`channel_scales`); the largest over the cells in which j is active
  (:func:`channel_shape`). Every channel then alarms at the same tail
  probability of its own noise — a channel with heavy tails (noise spikes)
  gets a wide band without widening the others', and a channel whose residual
  propagates far is not held to a stricter level than one that does not.
- Scale: z decreases as s grows (σ ≥ 0 and W ≥ 0), so each run has a
  critical scale S = sup{s : the run raises a candidate with bands s·b}: the run
  has a false alarm exactly when s ≤ S. S is a maximum over the run's cycles
  (found by bisection per cycle), so its tail is modelled as a Gumbel law's:
  a Gumbel distribution fitted to all the runs' S (scipy.stats.gumbel_r, maximum
  likelihood) and an exponential fitted to the top 20 % of them (the Gumbel tail,
  fitted to the tail only; :class:`~archself.runtime.tails.TailFit`); the same for
  each module's S_j (its residual alone, :func:`channel_scales`). The predicted rate is the larger
  of the whole-run fit and the sum over the modules (:class:`Prediction`). The
  scale is the smallest s at which the predicted and the empirical rate are both
  ≤ p, the largest over the (scenario, configuration) cells.

All functions are pure numpy/scipy on arrays; nothing here runs a simulation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from archself.runtime.knowledge import Knowledge
from archself.runtime.tails import TailFit, band_of_level, empirical_level, quantile_level

__all__ = [
    "Cell",
    "Prediction",
    "channel_scales",
    "channel_shape",
    "TailFit",
    "alarm_threshold",
    "critical_scales",
    "cycle_scales",
    "influence_block",
    "quantile_level",
]


def alarm_threshold(runtime: Any) -> float:
    """τ of the candidate set: ``runtime.threshold`` or ``runtime.hysteresis.on``.

    Raises
    ------
    ValueError
        With ``top_k`` (no threshold to calibrate against).
    """
    if runtime.threshold is not None:
        return float(runtime.threshold)
    if runtime.hysteresis is not None:
        return float(runtime.hysteresis.on)
    raise ValueError("runtime.top_k has no threshold τ to calibrate the bands against")


def influence_block(arch: Any, configuration: str, residual_modules: Sequence[str]) -> np.ndarray:
    """M with z_active = M · x-residuals: the columns of (I − Wᵀ)⁻¹ of the runtime.

    Rows: the active modules of ``configuration`` (file order); columns:
    ``residual_modules``. Computed with the runtime's own
    :class:`~archself.runtime.knowledge.Knowledge` (active edges, disabled edges,
    the ρ(W) normalization, the same solver), one unit vector per column.
    """

    k = Knowledge(arch, configuration)
    out = np.zeros((len(k.active_index), len(residual_modules)))
    for j, name in enumerate(residual_modules):
        e = np.zeros(len(k.names))
        e[k.index[name]] = 1.0
        out[:, j] = np.asarray(k.influence(e))[k.active_index]
    return out


def _max_abs_z(x: np.ndarray, n: np.ndarray, sens: np.ndarray, m: np.ndarray) -> np.ndarray:
    """max_i |z_i| per row of x (cycles × modules) for bands n (rows × modules or modules)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        r = sens * np.maximum(x - n, 0.0) / n
    r = np.where(np.isfinite(r), r, 0.0)
    if m.size == 0 or r.size == 0:
        return np.zeros(x.shape[0])
    return np.abs(r @ m.T).max(axis=1)


def cycle_scales(
    x: np.ndarray,
    base: np.ndarray,
    sens: np.ndarray,
    m: np.ndarray,
    tau: float,
    *,
    iterations: int = 60,
) -> np.ndarray:
    """The critical scale of every cycle: the largest s with max_i |z_i| ≥ τ for bands s·base.

    Parameters
    ----------
    x : ndarray (cycles × J)
        |s̄_j| per cycle.
    base : ndarray (J,)
        Band shape b (> 0).
    sens : ndarray (J,)
        σ_j.
    m : ndarray (A × J)
        :func:`influence_block`.
    tau : float
        τ.

    Returns
    -------
    ndarray (cycles,)
        0 where no band can raise a candidate (every x_j = 0); otherwise found
        by bisection on log s to a relative precision of about 1e-9.

    Examples
    --------
    One module, σ = 1, no edges: a candidate when (x − s·b)/(s·b) ≥ τ, i.e. s ≤ x/(b(1 + τ)).

    >>> s = cycle_scales(np.array([[3.0]]), np.array([1.0]), np.array([1.0]), np.eye(1), 0.5)
    >>> round(float(s[0]), 6)
    2.0
    """
    x = np.asarray(x, dtype=float)
    c = x.shape[0]
    out = np.zeros(c)
    if c == 0:
        return out
    hi = (x / base).max(axis=1)  # above this every r_j = 0
    live = hi > 0
    if not live.any():
        return out
    xs, his = x[live], hi[live]
    lo = his * 1e-12
    # a candidate at lo? (r huge); if not even there, the critical scale is ~0
    ok_lo = _max_abs_z(xs, lo[:, None] * base, sens, m) >= tau
    a, b = np.log(lo), np.log(his)
    for _ in range(iterations):
        mid = 0.5 * (a + b)
        alarm = _max_abs_z(xs, np.exp(mid)[:, None] * base, sens, m) >= tau
        a = np.where(alarm, mid, a)
        b = np.where(alarm, b, mid)
    out[live] = np.where(ok_lo, np.exp(a), 0.0)
    return out


@dataclass
class Cell:
    """The calibration runs of one (scenario, configuration).

    Attributes
    ----------
    scenario, configuration : str
    modules : list of str
        The active modules with a residual block (columns of every ``x``).
    x : list of ndarray
        Per run: cycles × modules, |s̄_j| after the warm-up.
    forced : ndarray of bool
        Per run: an active module was unavailable for a reason of its own in
        some cycle after the warm-up (a candidate whatever the bands).
    m : ndarray
        :func:`influence_block` for ``modules``.
    sens : ndarray
        σ_j of ``modules``.
    seeds : list of int
    failed : list of str
        Errors of the runs that failed (not in ``x``).
    """

    scenario: str
    configuration: str
    modules: list[str]
    x: list[np.ndarray]
    forced: np.ndarray
    m: np.ndarray
    sens: np.ndarray
    seeds: list[int] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)

    @property
    def runs(self) -> int:
        return len(self.x)

    def cycles(self, module: str) -> np.ndarray:
        """Every cycle's |s̄_j| of ``module`` after the warm-up, the runs one after another."""
        j = self.modules.index(module)
        return np.concatenate([xr[:, j] for xr in self.x]) if self.x else np.zeros(0)

    def run_max(self, module: str) -> np.ndarray:
        """Per run: the largest |s̄_j| of ``module`` after the warm-up."""
        j = self.modules.index(module)
        return np.array([float(xr[:, j].max()) if xr.shape[0] else 0.0 for xr in self.x])


def critical_scales(cell: Cell, bands: dict[str, float], tau: float) -> np.ndarray:
    """Per run of ``cell``: S, the largest s at which bands s·n raise a candidate.

    The run has a false alarm with bands s·n exactly when s ≤ S; with the bands
    themselves (s = 1) when S ≥ 1. A run with a forced candidate has S = inf.
    """
    base = np.array([float(bands[m]) for m in cell.modules], dtype=float)
    out = np.zeros(cell.runs)
    for k, xr in enumerate(cell.x):
        if cell.forced[k]:
            out[k] = math.inf
        elif xr.shape[0]:
            out[k] = float(cycle_scales(xr, base, cell.sens, cell.m, tau).max())
    return out


def channel_scales(cell: Cell, bands: dict[str, float], tau: float) -> np.ndarray:
    """Per run and module: S_j, the critical scale with module j's residual alone.

    With only r_j ≠ 0, max_i |z_i| = c_j·σ_j·(x_j/(s·n_j) − 1) with c_j = max_i |M_ij|, so
    S_j = max over the run's cycles of x_j / (n_j·(1 + τ/(c_j·σ_j))) (0 when c_j·σ_j = 0).
    A run with a forced candidate has S_j = inf. Shape: runs × modules.
    """
    n = np.array([float(bands[m]) for m in cell.modules], dtype=float)
    gain = np.abs(cell.m).max(axis=0) * np.abs(cell.sens) if cell.m.size else np.zeros(n.size)
    out = np.zeros((cell.runs, n.size))
    with np.errstate(divide="ignore"):
        factor = np.where(gain > 0, 1.0 / (n * (1.0 + tau / gain)), 0.0)
    for k, xr in enumerate(cell.x):
        if cell.forced[k]:
            out[k] = math.inf
        elif xr.shape[0]:
            out[k] = xr.max(axis=0) * factor
    return out


@dataclass
class Prediction:
    """P(a run has a false alarm at scale s): the whole-run fit or the channels' sum.

    ``all`` is the :class:`TailFit` of the runs' critical scales S; ``channels``
    those of each module's S_j (:func:`channel_scales`). A run alarms when
    S ≥ s, and S ≥ max_j S_j; when one channel drives the alarms (the usual case)
    S ≈ max_j S_j and P(S ≥ s) ≤ Σ_j P(S_j ≥ s). The prediction is the larger of
    the whole-run fit and that sum, so a rare mechanism of one channel (noise
    spikes of an observer) cannot hide behind the narrow bulk of another (the
    same setpoint ramp in every run).
    """

    all: TailFit
    channels: list[TailFit]

    @classmethod
    def of(cls, cell: Cell, bands: dict[str, float], tau: float) -> Prediction:
        per = channel_scales(cell, bands, tau)
        return cls(
            TailFit.fit(critical_scales(cell, bands, tau)),
            [TailFit.fit(per[:, j]) for j in range(per.shape[1])],
        )

    def predicted(self, s: float) -> float:
        """max(P_all(S ≥ s), Σ_j P_j(S_j ≥ s)), at most 1."""
        parts = sum(ch.predicted(s) for ch in self.channels)
        return min(1.0, max(self.all.predicted(s), parts))

    def empirical(self, s: float) -> float:
        """Share of the runs with S ≥ s."""
        return self.all.empirical(s)

    def quantile(self, p: float) -> float:
        """The smallest s with predicted(s) ≤ p and empirical(s) ≤ p (bisection)."""
        lo = max(self.all.quantile(p), empirical_level(self.all.values, p))
        if math.isinf(lo) or self.predicted(lo) <= p:
            return lo
        hi = max(lo, 1e-300) * 2.0
        for _ in range(200):
            if self.predicted(hi) <= p:
                break
            hi *= 2.0
        else:  # pragma: no cover - a tail that never falls below p
            return math.inf
        for _ in range(100):
            mid = 0.5 * (lo + hi)
            if self.predicted(mid) <= p:
                hi = mid
            else:
                lo = mid
        return hi


def channel_shape(cell: Cell, module: str, p: float, tau: float,
                  weights: Mapping[str, float] | None = None) -> float:
    """The band at which ``module``'s residual alone alarms in its share of ``cell``'s runs.

    The share is p·w_j/Σw over the cell's channels (a weighted Bonferroni split of the
    false-alarm budget; every weight 1 by default: p/K each, K the channels); the
    level is :func:`quantile_level` of the module's per-run maxima at that share,
    divided by its alarm factor 1 + τ/(c_j·σ_j) (the band n_j at which
    x_j = n_j·(1 + τ/(c_j·σ_j)) raises max_i |z_i| = τ, :func:`channel_scales`). A
    channel that cannot raise a candidate (c_j·σ_j = 0) keeps its plain level.

    Examples
    --------
    One channel, no edges (c = 1), σ = 1, τ = 0.5: alarms at 1.5·n, so n is the
    level over 1.5.

    >>> cell = Cell("s", "c", ["m"], [np.array([[v]]) for v in np.linspace(1, 2, 200)],
    ...             np.zeros(200, bool), np.eye(1), np.ones(1))
    >>> round(channel_shape(cell, "m", 0.01, 0.5) * 1.5, 3) == round(quantile_level(
    ...     cell.run_max("m"), 0.01), 3)
    True
    """
    j = cell.modules.index(module)
    w = weights or {}
    total = sum(float(w.get(m, 1.0)) for m in cell.modules)
    share = p * float(w.get(module, 1.0)) / total if total > 0 else p
    level = quantile_level(cell.run_max(module), share)
    gain = float(np.abs(cell.m[:, j]).max() * abs(cell.sens[j])) if cell.m.size else 0.0
    return band_of_level(level, tau, gain)
