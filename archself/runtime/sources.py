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

- :func:`source_estimate` — ``ê = max(0, (I − Wᵀ) r)``, exact when ``r`` follows
  the model, one sparse product per cycle (O(edges), no factorization: 10^5
  modules in about a millisecond). A module's estimate never exceeds its own
  residual, and a residual that its upstream explains (a downstream echo of
  the fault, or less than W predicts, as the nominal noise bands make it) gives
  0 rather than a negative source.
- :func:`source_nnls` — the non-negative least-squares fit
  ``min ‖(I − Wᵀ)⁻¹ e − r‖₂, e ≥ 0`` (:func:`scipy.optimize.nnls` on the dense
  propagation matrix; for comparison, up to a few hundred modules). Where the
  residuals downstream of a fault are *smaller* than W predicts, it lowers the
  estimate at the fault to fit them too, so the head of a chain scores below
  its own residual.

``bench/localization.py`` compares the two (and a sparse, L1-penalized fit) with
the paper's z on noisy residuals; docs/localization.md has the figures and why
the runtime uses :func:`source_estimate` for ``runtime.localization: source``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.optimize
import scipy.sparse

__all__ = ["propagation_matrix", "source_estimate", "source_nnls"]


def _transpose_product(W: Any, r: np.ndarray) -> np.ndarray:
    """``Wᵀ r`` for a dense or sparse ``W``."""
    if scipy.sparse.issparse(W):
        return np.asarray(W.T @ r, dtype=float).ravel()
    return np.asarray(W, dtype=float).T @ r


def source_estimate(W: Any, r: Any) -> np.ndarray:
    """Local faults ``ê = max(0, (I − Wᵀ) r)`` that explain the residuals ``r``.

    Parameters
    ----------
    W : array_like or scipy.sparse matrix, shape (n, n)
        Weighted adjacency matrix, ``W[j, i]`` the weight of the edge ``j → i``
        (Eq. 13).
    r : array_like, shape (n,)
        Module residuals (Eq. 12), in the index order of ``W``.

    Returns
    -------
    numpy.ndarray, shape (n,)
        ``ê_i = max(0, r_i − Σ_j W_ji r_j)``: module ``i``'s residual minus what
        its upstream residuals explain. :func:`archself.runtime.influence.influence`
        of ``ê`` gives ``r`` back wherever no component was clipped.

    Raises
    ------
    ValueError
        If ``r`` does not have one value per module or is not finite.

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
    r = np.asarray(r, dtype=float).ravel()
    if r.shape != (W.shape[0],):
        raise ValueError(f"r has shape {r.shape}, expected ({W.shape[0]},)")
    if not np.all(np.isfinite(r)):
        raise ValueError("r must be finite")
    e = r - _transpose_product(W, r)
    np.maximum(e, 0.0, out=e)
    return e


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


def source_nnls(W: Any, r: Any) -> np.ndarray:
    """Non-negative least squares ``argmin_{e ≥ 0} ‖(I − Wᵀ)⁻¹ e − r‖₂``.

    Dense (``O(n³)``): for comparison with :func:`source_estimate` on graphs of
    up to a few hundred modules, not for the runtime.

    Parameters
    ----------
    W : array_like or scipy.sparse matrix, shape (n, n)
        Weighted adjacency matrix (Eq. 13).
    r : array_like, shape (n,)
        Module residuals.

    Returns
    -------
    numpy.ndarray, shape (n,)
        The fitted local faults ``e ≥ 0``; equal to :func:`source_estimate`
        whenever ``(I − Wᵀ) r ≥ 0``.

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
    A = propagation_matrix(W)
    if r.shape != (A.shape[0],):
        raise ValueError(f"r has shape {r.shape}, expected ({A.shape[0]},)")
    if A.shape[0] == 0:
        return np.zeros(0)
    e, _ = scipy.optimize.nnls(A, r)
    return np.asarray(e, dtype=float)
