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
  ``min ‖((I − Wᵀ)⁻¹)_OO e_O − r_O‖₂, e_O ≥ 0`` (:func:`scipy.optimize.nnls` on
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

from typing import Any

import numpy as np
import scipy.optimize
import scipy.sparse
import scipy.sparse.csgraph

from archself.runtime.influence import InfluenceSolver

__all__ = [
    "SourceEstimator",
    "SourceFit",
    "propagation_matrix",
    "source_estimate",
    "source_nnls",
]


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


#: Two columns of the observed influence matrix closer than this (cosine) explain any
#: residual equally well: their modules form one equivalence class.
COLLINEAR_COS = 0.999
#: A further source is taken only if it explains at least this share of ‖r_O‖² more.
PARSIMONY = 0.1
#: Above DENSE_MAX modules, at most this many candidate sources are fitted (screened).
SCREEN = 64
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
    ``r_O`` (one adjoint solve, :meth:`_screen`).

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
        from archself.runtime.influence import DENSE_MAX

        S = scipy.sparse.csr_matrix(W, dtype=float)
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
        self._WT = S.T.tocsr()  # parents of i: row i of Wᵀ
        self._cols: dict[int, np.ndarray] = {}
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
        cand = self._ancestors(o[r_O > 0.0])
        if self._P_O is None and cand.size > SCREEN:
            cand = self._screen(cand, r_O)
        A = self._columns(cand)
        norms = np.linalg.norm(A, axis=0)
        keep = norms > 1e-12
        cand, A, norms = cand[keep], A[:, keep], norms[keep]
        U = A / norms
        members, reps = _collinear_classes(U)
        x, support = _parsimonious_fit(U[:, reps], r_O, PARSIMONY * total)
        chosen = U[:, [reps[c] for c in support]]
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


def _nnls(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """:func:`scipy.optimize.nnls` and the squared residual; a tall ``A`` via its Gram matrix.

    With ``G = AᵀA = V Λ Vᵀ`` and ``c = Aᵀb``, ``‖A x − b‖²`` equals
    ``‖Λ^½ Vᵀ x − Λ^-½ Vᵀ c‖²`` up to a constant: the same solution from a k × k
    problem (scipy's nnls on 10^4 × 64 took seconds).
    """
    if A.shape[0] <= 2 * A.shape[1]:
        x, res = scipy.optimize.nnls(A, b)
        return x, float(res) ** 2
    G, c = A.T @ A, A.T @ b
    lam, V = np.linalg.eigh(G)
    keep = lam > 1e-12 * max(1.0, float(lam[-1]))
    root = np.sqrt(lam[keep])
    x, _ = scipy.optimize.nnls(root[:, None] * V[:, keep].T, (V[:, keep].T @ c) / root)
    return x, max(0.0, float(b @ b) - 2.0 * float(c @ x) + float(x @ G @ x))


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
    U: np.ndarray, r: np.ndarray, gain: float
) -> tuple[np.ndarray, list[int]]:
    """Non-negative coefficients on unit columns: one, two or all, by ``gain`` per source.

    Returns the coefficients (one per column) and the indices of the chosen support.
    """
    m = U.shape[1]
    total = float(r @ r)
    proj = np.maximum(U.T @ r, 0.0)
    best = int(np.argmax(proj))
    x = np.zeros(m)
    x[best] = proj[best]
    rss, support = total - proj[best] ** 2, [best]
    if m < 2 or rss < gain:
        return x, support
    # pairs (a among the best 12 singles, b any): the 2×2 normal equations on unit columns,
    # both coefficients > 0 (else the pair is one of the singles already tried)
    p = U.T @ r
    pair_x, pair_rss, pair = x, rss, support
    for a in np.argsort(-proj, kind="stable")[: min(m, 12)].tolist():
        c = U.T @ U[:, a]
        det = 1.0 - c * c
        ok = det > 1e-9
        ok[a] = False
        xa = np.where(ok, (p[a] - c * p) / np.where(ok, det, 1.0), 0.0)
        xb = np.where(ok, (p - c * p[a]) / np.where(ok, det, 1.0), 0.0)
        ok &= (xa > 0) & (xb > 0)
        if not ok.any():
            continue
        res = np.where(ok, total - (xa * p[a] + xb * p), np.inf)
        b = int(np.argmin(res))
        if res[b] < pair_rss - 1e-12:
            pair_x = np.zeros(m)
            pair_x[[a, b]] = xa[b], xb[b]
            pair_rss, pair = float(res[b]), [a, b]
    if rss - pair_rss < gain:
        return x, support
    x, rss, support = pair_x, pair_rss, pair
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
