"""Dependency-weighted influence propagation (paper Eq. 13–15).

The architecture graph G = (M, Γ) gives a weighted adjacency matrix ``W`` with
``W[j, i] = ω_ji`` the influence of module m_j on module m_i, i.e. the weight of
the edge ``j → i`` (Eq. 13). Local residuals ``r`` propagate through the graph as

.. math::  z = (I - W^T)^{-1} r                                    \\qquad (14)

Row ``i`` of ``(I - Wᵀ) z = r`` reads ``z_i = r_i + Σ_j W_ji z_j``: the influence
of module ``i`` is its own residual plus the influence of every module ``j``
*upstream* of it (``j → i``), weighted by the edge. Expanding the inverse as the
Neumann series ``I + Wᵀ + (Wᵀ)² + …`` (Eq. 15) shows that ``z_i`` sums the
residuals of all modules from which a directed path leads to ``i``, each
multiplied by the product of the weights along the path. A residual therefore
flows *downstream*, in the direction of the edges: on a chain ``a → b → c`` with
a residual only at ``a``, ``z_c = ω_ab · ω_bc · r_a``.

The solve never forms an inverse: ``I - Wᵀ`` is LU-factorized once (dense
:func:`scipy.linalg.lu_factor` for small graphs, sparse
:func:`scipy.sparse.linalg.splu` for large ones) and the factorization is reused
for as long as ``W`` is unchanged (:class:`InfluenceSolver`).

scipy is imported where a function needs it: ρ(W) and the singularity test of a
small dense W (:func:`spectral_radius`, :func:`is_singular`, used by
``archself validate``) need numpy only.
"""

from __future__ import annotations

import math
import sys
import warnings
from collections.abc import Hashable, Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    import scipy.sparse

__all__ = [
    "DENSE_MAX",
    "InfluenceSolver",
    "influence",
    "is_singular",
    "matrix_key",
    "spectral_radius",
    "weight_matrix",
]

#: Graphs with at most this many modules are handled with dense linear algebra.
DENSE_MAX = 400
#: A pivot of the LU of ``I − Wᵀ`` at most this times the largest (or 1) makes it singular.
PIVOT_RTOL = 1e-12


def _issparse(W: Any) -> bool:
    """Whether ``W`` is a scipy.sparse matrix (without importing scipy: if it is not
    imported, nothing can be one)."""
    sparse = sys.modules.get("scipy.sparse")
    return sparse is not None and bool(sparse.issparse(W))


def weight_matrix(
    names: Sequence[str],
    edges: Iterable[tuple[str, str, float]],
    *,
    scale: float = 1.0,
    allow_negative: bool = False,
) -> scipy.sparse.csr_matrix:
    """Weighted adjacency matrix W of Eq. 13 as a sparse CSR matrix.

    Parameters
    ----------
    names : sequence of str
        The modules, in index order (row/column ``k`` is ``names[k]``).
    edges : iterable of (source, target, weight)
        The active edges ``source → target`` with weight ``ω ≥ 0``. Edges whose
        ends are not in ``names`` are ignored; parallel edges add up.
    scale : float, optional
        Factor applied to every weight (used to normalize ``ρ(W) < 1``).
    allow_negative : bool, optional
        Keep negative weights instead of raising (``archself validate`` measures
        ρ(W) of a file whose negative weight it reports).

    Returns
    -------
    scipy.sparse.csr_matrix
        ``W`` with ``W[j, i]`` the weight of the edge ``names[j] → names[i]``.

    Raises
    ------
    ValueError
        If a weight is not finite, or negative (unless ``allow_negative``).

    Examples
    --------
    >>> W = weight_matrix(["a", "b"], [("a", "b", 0.5)])
    >>> W.toarray()
    array([[0. , 0.5],
           [0. , 0. ]])
    """
    index = {name: k for k, name in enumerate(names)}
    rows: list[int] = []
    cols: list[int] = []
    data: list[float] = []
    for source, target, weight in edges:
        w = float(weight)
        if not np.isfinite(w) or (w < 0 and not allow_negative):
            raise ValueError(f"edge {source} -> {target}: weight must be finite and >= 0, got {w}")
        if source in index and target in index:
            rows.append(index[source])
            cols.append(index[target])
            data.append(w * scale)
    import scipy.sparse

    n = len(names)
    W = scipy.sparse.coo_matrix((data, (rows, cols)), shape=(n, n), dtype=float)
    return W.tocsr()  # duplicates are summed


def spectral_radius(W: Any, *, dense_max: int = DENSE_MAX, tol: float = 1e-9) -> float:
    """Spectral radius ρ(W) = max |λ(W)|.

    Parameters
    ----------
    W : array_like or scipy.sparse matrix
        Square matrix.
    dense_max : int, optional
        Up to this size the eigenvalues are computed densely.
    tol : float, optional
        Tolerance of the iterative estimate for large matrices.

    Returns
    -------
    float
        ρ(W). Large matrices are split into strongly connected components
        (the eigenvalues of a matrix are those of its diagonal SCC blocks):
        acyclic parts contribute 0, small components are solved densely and large
        ones with ARPACK (:func:`scipy.sparse.linalg.eigs`), falling back to a
        Gelfand power-iteration estimate (``‖W^k x‖^{1/k}``) if ARPACK fails.

    Examples
    --------
    >>> round(spectral_radius([[0.0, 0.5], [0.5, 0.0]]), 6)
    0.5
    """
    sparse = _issparse(W)
    n = W.shape[0] if sparse else np.shape(W)[0]
    if n == 0:
        return 0.0
    if n <= dense_max:
        dense = W.toarray() if sparse else np.asarray(W, dtype=float)
        if not np.any(dense):
            return 0.0
        return float(np.max(np.abs(np.linalg.eigvals(dense))))
    import scipy.sparse
    import scipy.sparse.csgraph
    import scipy.sparse.linalg

    S = scipy.sparse.csr_matrix(W, dtype=float)
    S.eliminate_zeros()
    ncomp, labels = scipy.sparse.csgraph.connected_components(S, directed=True, connection="strong")
    diag = S.diagonal()
    if ncomp == n:  # acyclic apart from self-loops: triangular up to a permutation
        return float(np.max(np.abs(diag)))
    sizes = np.bincount(labels, minlength=ncomp)
    rho = float(np.max(np.abs(diag[sizes[labels] == 1]), initial=0.0))
    for comp in np.flatnonzero(sizes > 1):
        idx = np.flatnonzero(labels == comp)
        block = S[idx][:, idx]
        if idx.size <= dense_max:
            value = float(np.max(np.abs(np.linalg.eigvals(block.toarray()))))
        else:
            bound = float(min(abs(block).sum(axis=1).max(), abs(block).sum(axis=0).max()))
            try:
                vals = scipy.sparse.linalg.eigs(
                    block, k=1, which="LM", tol=tol, return_eigenvectors=False, maxiter=5000
                )
                value = float(np.abs(vals).max())
            except (scipy.sparse.linalg.ArpackNoConvergence, scipy.sparse.linalg.ArpackError):
                value = _gelfand_estimate(block, bound)
        rho = max(rho, value)
    return rho


def _gelfand_estimate(A: scipy.sparse.csr_matrix, bound: float, iters: int = 200) -> float:
    """ρ(A) ≈ ‖A^k x‖^{1/k} for a positive start vector (Gelfand's formula)."""
    n = A.shape[0]
    x = np.ones(n) / np.sqrt(n)
    log_norm = 0.0
    est = bound
    for k in range(1, iters + 1):
        x = A @ x
        nrm = float(np.linalg.norm(x))
        if nrm == 0.0:
            return 0.0  # nilpotent along this start vector: all paths die out
        log_norm += np.log(nrm)
        x /= nrm
        est = float(np.exp(log_norm / k))
    return min(est, bound)


def _block_triangular_order(S: scipy.sparse.spmatrix) -> np.ndarray | None:
    """Module order with every edge ``j → i`` going forward between strong components.

    The strong components of :func:`scipy.sparse.csgraph.connected_components`
    are numbered in reverse topological order (Tarjan/Pearce); sorting by
    descending label puts sources first, so ``I − Wᵀ`` permuted symmetrically is
    block lower triangular. Verified on the edges; None if it does not hold.
    """
    import scipy.sparse
    import scipy.sparse.csgraph

    C = scipy.sparse.coo_matrix(S)
    _, labels = scipy.sparse.csgraph.connected_components(C, directed=True, connection="strong")
    src, dst = labels[C.row], labels[C.col]
    if np.any(src < dst):  # not the documented order: let SuperLU choose (COLAMD)
        return None
    return np.argsort(-labels, kind="stable")


def singular_pivots(pivots: np.ndarray) -> bool:
    """The rule: ``I − Wᵀ`` is singular (or numerically so) when a pivot of its LU is
    at most :data:`PIVOT_RTOL` times the largest pivot (or 1).

    One rule for every solver: the runtime's dense (LAPACK) and sparse (SuperLU)
    factorizations and the numpy one of :func:`is_singular`. Weights like 1e9 beside
    0.1 give pivots ~1e-18 of the largest: ρ(W) < 1, but no solve is meaningful.

    Examples
    --------
    >>> singular_pivots(np.array([1.0, 0.5])), singular_pivots(np.array([1e9, 1e-4]))
    (False, True)
    """
    return bool(len(pivots)) and float(pivots.min()) <= PIVOT_RTOL * max(1.0, float(pivots.max()))


def lu_pivots(M: np.ndarray) -> np.ndarray:
    """``|u_kk|`` of the LU factorization of ``M`` with partial pivoting, in numpy.

    The algorithm of LAPACK's ``getrf`` (row of the largest entry of the column
    as pivot, rank-one updates), so the pivots are LAPACK's up to rounding; a zero
    column below the diagonal gives a zero pivot (``getrf``'s ``info > 0``).

    Examples
    --------
    >>> lu_pivots(np.array([[1.0, 2.0], [3.0, 4.0]])).round(12).tolist()
    [3.0, 0.666666666667]
    """
    A = np.array(M, dtype=float)
    n = A.shape[0]
    out = np.empty(n)
    for k in range(n):
        p = k + int(np.argmax(np.abs(A[k:, k])))
        if p != k:
            A[[k, p], k:] = A[[p, k], k:]
        pivot = A[k, k]
        out[k] = abs(pivot)
        if pivot != 0.0 and k + 1 < n:
            A[k + 1:, k + 1:] -= np.outer(A[k + 1:, k] / pivot, A[k, k + 1:])
    return out


def is_singular(W: Any, *, dense_max: int = DENSE_MAX) -> bool:
    """Whether ``I − Wᵀ`` is singular, or numerically so (:func:`singular_pivots`).

    The runtime's verdict without its solver: up to ``dense_max`` modules the pivots
    of :func:`lu_pivots` (numpy only, no scipy import), above it the sparse
    factorization :class:`InfluenceSolver` uses (scipy, imported then).

    Examples
    --------
    >>> is_singular(np.array([[0.0, 1.0], [1.0, 0.0]])), is_singular(np.zeros((2, 2)))
    (True, False)
    """
    n = W.shape[0] if _issparse(W) else np.shape(W)[0]
    if n == 0:
        return False
    if n <= dense_max:
        dense = W.toarray() if _issparse(W) else np.asarray(W, dtype=float)
        return singular_pivots(lu_pivots(np.eye(n) - dense.T))
    try:
        InfluenceSolver(dense_max).set_matrix(W, key=0)
    except np.linalg.LinAlgError:
        return True
    return False


def matrix_key(W: Any) -> Hashable:
    """A hashable fingerprint of a matrix's sparsity pattern and values."""
    if _issparse(W):
        C = W.tocsr(copy=True)
        C.sum_duplicates()
        C.sort_indices()
        return (C.shape, C.indptr.tobytes(), C.indices.tobytes(), C.data.tobytes())
    A = np.ascontiguousarray(W, dtype=float)
    return (A.shape, A.tobytes())


class InfluenceSolver:
    """Solves ``(I − Wᵀ) z = r`` (Eq. 14) with a cached LU factorization.

    The factorization of ``I − Wᵀ`` is computed by :meth:`set_matrix` and kept
    until a matrix with a different key arrives, so a MAPE-K loop whose active
    edge set does not change factorizes once and then only back-substitutes.

    Parameters
    ----------
    dense_max : int, optional
        Graphs with at most this many nodes use dense LU
        (:func:`scipy.linalg.lu_factor`); larger ones sparse LU
        (:func:`scipy.sparse.linalg.splu`).

    Attributes
    ----------
    factorizations : int
        How many times a factorization was computed (for tests and profiling).
    key : hashable or None
        Key of the matrix currently factorized.

    Examples
    --------
    >>> import numpy as np
    >>> W = weight_matrix(["a", "b", "c"], [("a", "b", 0.5), ("b", "c", 0.4)])
    >>> solver = InfluenceSolver()
    >>> solver.set_matrix(W, key="chain")   # factorizes
    True
    >>> solver.solve(np.array([1.0, 0.0, 0.0])).round(6).tolist()
    [1.0, 0.5, 0.2]
    """

    def __init__(self, dense_max: int = DENSE_MAX) -> None:
        self.dense_max = dense_max
        self.factorizations = 0
        self.key: Hashable | None = None
        self.n = 0
        self._dense: tuple[np.ndarray, np.ndarray] | None = None
        self._sparse: Any = None
        self._order: np.ndarray | None = None
        self._getrs: Any = None

    def set_matrix(self, W: Any, key: Hashable | None = None) -> bool:
        """Use ``W``; refactorize only if its key differs from the current one.

        Parameters
        ----------
        W : array_like or scipy.sparse matrix
            The weighted adjacency matrix (``W[j, i]`` = weight of ``j → i``).
        key : hashable, optional
            Identifies ``W`` (e.g. the frozenset of active edges). Default: a
            fingerprint of the matrix itself (:func:`matrix_key`).

        Returns
        -------
        bool
            True when a new factorization was computed.

        Raises
        ------
        numpy.linalg.LinAlgError
            If ``I − Wᵀ`` is singular.
        """
        if key is None:
            key = matrix_key(W)
        if key == self.key and (self._dense is not None or self._sparse is not None):
            return False
        n = W.shape[0]
        if n <= self.dense_max:
            import scipy.linalg

            dense = W.toarray() if _issparse(W) else np.asarray(W, dtype=float)
            M = np.eye(n) - dense.T
            if n == 0:
                self._dense = (np.zeros((0, 0)), np.zeros(0, dtype=np.int32))
            else:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
                    lu, piv = scipy.linalg.lu_factor(M, check_finite=True)
                if singular_pivots(np.abs(np.diag(lu))):
                    raise np.linalg.LinAlgError("I - W^T is singular")
                self._dense = (lu, piv)
                # LAPACK getrs, the routine lu_solve calls, without its per-call checks
                (self._getrs,) = scipy.linalg.get_lapack_funcs(("getrs",), (lu,))
            self._sparse = None
        else:
            import scipy.sparse
            import scipy.sparse.linalg

            S = scipy.sparse.csc_matrix(W, dtype=float)
            M = (scipy.sparse.identity(n, format="csc") - S.T).tocsc()
            # Scale fix: SuperLU's default COLAMD ordering took minutes on a 10^5-module
            # DAG. Ordered by the strongly connected components in topological order,
            # I - W^T is block lower triangular, so the natural ordering has no fill-in
            # outside the (small) cyclic blocks: ~0.1 s at 10^5 modules.
            order = _block_triangular_order(S)
            try:
                if order is None:
                    self._sparse = scipy.sparse.linalg.splu(M)
                else:
                    P = M[order][:, order].tocsc()
                    self._sparse = scipy.sparse.linalg.splu(
                        P, permc_spec="NATURAL", diag_pivot_thresh=0.1
                    )
            except RuntimeError as exc:  # "Factor is exactly singular"
                raise np.linalg.LinAlgError(f"I - W^T is singular: {exc}") from exc
            if singular_pivots(np.abs(self._sparse.U.diagonal())):
                raise np.linalg.LinAlgError("I - W^T is singular")
            self._order = order
            self._dense = None
        self.key = key
        self.n = n
        self.factorizations += 1
        return True

    def solve(self, r: Any) -> np.ndarray:
        """Aggregated influence ``z = (I − Wᵀ)⁻¹ r`` for the current matrix.

        Parameters
        ----------
        r : array_like, shape (n,)
            Local residuals, in the index order of ``W``.

        Returns
        -------
        numpy.ndarray, shape (n,)
            The influence vector ``z``.
        """
        r = np.asarray(r, dtype=float).ravel()
        if self._dense is None and self._sparse is None:
            raise RuntimeError("InfluenceSolver.solve called before set_matrix")
        if r.shape != (self.n,):
            raise ValueError(f"r has shape {r.shape}, expected ({self.n},)")
        if self.n == 0:
            return np.zeros(0)
        if self._dense is not None:
            if not math.isfinite(sum(r.tolist())):  # what lu_solve's check_finite reports
                raise ValueError("array must not contain infs or NaNs")
            lu, piv = self._dense
            z, info = self._getrs(lu, piv, r, trans=0, overwrite_b=False)
            if info != 0:
                raise ValueError(f"illegal value in {-info}th argument of internal getrs")
            return np.asarray(z)
        if self._order is None:
            return np.asarray(self._sparse.solve(r))
        z = np.empty(self.n)
        z[self._order] = self._sparse.solve(r[self._order])
        return z


def influence(W: Any, r: Any) -> np.ndarray:
    """One-shot ``z = (I − Wᵀ)⁻¹ r`` (Eq. 14) by LU factorization.

    Examples
    --------
    >>> W = weight_matrix(["a", "b", "c"], [("a", "b", 0.5), ("b", "c", 0.4)])
    >>> influence(W, [0.0, 0.0, 1.0]).tolist()   # a residual at c stays at c
    [0.0, 0.0, 1.0]
    """
    solver = InfluenceSolver()
    solver.set_matrix(W, key=0)
    return solver.solve(r)
