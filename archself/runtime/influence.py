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

The solve is prepared once and reused for as long as ``W`` is unchanged
(:class:`InfluenceSolver`): up to :data:`SOLVE_DENSE_MAX` modules the dense
``P = (I − Wᵀ)⁻¹`` (:func:`propagation_matrix`, numpy's LAPACK ``gesv``; each
solve is then one product ``P r``), above it a sparse LU of ``I − Wᵀ``
(:func:`scipy.sparse.linalg.splu`, never an inverse).

scipy is imported only above those sizes: a small system's run path (W, ρ(W),
the singularity test, the solves, the source fit and its non-negative least
squares, :func:`nnls`) and ``archself validate`` need numpy only. Dense numpy is
also the faster tool there (docs/benchmarks.md, "Start-up").

Root-cause localization: the local faults e that explain the residuals r.

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
  chain at it (heater → *room* → *sensor* → observer: the observer's residual
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
  ``min ‖((I − Wᵀ)⁻¹)_OO e_O − r_O‖₂, e_O ≥ 0`` (:func:`nnls` on
  the dense propagation matrix; for comparison, up to a few hundred modules).
  Where the residuals downstream of a fault are *smaller* than W predicts, it
  lowers the estimate at the fault to fit them too, so the head of a chain
  scores below its own residual.

- :class:`SourceFit` (``runtime.localization: fit``, the default) — few
  non-negative local faults on observed *and hidden* modules that explain the
  observed residuals, with an identifiability rule (collinear columns of the
  observed propagation matrix form one class of equivalent candidates) and a
  parsimony rule (one, two, then all sources). The clipped inverse fixes a hidden
  module's estimate at its own residual (0), so a heater without a residual at the
  head of a loop is never a candidate there; the fit finds it.

``bench/localization.py`` compares the estimates (and a sparse, L1-penalized fit)
with the paper's z on noisy residuals, hidden sources included; docs/localization.md
has the figures and where each fails.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Hashable, Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    import scipy.sparse

__all__ = [
    "DENSE_MAX",
    "NNLS_NUMPY_MAX",
    "SOLVE_DENSE_MAX",
    "InfluenceSolver",
    "SourceEstimator",
    "SourceFit",
    "influence",
    "is_singular",
    "is_sparse",
    "matrix_key",
    "nnls",
    "propagation_matrix",
    "source_estimate",
    "source_nnls",
    "spectral_radius",
    "weight_matrix",
]

#: Graphs with at most this many modules are handled with dense linear algebra.
DENSE_MAX = 400
#: :class:`InfluenceSolver` keeps the dense ``(I − Wᵀ)⁻¹`` up to this many modules (numpy:
#: ≤ 0.8 ms per factorization, its pivots included; 9 ms at 100, 108 ms at 400, where
#: SuperLU takes 0.3 and 1.4 ms), SuperLU above. bench/dense_bounds.py measures both.
SOLVE_DENSE_MAX = 64
#: Non-negative least squares with at most this many unknowns are solved in numpy
#: (:func:`nnls`; ≤ 0.3 ms a call, scipy's C 15 µs at 16, 4 ms against 0.18 ms at 64),
#: larger ones by :func:`scipy.optimize.nnls`.
NNLS_NUMPY_MAX = 16
#: A pivot of the LU of ``I − Wᵀ`` at most this times the largest (or 1) makes it singular.
PIVOT_RTOL = 1e-12


def is_sparse(W: Any) -> bool:
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
    dense_max: int = -1,
) -> np.ndarray | scipy.sparse.csr_matrix:
    """Weighted adjacency matrix W of Eq. 13: sparse CSR, or dense up to ``dense_max``.

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
    dense_max : int, optional
        Up to this many modules W is a dense numpy array (no scipy import; the
        runtime passes :data:`DENSE_MAX`); default: always sparse.

    Returns
    -------
    numpy.ndarray or scipy.sparse.csr_matrix
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
    n = len(names)
    if n <= dense_max:
        dense = np.zeros((n, n))
        np.add.at(dense, (rows, cols), data)  # parallel edges add up, in their order
        return dense
    import scipy.sparse

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
    sparse = is_sparse(W)
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
    n = W.shape[0] if is_sparse(W) else np.shape(W)[0]
    if n == 0:
        return False
    if n <= dense_max:
        dense = W.toarray() if is_sparse(W) else np.asarray(W, dtype=float)
        return singular_pivots(lu_pivots(np.eye(n) - dense.T))
    try:
        InfluenceSolver(dense_max).set_matrix(W, key=0)
    except np.linalg.LinAlgError:
        return True
    return False


def matrix_key(W: Any) -> Hashable:
    """A hashable fingerprint of a matrix's sparsity pattern and values."""
    if is_sparse(W):
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
        Graphs with at most this many nodes keep the dense ``P = (I − Wᵀ)⁻¹``
        (:func:`propagation_matrix`; a solve is ``P r``, numpy only; default
        :data:`SOLVE_DENSE_MAX`); larger ones sparse LU (:func:`scipy.sparse.linalg.splu`).

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

    def __init__(self, dense_max: int = SOLVE_DENSE_MAX) -> None:
        self.dense_max = dense_max
        self.factorizations = 0
        self.key: Hashable | None = None
        self.n = 0
        self._dense: np.ndarray | None = None
        self._sparse: Any = None
        self._order: np.ndarray | None = None

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
            dense = W.toarray() if is_sparse(W) else np.asarray(W, dtype=float)
            if not np.all(np.isfinite(dense)):
                raise ValueError("array must not contain infs or NaNs")
            if singular_pivots(lu_pivots(np.eye(n) - dense.T)):
                raise np.linalg.LinAlgError("I - W^T is singular")
            self._dense = propagation_matrix(dense)
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
            if not math.isfinite(sum(r.tolist())):
                raise ValueError("array must not contain infs or NaNs")
            return self._dense @ r
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


def _operand(W: Any) -> Any:
    """``W`` as a float numpy array up to :data:`DENSE_MAX` modules, else CSR (scipy then)."""
    sparse = is_sparse(W)
    if (W.shape[0] if sparse else np.shape(W)[0]) <= DENSE_MAX:
        return W.toarray() if sparse else np.array(W, dtype=float)
    import scipy.sparse

    return scipy.sparse.csr_matrix(W, dtype=float)


def _transpose(S: Any) -> Any:
    """``Sᵀ`` of an :func:`_operand`, laid out for products (CSR, or a C-ordered array)."""
    return S.T.tocsr() if is_sparse(S) else np.ascontiguousarray(S.T)


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
    A fault at the head of heater → room → sensor → observer, where only the
    heater and the observer carry a residual (room and sensor are hidden):

    >>> from archself.runtime.influence import weight_matrix, influence
    >>> names = ["heater", "room", "sensor", "observer"]
    >>> W = weight_matrix(names, [("heater", "room", 0.8), ("room", "sensor", 0.9),
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
        S = _operand(W)
        n = S.shape[0]
        self.n = n
        self.observed = _mask(observed, n)
        self.hidden_index = np.flatnonzero(~self.observed)
        self.observed_index = np.flatnonzero(self.observed)
        self._WT = _transpose(S)
        self._solver: InfluenceSolver | None = None
        if self.hidden_index.size:
            h, o = self.hidden_index, self.observed_index
            self._solver = InfluenceSolver()
            self._solver.set_matrix(S[h][:, h], key=0)
            self._W_OH_T = _transpose(S[o][:, h])

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
        r = _residuals(r, self.n)
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
    dense = W.toarray() if is_sparse(W) else np.asarray(W, dtype=float)
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
        e[o], _ = nnls(P[np.ix_(o, o)], r[o])
    return e


def nnls(A: Any, b: Any) -> tuple[np.ndarray, float]:
    """Non-negative least squares ``argmin_{x ≥ 0} ‖A x − b‖₂`` and ``‖A x − b‖₂``.

    What :func:`scipy.optimize.nnls` returns (it is the tests' oracle, and solves
    the problems of more than :data:`NNLS_NUMPY_MAX` unknowns); smaller ones by the
    active-set algorithm of Lawson & Hanson, *Solving Least Squares Problems*
    (SIAM, 1995), ch. 23, in numpy: no scipy import on a small system's run path.

    Parameters
    ----------
    A : array_like, shape (m, k)
    b : array_like, shape (m,)

    Returns
    -------
    x : numpy.ndarray, shape (k,)
        The solution, ``≥ 0``.
    rnorm : float
        ``‖A x − b‖₂``.

    Raises
    ------
    ValueError
        If ``A`` or ``b`` is not finite, or their shapes do not match.

    Examples
    --------
    >>> x, rnorm = nnls(np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([2.0, 1.0, -1.0]))
    >>> np.round(x, 9).tolist(), round(rnorm, 6)  # to rounding (the LAPACK build's)
    ([1.5, 0.0], 1.224745)
    """
    A = np.asarray_chkfinite(A, dtype=float)
    b = np.asarray_chkfinite(b, dtype=float).ravel()
    if A.ndim != 2 or A.shape[0] != b.shape[0]:
        raise ValueError(f"A has shape {A.shape}, b {b.shape}: expected (m, k) and (m,)")
    k = A.shape[1]
    if k > NNLS_NUMPY_MAX:
        from scipy.optimize import nnls as scipy_nnls

        x, rnorm = scipy_nnls(A, b)
        return x, float(rnorm)
    x = np.zeros(k)
    passive = np.zeros(k, dtype=bool)  # L&H's set P; the others are held at 0
    refused = np.zeros(k, dtype=bool)  # entered with a non-positive value: skipped until x moves
    tol = 10.0 * np.finfo(float).eps * max(A.shape) * float(np.abs(A).sum(axis=0).max(initial=0.0))
    w = A.T @ b
    moves = 0
    while True:
        free = ~passive & ~refused
        if not free.any() or float(w[free].max()) <= tol:
            break
        j = int(np.argmax(np.where(free, w, -np.inf)))
        passive[j] = True
        s = _passive_lstsq(A, b, passive)
        if s[j] <= 0.0:  # rounding: j cannot enter (L&H's test on z_j)
            passive[j], refused[j] = False, True
            continue
        moves += 1
        if moves > 3 * k:
            raise ValueError(f"nnls: no convergence in {3 * k} steps (A has shape {A.shape})")
        while (low := passive & (s <= 0.0)).any():  # step back to the bound, drop those at 0
            x = x + float(np.min(x[low] / (x[low] - s[low]))) * (s - x)
            passive &= x > tol
            x[~passive] = 0.0
            s = _passive_lstsq(A, b, passive)
        x = s
        refused[:] = False
        w = A.T @ (b - A @ x)
    return x, float(np.linalg.norm(A @ x - b))


#: Two columns of the observed influence matrix closer than this (cosine) explain any
#: residual equally well: their modules form one equivalence class.
COLLINEAR_COS = 0.999
#: A further source is taken only if it explains at least this share of ‖r_O‖² more.
PARSIMONY = 0.1
#: Above DENSE_MAX modules, at most this many candidate sources are fitted (screened).
SCREEN = 64
#: Patterns of positive residuals whose candidate classes a dense fit keeps (then starts over).
BASES_MAX = 256
#: A zero residual is read as "inside the band": a predicted echo up to this is no
#: contradiction (residuals are in units of the nominal level, Eq. 12).
BAND = 1.0


class SourceFit:
    """Few non-negative local faults on observed *and hidden* modules that explain r_O.

    The model ``r_O = P_O e`` with ``P = (I − Wᵀ)⁻¹`` (``P_O``: the observed rows) and
    ``e ≥ 0`` on every module. Candidate sources are the modules with a path to an
    observed module whose residual is non-zero (their ancestors and themselves); of
    them the fit prefers few:

    1. **Identifiability.** Modules whose columns of ``P_O`` are collinear (cosine
       ≥ :data:`COLLINEAR_COS`) explain every residual equally — typically a hidden
       module and everything between it and the one observed module its effect
       passes through. They form one *equivalence class*; the fit is made on one
       unit column per class, and every member gets the same estimate: the data
       cannot tell them apart, so none is picked silently (:attr:`classes`).
    2. **Parsimony.** The best single class (``x = max(0, uᵀ r_O)``), then the best
       pair (non-negative, over the classes), then :func:`scipy.optimize.nnls` over
       all classes: a further source is accepted only when it lowers the unexplained
       ``‖r_O − P_O e‖²`` by at least :data:`PARSIMONY` of ``‖r_O‖²``.

    The estimate of a source is the size of what it explains, ``x_c = ‖P_O[:, j] e_j‖₂``
    (the coefficient on the unit column), in the units of the residuals — those τ is
    set in — refitted on the chosen sources with each zero residual read as "inside
    its band" (a predicted echo up to :data:`BAND` there is no contradiction): a
    module whose fault shows only in its own residual gets exactly that residual, as
    with :class:`SourceEstimator`. (The fault in the module's own units,
    ``e_j = x_c / ‖P_O[:, j]‖``, differs between members of a class and is not what
    the data say.)

    A hidden module with a residual of its own (one the system reports unavailable)
    keeps it as its source and its predicted echoes are removed from r_O first, as
    in :class:`SourceEstimator`.

    The propagation matrix is dense and computed once per W up to
    :data:`~archself.runtime.influence.DENSE_MAX` modules; larger graphs solve one
    column per candidate source with the reused factorization (cached per W), the
    candidates restricted to the ancestors of the modules with a residual and, when
    there are more than :data:`SCREEN`, to those whose columns carry the most of
    ``r_O`` (one adjoint solve, :meth:`_screen`). With a dense ``P_O`` the candidates,
    their classes and unit columns depend on ``r_O`` only through which observed
    residuals are positive: they are kept per such pattern (:meth:`_basis`).

    Parameters
    ----------
    W : array_like or scipy.sparse matrix, shape (n, n)
        Weighted adjacency matrix, ``W[j, i]`` the weight of the edge ``j → i``.
    observed : array_like of bool, shape (n,), optional
        Modules with an observed residual; default all.

    Attributes
    ----------
    classes : list of list of int
        After :meth:`estimate`: the equivalence classes of the chosen sources, largest
        explained share first (module indices; one element when identifiable).
    shares : list of numpy.ndarray
        After :meth:`estimate`, one per class: the part of each observed residual the
        class explains (its predicted echo's share of the residual; 0 on hidden
        modules). Off the class's members it is the source's echo downstream.

    Examples
    --------
    The heater has no residual; its fault shows at the observer and, through it, at
    the controller. Heater, room and observer reach the observed modules only through the
    observer: one class, the same estimate for each.

    >>> from archself.runtime.influence import weight_matrix
    >>> names = ["heater", "room", "observer", "controller"]
    >>> W = weight_matrix(names, [("heater", "room", 1.2), ("room", "observer", 2.0),
    ...                           ("observer", "controller", 0.25),
    ...                           ("controller", "heater", 0.15)])
    >>> fit = SourceFit(W, observed=[False, False, True, True])
    >>> fit.estimate([0.0, 0.0, 4.0, 1.0]).round(2).tolist()  # z at the observer
    [4.79, 4.79, 4.79, 0.0]
    >>> [[names[j] for j in c] for c in fit.classes]
    [['heater', 'room', 'observer']]
    """

    def __init__(self, W: Any, observed: Any = None) -> None:
        S = _operand(W)
        n = S.shape[0]
        self.n = n
        self.observed = _mask(observed, n)
        self.observed_index = np.flatnonzero(self.observed)
        self.hidden_index = np.flatnonzero(~self.observed)
        self.classes: list[list[int]] = []
        self.shares: list[np.ndarray] = []
        self._row = np.full(n, -1)
        self._row[self.observed_index] = np.arange(self.observed_index.size)
        self._P_O: np.ndarray | None = None
        self._P: np.ndarray | None = None
        self._WT = _transpose(S)  # parents of i: row i of Wᵀ
        self._cols: dict[int, np.ndarray] = {}
        self._bases: dict[bytes, _Basis] = {}
        self._solver: InfluenceSolver | None = None
        self._adjoint: InfluenceSolver | None = None
        if n <= DENSE_MAX:
            self._P = propagation_matrix(S) if n else np.zeros((0, 0))
            self._P_O = self._P[self.observed_index]
        else:
            self._solver = InfluenceSolver()
            self._solver.set_matrix(S, key=0)

    def _ancestors(self, start: np.ndarray) -> np.ndarray:
        """The modules with a path to one of ``start`` (themselves included), sorted."""
        if self._P_O is not None:
            return np.flatnonzero(np.any(self._P_O[self._row[start]] != 0.0, axis=0))
        # one breadth-first search on the reversed graph from a node pointing at ``start``
        import scipy.sparse
        import scipy.sparse.csgraph

        n = self.n
        hub = scipy.sparse.csr_matrix(
            (np.ones(start.size), (np.zeros(start.size, dtype=int), start)), shape=(1, n + 1)
        )
        G = scipy.sparse.vstack(
            [scipy.sparse.hstack([self._WT, scipy.sparse.csr_matrix((n, 1))]), hub]
        ).tocsr()
        found = scipy.sparse.csgraph.breadth_first_order(
            G, n, directed=True, return_predecessors=False
        )
        return np.sort(found[found < n])

    def _columns(self, cand: np.ndarray) -> np.ndarray:
        """``P_O[:, cand]``: the observed residuals a unit fault at each candidate gives."""
        if self._P_O is not None:
            return self._P_O[:, cand]
        out = np.empty((self.observed_index.size, cand.size))
        for k, j in enumerate(cand.tolist()):
            col = self._cols.get(j)
            if col is None:
                unit = np.zeros(self.n)
                unit[j] = 1.0
                assert self._solver is not None
                col = self._cols[j] = self._solver.solve(unit)[self.observed_index]
            out[:, k] = col
        return out

    def _screen(self, cand: np.ndarray, r_O: np.ndarray) -> np.ndarray:
        """The :data:`SCREEN` candidates with the largest ``(P_Oᵀ r_O)_j`` (large graphs).

        One solve with ``(I − W)`` (the adjoint, factorized once per W) scores every
        candidate by how much of ``r_O`` its column carries, before any column is
        solved for.
        """
        if self._adjoint is None:
            self._adjoint = InfluenceSolver()
            self._adjoint.set_matrix(self._WT, key=0)
        y = np.zeros(self.n)
        y[self.observed_index] = r_O
        score = self._adjoint.solve(y)[cand]
        return np.sort(cand[np.argsort(-score, kind="stable")[:SCREEN]])

    def estimate(self, r: Any) -> np.ndarray:
        """``ê`` on every module: the sparse non-negative fit of the observed residuals.

        Parameters
        ----------
        r : array_like, shape (n,)
            Module residuals (Eq. 12); hidden modules' are 0 unless unavailable.

        Returns
        -------
        numpy.ndarray, shape (n,)
            ``≥ 0``: per module the size of the residuals its fault explains, the same
            for the members of a class (:attr:`classes` says which belong together);
            0 off the chosen sources.

        Raises
        ------
        ValueError
            If ``r`` does not have one value per module or is not finite.
        """
        r = _residuals(r, self.n)
        self.classes = []
        self.shares = []
        e = np.zeros(self.n)
        h, o = self.hidden_index, self.observed_index
        r_O = np.maximum(r[o], 0.0)
        own = h[r[h] != 0.0]
        if own.size:  # unavailable hidden modules: their own residual, its echoes removed
            e[own] = r[own]
            r_O = np.maximum(r_O - self._columns(own) @ r[own], 0.0)
        total = float(r_O @ r_O)
        if total <= 0.0:
            return e
        basis = self._basis(r_O)
        cand, members = basis.cand, basis.members
        x, support = _parsimonious_fit(basis.U, r_O, PARSIMONY * total, basis.gram)
        chosen = basis.U[:, support]
        size = _censored_fit(chosen, r_O, x[support])
        z_share, shares = self._explained_z(chosen * size, r_O, [
            cand[members[c]] for c in support])
        size = np.maximum(size, z_share)
        for k in np.argsort(-size, kind="stable").tolist():
            if size[k] <= 0.0:
                continue
            idx = members[support[k]]
            e[cand[idx]] = size[k]
            self.classes.append(cand[idx].tolist())
            self.shares.append(shares[k])
        return e


    def _basis(self, r_O: np.ndarray) -> _Basis:
        """The candidate sources of ``r_O`` and their classes' unit columns.

        They depend on ``r_O`` only through which observed residuals are positive
        when ``P_O`` is dense: cached per such pattern (W is fixed per fit); large
        graphs screen by the values and recompute.
        """
        pos = r_O > 0.0
        key = pos.tobytes() if self._P_O is not None else None
        basis = self._bases.get(key) if key is not None else None
        if basis is not None:
            return basis
        cand = self._ancestors(self.observed_index[pos])
        if self._P_O is None and cand.size > SCREEN:
            cand = self._screen(cand, r_O)
        A = self._columns(cand)
        norms = np.linalg.norm(A, axis=0)
        keep = norms > 1e-12
        cand, A, norms = cand[keep], A[:, keep], norms[keep]
        U = A / norms
        members, reps = _collinear_classes(U)
        basis = _Basis(cand, members, U[:, reps])
        if key is not None:
            if len(self._bases) >= BASES_MAX:
                self._bases.clear()
            self._bases[key] = basis
        return basis

    def _explained_z(
        self, echoes: np.ndarray, r_O: np.ndarray, classes: list[np.ndarray]
    ) -> tuple[np.ndarray, list[np.ndarray]]:
        """Per chosen class, the paper's z of the residuals it explains, at its members.

        Each observed residual is shared among the chosen sources in proportion to the
        echo each predicts there (``echoes``, one column per class); the z of a class's
        share ``a_c``, ``(I − Wᵀ)⁻¹ a_c``, is taken at its members and the largest
        returned, with the shares (length ``n``, 0 on hidden modules). A source's
        estimate is never below it (:meth:`estimate`): a fault that shows only in its own
        residual gets exactly the z Algorithm 1 would give it, feedback through its loop
        included, so τ keeps the meaning it has for z; the echoes of other sources are
        not added to it, as z adds them.
        """
        total = echoes.sum(axis=1)
        share = np.divide(echoes, total[:, None], out=np.zeros_like(echoes),
                          where=total[:, None] > 0.0)
        out = np.zeros(len(classes))
        shares = []
        for k, idx in enumerate(classes):
            a = np.zeros(self.n)
            a[self.observed_index] = share[:, k] * r_O
            shares.append(a)
            z = self.influence(a)[idx]
            out[k] = float(z.max()) if z.size else 0.0
        return out, shares

    def influence(self, a: np.ndarray) -> np.ndarray:
        """The paper's z of residuals ``a`` (length n): ``(I − Wᵀ)⁻¹ a``, by this fit's P."""
        if self._P is not None:
            return self._P @ a
        assert self._solver is not None
        return self._solver.solve(a)


class _Basis:
    """What :meth:`SourceFit.estimate` fits on for one pattern of positive residuals.

    ``cand`` the candidate modules, ``members`` per class its positions in ``cand``,
    ``U`` one unit column of ``P_O`` per class (its representative's) and ``gram``
    its Gram matrix by rows, ``gram[a] = Uᵀ U[:, a]`` (:func:`_parsimonious_fit`).
    """

    __slots__ = ("cand", "members", "U", "gram")

    def __init__(self, cand: np.ndarray, members: list[np.ndarray], U: np.ndarray) -> None:
        self.cand, self.members, self.U = cand, members, U
        self.gram = np.array([U.T @ U[:, a] for a in range(U.shape[1])]).reshape(
            U.shape[1], U.shape[1])


def _nnls(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """:func:`nnls` and the squared residual; a tall ``A`` via its Gram matrix.

    With ``G = AᵀA = V Λ Vᵀ`` and ``c = Aᵀb``, ``‖A x − b‖²`` equals
    ``‖Λ^½ Vᵀ x − Λ^-½ Vᵀ c‖²`` up to a constant: the same solution from a k × k
    problem (scipy's nnls on 10^4 × 64 took seconds).
    """
    if A.shape[0] <= 2 * A.shape[1]:
        x, res = nnls(A, b)
        return x, float(res) ** 2
    G, c = A.T @ A, A.T @ b
    lam, V = np.linalg.eigh(G)
    keep = lam > 1e-12 * max(1.0, float(lam[-1]))
    root = np.sqrt(lam[keep])
    x, _ = nnls(root[:, None] * V[:, keep].T, (V[:, keep].T @ c) / root)
    return x, max(0.0, float(b @ b) - 2.0 * float(c @ x) + float(x @ G @ x))


def _passive_lstsq(A: np.ndarray, b: np.ndarray, passive: np.ndarray) -> np.ndarray:
    """Least squares on the columns ``passive`` of ``A``, zeros elsewhere (:func:`nnls`)."""
    s = np.zeros(A.shape[1])
    s[passive] = np.linalg.lstsq(A[:, passive], b, rcond=None)[0]
    return s


def _censored_fit(U: np.ndarray, r: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Refit the chosen sources with the zero residuals read as ``≤ BAND``, not ``= 0``.

    A residual of 0 says the signal is inside its nominal band, so a predicted echo
    up to :data:`BAND` there is no contradiction (W is rarely known better: the
    bench draws it ±40 % off). Active set: zero rows predicted above the band are
    fitted to the band, the others left out, until the set settles (≤ 10 rounds).
    A module whose fault shows only in its own residual gets exactly that residual.
    """
    zero = r <= 0.0
    target = np.where(zero, BAND, r)
    active = zero & (U @ x > BAND)
    for _ in range(10):
        rows = ~zero | active
        x, _ = _nnls(U[rows], target[rows])
        now = zero & (U @ x > BAND)
        if np.array_equal(now, active):
            break
        active = now
    return x


def _collinear_classes(U: np.ndarray) -> tuple[list[np.ndarray], list[int]]:
    """Group unit columns with cosine ≥ :data:`COLLINEAR_COS`; (members, representative)."""
    m = U.shape[1]
    label = np.full(m, -1)
    members: list[np.ndarray] = []
    reps: list[int] = []
    cos = U.T @ U
    for j in range(m):
        if label[j] >= 0:
            continue
        same = np.flatnonzero((label < 0) & (cos[j] >= COLLINEAR_COS))
        label[same] = len(reps)
        members.append(same)
        reps.append(j)
    return members, reps


def _parsimonious_fit(
    U: np.ndarray, r: np.ndarray, gain: float, gram: np.ndarray
) -> tuple[np.ndarray, list[int]]:
    """Non-negative coefficients on unit columns: one, two or all, by ``gain`` per source.

    ``gram[a]`` is ``Uᵀ U[:, a]`` (:class:`_Basis`). Returns the
    coefficients (one per column) and the indices of the chosen support.
    """
    m = U.shape[1]
    total = float(r @ r)
    p = U.T @ r
    proj = np.maximum(p, 0.0)
    best = int(np.argmax(proj))
    x = np.zeros(m)
    x[best] = proj[best]
    rss, support = total - proj[best] ** 2, [best]
    if m < 2 or rss < gain:
        return x, support
    # pairs (a among the best 12 singles, b any): the 2×2 normal equations on unit columns,
    # both coefficients > 0 (else the pair is one of the singles already tried); one row per a
    top = np.argsort(-proj, kind="stable")[: min(m, 12)]
    c = gram[top]
    det = 1.0 - c * c
    ok = det > 1e-9
    ok[np.arange(top.size), top] = False
    pa = p[top][:, None]
    safe = np.where(ok, det, 1.0)
    xa = np.where(ok, (pa - c * p) / safe, 0.0)
    xb = np.where(ok, (p - c * pa) / safe, 0.0)
    ok &= (xa > 0) & (xb > 0)
    res = np.where(ok, total - (xa * pa + xb * p), np.inf)
    bs = np.argmin(res, axis=1)
    pair_rss, pair = rss, None
    for i, low in enumerate(res[np.arange(top.size), bs].tolist()):
        if low < pair_rss - 1e-12:  # the first a reaching the lowest, as tried in order
            pair_rss, pair = low, i
    if pair is None or rss - pair_rss < gain:
        return x, support
    a, b = int(top[pair]), int(bs[pair])
    x = np.zeros(m)
    x[[a, b]] = xa[pair, b], xb[pair, b]
    rss, support = pair_rss, [a, b]
    coef, res2 = _nnls(U, r)
    if rss - res2 >= gain and np.count_nonzero(coef) > 2:
        return coef, np.flatnonzero(coef).tolist()
    return x, support


def _residuals(r: Any, n: int) -> np.ndarray:
    """``r`` as a flat float array of ``n`` finite values; ValueError otherwise."""
    r = np.asarray(r, dtype=float).ravel()
    if r.shape != (n,):
        raise ValueError(f"r has shape {r.shape}, expected ({n},)")
    if not np.all(np.isfinite(r)):
        raise ValueError("r must be finite")
    return r
