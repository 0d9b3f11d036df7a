"""Root-cause localization: the local faults e that explain the residuals r.

The paper's influence (Eq. 14), ``z = (I − Wᵀ)⁻¹ r``, accumulates residuals along
the edges: on a chain ``a → b → c`` a fault at ``a`` that also shows in the
residuals of ``b`` and ``c`` gives its largest ``z`` at ``c``, the end of the
chain. Read as a model of the data instead (the one ``archself identify`` fits
W with), the same equation says how *local faults* ``e ≥ 0`` spread into the
residuals:

.. math::  r = (I - W^T)^{-1} e \\quad\\Longleftrightarrow\\quad
           e_i = r_i - \\sum_{j \\to i} W_{ji}\\, r_j .

Row ``i``: a module's own fault is its residual minus what its upstream modules'
residuals explain through the edges. The **source estimate** inverts the
propagation instead of applying it once more:

- ``ê = max(0, (I − Wᵀ) r)`` when every module's residual is observed: exact
  when ``r`` follows the model, one sparse product per cycle. A module's
  estimate never exceeds its own residual, and a residual its upstream explains
  (a downstream echo of the fault, or less than W predicts, as the nominal noise
  bands make it) gives 0 rather than a negative source.
- **Hidden modules.** A module without a ``residual`` block (a plant, a sensor)
  has no observed residual: the runtime gives it ``r = 0``, which would cut every
  chain at it (heater → *zone* → *sensor* → observer: the observer's residual
  would look like its own fault). Its residual is unknown, not zero, so it is
  filled in with the echo the observed residuals predict,
  ``x_H = (I − W_HHᵀ)⁻¹ (r_H + W_OHᵀ r_O)`` (``O`` observed, ``H`` hidden), and the
  observed modules' sources are ``ê_O = max(0, r_O − (Wᵀ x)_O)``: the
  elimination of the hidden modules (a Schur complement), solved with the same
  reused factorization as z (:class:`~archself.runtime.influence.InfluenceSolver`
  on ``W_HH``), so 10^5 modules cost one back-substitution per cycle. A hidden
  module's own source is its own residual (non-zero only when the system reports
  it unavailable).
- :func:`source_nnls` — the non-negative least-squares fit
  ``min ‖((I − Wᵀ)⁻¹)_OO e_O − r_O‖₂, e_O ≥ 0`` (:func:`scipy.optimize.nnls` on
  the dense propagation matrix; for comparison, up to a few hundred modules).
  Where the residuals downstream of a fault are *smaller* than W predicts, it
  lowers the estimate at the fault to fit them too, so the head of a chain
  scores below its own residual.

``bench/localization.py`` compares the estimates (and a sparse, L1-penalized fit)
with the paper's z on noisy residuals; docs/localization.md has the figures and
why the runtime uses :class:`SourceEstimator` for ``runtime.localization: source``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.optimize
import scipy.sparse

from archself.runtime.influence import InfluenceSolver

__all__ = ["SourceEstimator", "propagation_matrix", "source_estimate", "source_nnls"]


def _mask(observed: Any, n: int) -> np.ndarray:
    """Boolean observed-mask of length ``n`` (None: every module observed)."""
    if observed is None:
        return np.ones(n, dtype=bool)
    mask = np.asarray(observed, dtype=bool).ravel()
    if mask.shape != (n,):
        raise ValueError(f"observed has shape {mask.shape}, expected ({n},)")
    return mask


class SourceEstimator:
    """The source estimate ê for one W, with the hidden modules eliminated once.

    Parameters
    ----------
    W : array_like or scipy.sparse matrix, shape (n, n)
        Weighted adjacency matrix, ``W[j, i]`` the weight of the edge ``j → i``
        (Eq. 13).
    observed : array_like of bool, shape (n,), optional
        Which modules' residuals are observed (a ``residual`` block); the others
        are hidden. Default: all observed.

    Examples
    --------
    A fault at the head of heater → zone → sensor → observer, where only the
    heater and the observer carry a residual (zone and sensor are hidden):

    >>> from archself.runtime.influence import weight_matrix, influence
    >>> names = ["heater", "zone", "sensor", "observer"]
    >>> W = weight_matrix(names, [("heater", "zone", 0.8), ("zone", "sensor", 0.9),
    ...                           ("sensor", "observer", 0.7)])
    >>> r = [1.0, 0.0, 0.0, 0.5]                  # the observer sees the fault's echo
    >>> influence(W, r).round(3).tolist()         # the paper's z: largest at the observer
    [1.0, 0.8, 0.72, 1.004]
    >>> est = SourceEstimator(W, observed=[True, False, False, True])
    >>> est.estimate(r).round(3).tolist()         # the source: the heater
    [1.0, 0.0, 0.0, 0.0]
    >>> source_estimate(W, r).round(3).tolist()   # hidden residuals taken as 0: wrong
    [1.0, 0.0, 0.0, 0.5]
    """

    def __init__(self, W: Any, observed: Any = None) -> None:
        S = scipy.sparse.csr_matrix(W, dtype=float)
        n = S.shape[0]
        self.n = n
        self.observed = _mask(observed, n)
        self.hidden_index = np.flatnonzero(~self.observed)
        self.observed_index = np.flatnonzero(self.observed)
        self._WT = S.T.tocsr()
        self._solver: InfluenceSolver | None = None
        if self.hidden_index.size:
            h, o = self.hidden_index, self.observed_index
            self._solver = InfluenceSolver()
            self._solver.set_matrix(S[h][:, h], key=0)
            self._W_OH_T = S[o][:, h].T.tocsr()

    def estimate(self, r: Any) -> np.ndarray:
        """``ê``: observed modules ``max(0, r_O − (Wᵀ x)_O)``, hidden ones their own ``r``.

        Parameters
        ----------
        r : array_like, shape (n,)
            Module residuals (Eq. 12), hidden modules' usually 0.

        Returns
        -------
        numpy.ndarray, shape (n,)
            The estimated local faults, ``≥ 0`` for ``r ≥ 0``.

        Raises
        ------
        ValueError
            If ``r`` does not have one value per module or is not finite.
        """
        r = np.asarray(r, dtype=float).ravel()
        if r.shape != (self.n,):
            raise ValueError(f"r has shape {r.shape}, expected ({self.n},)")
        if not np.all(np.isfinite(r)):
            raise ValueError("r must be finite")
        if not r.any():
            # Nothing to explain (most cycles: residuals inside their bands are 0). Each
            # (Wᵀ x)_i sums from +0.0, so r − Wᵀ x is r here: the same bits as the full path.
            e = r.copy()
            np.maximum(e, 0.0, out=e)
            e[self.hidden_index] = r[self.hidden_index]
            return e
        return self._estimate_full(r)

    def _estimate_full(self, r: np.ndarray) -> np.ndarray:
        """:meth:`estimate` of a checked ``r`` (float array of shape (n,)), without shortcut."""
        x = r
        if self._solver is not None:
            h, o = self.hidden_index, self.observed_index
            x = r.copy()
            x[h] = self._solver.solve(r[h] + self._W_OH_T @ r[o])
        e = r - self._WT @ x
        np.maximum(e, 0.0, out=e)
        if self._solver is not None:
            e[self.hidden_index] = r[self.hidden_index]
        return e


def source_estimate(W: Any, r: Any, observed: Any = None) -> np.ndarray:
    """One-shot source estimate (:class:`SourceEstimator`).

    With every module observed, ``ê = max(0, (I − Wᵀ) r)``: module ``i``'s
    residual minus what its upstream residuals explain.

    Parameters
    ----------
    W : array_like or scipy.sparse matrix, shape (n, n)
        Weighted adjacency matrix, ``W[j, i]`` the weight of the edge ``j → i``.
    r : array_like, shape (n,)
        Module residuals (Eq. 12), in the index order of ``W``.
    observed : array_like of bool, shape (n,), optional
        Modules with an observed residual; default all.

    Returns
    -------
    numpy.ndarray, shape (n,)
        The estimated local faults; :func:`~archself.runtime.influence.influence`
        of them gives ``r`` back wherever nothing was clipped (all observed).

    Examples
    --------
    A fault at the head of the chain a → b → c, its echoes downstream as W says:

    >>> from archself.runtime.influence import weight_matrix, influence
    >>> W = weight_matrix(["a", "b", "c"], [("a", "b", 0.5), ("b", "c", 0.8)])
    >>> r = [1.0, 0.5, 0.4]
    >>> influence(W, r).round(3).tolist()        # the paper's z: largest at c
    [1.0, 1.0, 1.2]
    >>> source_estimate(W, r).round(3).tolist()  # the source: a
    [1.0, 0.0, 0.0]
    """
    return SourceEstimator(W, observed).estimate(r)


def propagation_matrix(W: Any) -> np.ndarray:
    """The dense ``(I − Wᵀ)⁻¹`` (column ``j``: the residuals a unit fault at ``j`` gives).

    Examples
    --------
    >>> propagation_matrix([[0.0, 0.5], [0.0, 0.0]]).tolist()
    [[1.0, 0.0], [0.5, 1.0]]
    """
    dense = W.toarray() if scipy.sparse.issparse(W) else np.asarray(W, dtype=float)
    n = dense.shape[0]
    return np.linalg.solve(np.eye(n) - dense.T, np.eye(n))


def source_nnls(W: Any, r: Any, observed: Any = None) -> np.ndarray:
    """Non-negative least squares ``argmin_{e_O ≥ 0} ‖P_OO e_O − r_O‖₂``, ``P = (I − Wᵀ)⁻¹``.

    Dense (``O(n³)``): for comparison with :class:`SourceEstimator` on graphs of
    up to a few hundred modules, not for the runtime.

    Parameters
    ----------
    W : array_like or scipy.sparse matrix, shape (n, n)
        Weighted adjacency matrix (Eq. 13).
    r : array_like, shape (n,)
        Module residuals.
    observed : array_like of bool, shape (n,), optional
        Modules with an observed residual (the fit's rows and unknowns); default
        all. Hidden modules get their own residual, as in :class:`SourceEstimator`.

    Returns
    -------
    numpy.ndarray, shape (n,)
        The fitted local faults ``e ≥ 0``; equal to :func:`source_estimate`
        whenever nothing is clipped there.

    Examples
    --------
    The downstream residual is smaller than W predicts (0.2 < 0.5 · 1.0): the
    fit lowers the head to match it, the clipped inverse keeps the head's own
    residual.

    >>> W = [[0.0, 0.5], [0.0, 0.0]]
    >>> source_nnls(W, [1.0, 0.2]).round(3).tolist()
    [0.88, 0.0]
    >>> source_estimate(np.array(W), [1.0, 0.2]).tolist()
    [1.0, 0.0]
    """
    r = np.asarray(r, dtype=float).ravel()
    P = propagation_matrix(W)
    n = P.shape[0]
    if r.shape != (n,):
        raise ValueError(f"r has shape {r.shape}, expected ({n},)")
    mask = _mask(observed, n)
    e = np.where(mask, 0.0, r)
    o = np.flatnonzero(mask)
    if o.size:
        e[o], _ = scipy.optimize.nnls(P[np.ix_(o, o)], r[o])
    return e
