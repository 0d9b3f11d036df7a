"""The maths of ``archself identify``: edge weights W from residual differences.

Pure functions on arrays, no simulation. The model (paper Eq. 14, read as a
model of the data): module residuals r relate to local faults e by
``(I − Wᵀ) r = e``, i.e. for every module i

.. math::  r_i = e_i + \\sum_{k \\to i} W_{ki}\\, r_k .

An *experiment* perturbs one module x (a small fault on its output) and compares
the time-averaged residuals with those of the unperturbed run of the same seed:
``Δr = r(perturbed) − r(nominal)``. Where the perturbation reaches module i only
through modules whose residual is observed, ``Δe_i = 0`` and row i of the model
is a linear equation in the weights of the edges into i:

.. math::  Δr_i = \\sum_{k \\to i} W_{ki}\\, Δr_k .

Modules without a ``residual`` block have no observed r (the runtime gives them
r = 0), so a perturbation that reaches i through such *hidden* modules only —
or that starts at i itself — acts on i as a local fault ``Δe_i ≠ 0``; those
equations are left out (:func:`usable_targets`). The rest are pooled over
experiments and seeds and solved per target module by non-negative least
squares (:func:`fit_target`), with standard errors from the residuals of the
fit and the uncentered R² (the model has no intercept: Δr = 0 is meaningful).

Examples
--------
A chain ``a → b → c`` with W_ab = 0.5, W_bc = 0.4, perturbed at a and at b:

>>> import numpy as np
>>> W = np.array([[0, .5, 0], [0, 0, .4], [0, 0, 0]])
>>> dr = propagate(W, np.eye(3)[:2])          # rows: experiment a, experiment b
>>> fit = fit_target(dr[:, [1]], dr[:, 2])      # c from b, both experiments
>>> round(float(fit.weights[0]), 12), fit.identifiable.tolist()
(0.4, [True])
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from archself.runtime.influence import nnls

__all__ = [
    "EdgeEstimate",
    "TargetFit",
    "delta_residuals",
    "fit_edges",
    "fit_target",
    "propagate",
    "usable_targets",
]


def propagate(W: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Residuals ``r = (I − Wᵀ)⁻¹ e`` of local faults ``e`` (one row per experiment).

    Parameters
    ----------
    W : numpy.ndarray
        n × n, ``W[k, i]`` the weight of the edge k → i, ρ(W) < 1.
    e : numpy.ndarray
        m × n local faults, or a single vector of n.

    Returns
    -------
    numpy.ndarray
        r, the same shape as ``e``.

    Examples
    --------
    >>> propagate(np.array([[0.0, 0.5], [0.0, 0.0]]), np.array([1.0, 0.0])).tolist()
    [1.0, 0.5]
    """
    W = np.asarray(W, dtype=float)
    e = np.asarray(e, dtype=float)
    n = W.shape[0]
    A = np.eye(n) - W.T
    return np.linalg.solve(A, e.T).T


def delta_residuals(
    perturbed: np.ndarray,
    nominal: np.ndarray,
    sensitivity: np.ndarray,
    scale: np.ndarray,
) -> np.ndarray:
    """Δr in the loop's units from time-averaged filtered signals |s̄| of two runs.

    The Monitor's residual (Eq. 12) is ``r_i = sensitivity_i · max(0, |s̄_i| − nominal_i)
    / nominal_i`` (``normalization: nominal``; ``scale`` = nominal) or
    ``sensitivity_i · |s̄_i|`` (``none``; ``scale`` = 1). Its increment is taken on
    the unclipped part, ``sensitivity_i · Δ|s̄_i| / scale_i``: the dead zone below
    the band would hide small perturbations and is not part of the linear model.

    Parameters
    ----------
    perturbed, nominal : numpy.ndarray
        Mean |s̄| per module (last axis), same shape.
    sensitivity, scale : numpy.ndarray
        Per module.

    Examples
    --------
    >>> delta_residuals(np.array([0.3]), np.array([0.2]), np.array([1.0]), np.array([0.1])).round(6)
    array([1.])
    """
    return (
        np.asarray(sensitivity, float)
        * (np.asarray(perturbed, float) - np.asarray(nominal, float))
        / np.asarray(scale, float)
    )


def usable_targets(
    experiment: str,
    observed: Iterable[str],
    edges: Iterable[tuple[str, str]],
) -> set[str]:
    """The observed modules whose equation holds in the experiment that perturbs ``experiment``.

    Module i's equation ``Δr_i = Σ W_ki Δr_k`` needs ``Δe_i = 0``: i is not the
    perturbed module, and no path from it reaches i whose inner modules are all
    hidden (no residual) — including the direct edge when the perturbed module
    itself is hidden. Such a path carries the perturbation past every observed
    residual, which the model cannot see.

    Parameters
    ----------
    experiment : str
        The perturbed module (observed or hidden).
    observed : iterable of str
        The active modules with a residual.
    edges : iterable of (source, target)
        The active edges.

    Returns
    -------
    set of str

    Examples
    --------
    >>> sorted(usable_targets("a", ["a", "b", "c"], [("a", "h"), ("h", "b"), ("b", "c")]))
    ['c']
    >>> sorted(usable_targets("h", ["a", "b", "c"], [("a", "h"), ("h", "b"), ("b", "c")]))
    ['a', 'c']
    >>> sorted(usable_targets("a", ["a", "b"], [("a", "b")]))
    ['b']
    """
    obs = set(observed)
    succ: dict[str, list[str]] = {}
    for s, t in edges:
        succ.setdefault(s, []).append(t)
    reached: set[str] = set()  # observed modules reached through hidden modules only
    seen: set[str] = set()
    # hidden modules the perturbation enters (the start itself when hidden)
    frontier = (
        [experiment]
        if experiment not in obs
        else [t for t in succ.get(experiment, ()) if t not in obs]
    )
    while frontier:
        h = frontier.pop()
        if h in seen:
            continue
        seen.add(h)
        for t in succ.get(h, ()):
            if t in obs:
                reached.add(t)
            elif t not in seen:
                frontier.append(t)
    return obs - reached - {experiment}


@dataclass
class TargetFit:
    """The fit of the weights of the edges into one module.

    Attributes
    ----------
    weights : numpy.ndarray
        Fitted W_ki per source column (NaN where not identifiable).
    se : numpy.ndarray
        Standard errors (NaN where not identifiable or no degrees of freedom left).
    identifiable : numpy.ndarray of bool
        Per source: excited in the usable rows and not collinear with the others.
    rows : int
        Equations used.
    r2 : float
        Uncentered R² ``1 − RSS / Σ Δr_i²`` (NaN without signal).
    rms : float
        Root mean square of the fit's residuals.
    moved : float
        Largest |Δr| of the target in the usable equations (an R² of a target
        that hardly moves says little).
    """

    weights: np.ndarray
    se: np.ndarray
    identifiable: np.ndarray
    rows: int
    r2: float
    rms: float
    moved: float = math.nan


def fit_target(
    X: np.ndarray,
    y: np.ndarray,
    *,
    min_excitation: float = 0.0,
    nonnegative: bool = True,
    rcond: float = 1e-8,
) -> TargetFit:
    """Least-squares fit ``y ≈ X w`` (``w ≥ 0`` by default) with standard errors.

    Parameters
    ----------
    X : numpy.ndarray
        rows × sources: Δr of the sources in the usable equations.
    y : numpy.ndarray
        rows: Δr of the target.
    min_excitation : float
        A source whose largest |Δr| stays at or below this is not identifiable.
    nonnegative : bool
        Non-negative least squares (weights are ≥ 0 in the runtime); else
        ordinary least squares.
    rcond : float
        Sources whose columns are linearly dependent (relative singular value
        below ``rcond``) are not identifiable.

    Returns
    -------
    TargetFit
        Standard errors are ``sqrt(diag(σ² (XᵀX)⁻¹))`` over the identifiable
        sources, σ² = RSS/(rows − p); for a weight at the bound 0 this is the
        error of the unconstrained estimate.

    Examples
    --------
    >>> f = fit_target(np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]]), np.array([0.5, 0.4, 0.7]))
    >>> f.weights.round(6).tolist(), f.se.round(6).tolist(), f.r2
    ([0.5, 0.2], [0.0, 0.0], 1.0)
    >>> fit_target(np.zeros((2, 1)), np.ones(2)).identifiable.tolist()
    [False]
    """
    X = np.asarray(X, dtype=float)
    if X.ndim != 2:  # a 2-D X may have no rows (no usable experiment): (0, p), not (0, -1)
        X = X.reshape(len(y), -1)
    y = np.asarray(y, dtype=float)
    n, p = X.shape
    weights = np.full(p, math.nan)
    se = np.full(p, math.nan)
    excited = np.abs(X).max(axis=0) > min_excitation if n else np.zeros(p, dtype=bool)
    # drop columns that are (near) combinations of others, greedily in column order
    cols: list[int] = []
    for k in np.flatnonzero(excited).tolist():
        s = np.linalg.svd(X[:, cols + [k]], compute_uv=False)
        if s.size and s[-1] > rcond * max(s[0], 1e-300):
            cols.append(k)
    ok = np.zeros(p, dtype=bool)
    ok[cols] = True
    ss = float(y @ y)
    rss = ss
    if cols:
        A = X[:, cols]
        w = nnls(A, y)[0] if nonnegative else np.linalg.lstsq(A, y, rcond=None)[0]
        res = y - A @ w
        rss = float(res @ res)
        dof = n - len(cols)
        if dof > 0:
            cov = (rss / dof) * np.linalg.inv(A.T @ A)
            se[cols] = np.sqrt(np.maximum(np.diag(cov), 0.0))
        weights[cols] = w
    return TargetFit(
        weights,
        se,
        ok,
        n,
        math.nan if ss == 0 else 1.0 - rss / ss,
        math.sqrt(rss / n) if n else math.nan,
        float(np.abs(y).max()) if n else math.nan,
    )


@dataclass
class EdgeEstimate:
    """The estimate of one edge's weight (source → target)."""

    source: str
    target: str
    weight: float
    se: float
    identifiable: bool
    reason: str = ""


def fit_edges(
    dr: np.ndarray,
    experiments: Sequence[str],
    observed: Sequence[str],
    edges: Sequence[tuple[str, str]],
    *,
    min_excitation: float = 0.0,
) -> tuple[list[EdgeEstimate], dict[str, TargetFit]]:
    """Fit every edge's weight from pooled experiments.

    Parameters
    ----------
    dr : numpy.ndarray
        rows × observed: Δr of each (experiment, seed) row.
    experiments : sequence of str
        The perturbed module of each row.
    observed : sequence of str
        The modules of ``dr``'s columns (active, with a residual).
    edges : sequence of (source, target)
        The active edges (pairs; parallel edges counted once).
    min_excitation : float
        See :func:`fit_target` (non-negative least squares).

    Returns
    -------
    (list of EdgeEstimate, dict)
        One estimate per edge, in ``edges`` order, and target -> :class:`TargetFit`
        for the targets with at least one edge from an observed source.

    Examples
    --------
    >>> W = np.array([[0, .5, .3], [0, 0, .2], [0, 0, 0]])
    >>> dr = propagate(W, np.eye(3))
    >>> est, fits = fit_edges(dr, ["a", "b", "c"], ["a", "b", "c"],
    ...                       [("a", "b"), ("a", "c"), ("b", "c"), ("h", "c")])
    >>> [(e.source, e.target, round(e.weight, 9)) for e in est[:3]]
    [('a', 'b', 0.5), ('a', 'c', 0.3), ('b', 'c', 0.2)]
    >>> est[3].identifiable, est[3].reason
    (False, 'source has no residual')
    """
    dr = np.asarray(dr, dtype=float)
    col = {m: k for k, m in enumerate(observed)}
    pairs = list(dict.fromkeys((s, t) for s, t in edges))
    usable = {x: usable_targets(x, observed, pairs) for x in dict.fromkeys(experiments)}
    fits: dict[str, TargetFit] = {}
    sources_of: dict[str, list[str]] = {}
    for s, t in pairs:
        if s in col and t in col:
            sources_of.setdefault(t, []).append(s)
    out_of: dict[tuple[str, str], EdgeEstimate] = {}
    for t, srcs in sources_of.items():
        rows = [r for r, x in enumerate(experiments) if t in usable[x]]
        X = dr[np.ix_(rows, [col[s] for s in srcs])]
        y = dr[rows, col[t]]
        fits[t] = fit = fit_target(X, y, min_excitation=min_excitation)
        for k, s in enumerate(srcs):
            ident = bool(fit.identifiable[k])
            if ident:
                why = ""
            elif not rows:
                why = "no usable experiment"
            elif not np.abs(X[:, k]).max(initial=0.0) > min_excitation:
                why = "source not excited"
            else:
                why = "collinear with another source"
            out_of[(s, t)] = EdgeEstimate(s, t, float(fit.weights[k]), float(fit.se[k]), ident, why)
    for s, t in pairs:
        if (s, t) not in out_of:
            why = "target has no residual" if t not in col else "source has no residual"
            if s not in col and t not in col:
                why = "neither end has a residual"
            out_of[(s, t)] = EdgeEstimate(s, t, math.nan, math.nan, False, why)
    return [out_of[e] for e in pairs], fits
