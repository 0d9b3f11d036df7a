"""The closed loop of a configuration as data, and its modes (eigenvalues, modal form).

:func:`eigenvalues` splits a sparse matrix into the strong components of its
pattern (block triangular: the eigenvalues are those of the diagonal blocks);
:func:`modal_form` maps the discrete eigenvalues λ of a loop to a real matrix with
the continuous-equivalent eigenvalues ``ln(λ)/dt`` that Eq. 21 tests (pure maths).

:class:`Interconnection` is the discrete closed loop :func:`archself.linear.wiring.interconnect`
makes (A, period, the module owning each state); :class:`ClosedLoop` adds the
``linearization()`` blocks of the modules without a model and gives the
continuous-time A of Eq. 20 (:meth:`ClosedLoop.matrix`) and the least stable
mode with the modules' shares of it (:meth:`ClosedLoop.worst_mode`).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # scipy is imported where a sparse matrix is made, not with the system
    import scipy.sparse

__all__ = ["ClosedLoop", "Interconnection", "LAMBDA_FLOOR", "WholeLoop", "block_diag",
           "eigenvalues", "modal_form"]


#: Floor of |λ| when mapping a discrete eigenvalue to ln|λ|/dt (a pure delay has λ = 0).
LAMBDA_FLOOR = 1e-12


def issparse(A: Any) -> bool:
    """``scipy.sparse.issparse(A)`` without importing scipy (no sparse matrix without it)."""
    sparse = sys.modules.get("scipy.sparse")
    return sparse is not None and sparse.issparse(A)


#: Up to this many nodes :func:`strong_components` works on the dense pattern in numpy
#: (≤ 0.15 ms a call; 3.8 ms at 200, where scipy's takes 0.4 ms with the conversion:
#: bench/dense_bounds.py); larger graphs use :func:`scipy.sparse.csgraph.connected_components`.
COMPONENTS_DENSE_MAX = 100


def strong_components(A: Any) -> np.ndarray:
    """The strongly connected component of each node of the pattern of ``A`` (``A[i, j] ≠ 0``:
    an edge ``i → j``), as labels ``0, 1, …``.

    Up to :data:`COMPONENTS_DENSE_MAX` nodes of a dense ``A``: the transitive closure by
    repeated squaring of the boolean pattern (numpy only), a component numbered by
    its first node; above, or sparse, scipy's (numbered in reverse topological order).

    Examples
    --------
    >>> strong_components(np.array([[0, 1, 0], [1, 0, 1], [0, 0, 0]])).tolist()
    [0, 0, 1]
    """
    n = A.shape[0]
    if issparse(A) or n > COMPONENTS_DENSE_MAX:
        import scipy.sparse
        from scipy.sparse.csgraph import connected_components

        return connected_components(scipy.sparse.csr_matrix(A), directed=True,
                                    connection="strong")[1]
    reach = (np.asarray(A) != 0) | np.eye(n, dtype=bool)
    while True:  # paths of length ≤ 2^k: at most ⌈log2 n⌉ + 1 squarings
        f = reach.astype(np.float32)
        wider = (f @ f) > 0.0
        if np.array_equal(wider, reach):
            break
        reach = wider
    first = np.argmax(reach & reach.T, axis=1)  # the lowest node of each one's component
    return np.unique(first, return_inverse=True)[1].ravel()


def eigenvalues(A: np.ndarray | scipy.sparse.spmatrix) -> np.ndarray:
    """The eigenvalues of a dense or ``scipy.sparse`` square matrix (complex).

    A sparse matrix is split into the strong components of its pattern: in their
    topological order it is block triangular, so its eigenvalues are those of the
    diagonal blocks (a 1×1 block's is its entry).

    Examples
    --------
    >>> import scipy.sparse
    >>> A = scipy.sparse.csr_matrix([[0.5, 0.0, 0.0], [1.0, 0.0, 2.0], [0.0, -2.0, 0.0]])
    >>> sorted(eigenvalues(A).round(6).tolist(), key=lambda z: (z.real, z.imag))
    [-2j, 2j, (0.5+0j)]
    """
    if not issparse(A):
        A = np.atleast_2d(np.asarray(A, dtype=float))
        return np.linalg.eigvals(A) if A.size else np.zeros(0, dtype=complex)
    import scipy.sparse
    from scipy.sparse.csgraph import connected_components

    A = scipy.sparse.csr_matrix(A)
    if A.shape[0] == 0:
        return np.zeros(0, dtype=complex)
    count, labels = connected_components(A, directed=True, connection="strong")
    size = np.bincount(labels, minlength=count)
    single = size[labels] == 1
    out = [A.diagonal()[single].astype(complex)]
    order = np.argsort(labels, kind="stable")
    starts = np.concatenate([[0], np.cumsum(size)])
    for c in np.flatnonzero(size > 1).tolist():
        idx = order[starts[c] : starts[c + 1]]
        out.append(np.linalg.eigvals(A[idx][:, idx].toarray()))
    return np.concatenate(out)


def modal_form(Ad: np.ndarray, dt: float) -> np.ndarray:
    """A real matrix whose eigenvalues are ``ln(λ_i)/dt`` for the eigenvalues λ_i of ``Ad``.

    Real λ give 1×1 blocks ``ln|λ|/dt``; a complex pair gives the 2×2 block
    ``[[a, ω], [−ω, a]]`` with ``a = ln|λ|/dt`` and ``ω = arg(λ)/dt``. Only the real
    parts matter for Eq. 21; |λ| is floored at 1e-12 (a pure delay).

    Examples
    --------
    >>> modal_form(np.array([[0.5]]), 0.1).round(4).tolist()
    [[-6.9315]]
    """
    if issparse(Ad):
        return _modal_sparse(eigenvalues(Ad), dt)
    lam = np.linalg.eigvals(np.atleast_2d(Ad)) if Ad.size else np.zeros(0)
    blocks = []
    for z in lam:
        a = math.log(max(abs(z), LAMBDA_FLOOR)) / dt
        if z.imag > 1e-12:
            w = math.atan2(z.imag, z.real) / dt
            blocks.append(np.array([[a, w], [-w, a]]))
        elif z.imag >= -1e-12:
            blocks.append(np.array([[a]]))
    return block_diag(blocks)


def _modal_sparse(lam: np.ndarray, dt: float) -> scipy.sparse.csr_matrix:
    """:func:`modal_form` of the eigenvalues ``lam``, as a sparse matrix."""
    a = np.log(np.maximum(np.abs(lam), LAMBDA_FLOOR)) / dt
    w = np.arctan2(lam.imag, lam.real) / dt
    real = np.abs(lam.imag) <= 1e-12
    pair = lam.imag > 1e-12
    keep = real | pair
    width = np.where(pair, 2, 1)[keep]
    start = np.concatenate([[0], np.cumsum(width)[:-1]]).astype(np.intp)
    a, w, pair = a[keep], w[keep], pair[keep]
    rows = [start, start[pair], start[pair] + 1, start[pair] + 1]
    cols = [start, start[pair] + 1, start[pair], start[pair] + 1]
    vals = [a, w[pair], -w[pair], a[pair]]
    size = int(width.sum())
    import scipy.sparse

    return scipy.sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(size, size)
    )


def block_diag(blocks: Sequence[Any]) -> Any:
    """The blocks on a diagonal: sparse if any block is, else dense."""
    if any(issparse(b) for b in blocks):
        import scipy.sparse

        return scipy.sparse.block_diag(blocks, format="csr")
    size = sum(b.shape[0] for b in blocks)
    out = np.zeros((size, size))
    i = 0
    for b in blocks:
        k = b.shape[0]
        out[i : i + k, i : i + k] = b
        i += k
    return out

@dataclass
class Interconnection:
    """The discrete closed loop of wired models.

    Attributes
    ----------
    A : numpy.ndarray
        Closed-loop state matrix (discrete, period ``dt``).
    dt : float
        The period.
    owners : list of str
        The module (or ``source→target`` delay line) each state belongs to.
    labels : list of str
        ``owner.state`` per state.
    """

    A: np.ndarray
    dt: float
    owners: list[str]
    labels: list[str]


@dataclass
class ClosedLoop:
    """The closed loop of a configuration: the wired models and the fallback blocks.

    Attributes
    ----------
    loop : Interconnection or None
        The discrete closed loop of the modules that give a linear model.
    blocks : list of (str, numpy.ndarray)
        ``(module, A)``: continuous closed-loop matrices of the modules that give
        only ``linearization()`` (or whose model closes no loop), in file order.
    """

    loop: Interconnection | None = None
    blocks: list[tuple[str, np.ndarray]] = field(default_factory=list)

    def matrix(self) -> np.ndarray | None:
        """The continuous-time A of Eq. 20 the eigenvalue margin tests (None: no model).

        The wired part in :func:`modal_form`, then the blocks on the diagonal.
        """
        parts = []
        if self.loop is not None and self.loop.A.shape[0]:
            parts.append(modal_form(self.loop.A, self.loop.dt))
        parts += [b for _, b in self.blocks]
        if not parts:
            return None
        return block_diag(parts)

    def worst_mode(self) -> tuple[float, float | None, list[tuple[str, float]]] | None:
        """``(max Re μ, |λ| or None, [(module, share), ...])`` of the least stable mode.

        ``μ`` is the continuous-equivalent eigenvalue; ``|λ|`` its discrete
        magnitude when it comes from the wired part (per step). The shares are the
        fractions of the mode's eigenvector (``|v_j|²``, normalized) in each module's
        states, largest first. None when there are no states.
        """
        best: tuple[float, float | None, list[tuple[str, float]]] | None = None
        loop = self.loop
        if loop is not None and loop.A.shape[0] and issparse(loop.A):
            best = _worst_sparse(loop)
        elif loop is not None and loop.A.shape[0]:  # dense
            lam, vec = np.linalg.eig(loop.A)
            mag = np.maximum(np.abs(lam), LAMBDA_FLOOR)
            k = int(np.argmax(mag))
            best = (
                math.log(mag[k]) / loop.dt,
                float(np.abs(lam[k])),
                _shares(np.abs(vec[:, k]) ** 2, loop.owners),
            )
        for name, b in self.blocks:
            if not b.size:
                continue
            worst = float(np.max(np.linalg.eigvals(b).real))
            if best is None or worst > best[0]:
                best = (worst, None, [(name, 1.0)])
        return best


def _worst_sparse(loop: Interconnection) -> tuple[float, float, list[tuple[str, float]]]:
    """``worst_mode`` of a sparse loop with states: the largest |λ| of its components' blocks.

    The shares are those of the eigenvector of the component's own block (the
    mode's states in that component; its echo in the components downstream is
    not counted).
    """
    import scipy.sparse
    from scipy.sparse.csgraph import connected_components

    A = scipy.sparse.csr_matrix(loop.A)
    _, labels = connected_components(A, directed=True, connection="strong")
    size = np.bincount(labels)
    diag = np.abs(A.diagonal())
    single = size[labels] == 1
    best: tuple[float, list[int], np.ndarray] | None = None
    if single.any():
        i = int(np.flatnonzero(single)[np.argmax(diag[single])])
        best = (float(diag[i]), [i], np.ones(1))
    for c in np.flatnonzero(size > 1).tolist():
        members = np.flatnonzero(labels == c)
        lam, vec = np.linalg.eig(A[members][:, members].toarray())
        k = int(np.argmax(np.abs(lam)))
        if best is None or abs(lam[k]) > best[0]:
            best = (float(abs(lam[k])), members.tolist(), np.abs(vec[:, k]) ** 2)
    assert best is not None
    mag, idx, weight = best
    owners = [loop.owners[i] for i in idx]
    return (math.log(max(mag, LAMBDA_FLOOR)) / loop.dt, mag, _shares(weight, owners))


def _shares(weight: np.ndarray, owners: Sequence[str]) -> list[tuple[str, float]]:
    total = float(weight.sum()) or 1.0
    acc: dict[str, float] = {}
    for w, o in zip(weight.tolist(), owners, strict=True):
        acc[o] = acc.get(o, 0.0) + w / total
    return sorted(acc.items(), key=lambda kv: -kv[1])


#: |λ| per step within this of 1 is a marginal mode (an integrator nothing closes).
MARGINAL_TOL = 1e-4


@dataclass
class Mode:
    """One mode of a whole-loop A: ``|λ|`` per step and the modules' shares of it."""

    magnitude: float
    shares: list[tuple[str, float]]
    states: list[str] = field(default_factory=list)
    #: λ of A itself (over the map's span; one of a complex pair)
    value: complex = 0j

    def label(self, steps: int = 1) -> str:
        """``'λ = -1.05'`` for a real mode of a one-step map (the sign tells a period-2
        oscillation from a growth), else ``'|λ| = 0.999480'`` (per step)."""
        if steps == 1 and self.value.imag == 0:
            return f"λ = {self.value.real:+.6g}"
        return f"|λ| = {self.magnitude:.6f}"

    def where(self, top: int = 3) -> str:
        """``'chassis 50 %, odometry 50 %: chassis.pose[2], …'``: the modules (and states)."""
        mods = ", ".join(f"{m} {100 * s:.0f} %" for m, s in self.shares[:top] if s >= 0.005)
        return f"{mods}: {', '.join(self.states[:top])}" if self.states else mods


@dataclass
class WholeLoop:
    """The numerical linearization of a configuration's one-step map (every module's state).

    Attributes
    ----------
    A : numpy.ndarray or scipy.sparse.csr_matrix
        ``∂x_{k+steps} / ∂x_k``: discrete, over ``steps`` steps of ``dt``.
    dt : float
        The step (s).
    steps : int
        Steps the map spans (1: the one-step map).
    owners : list of str
        The module each state belongs to.
    labels : list of str
        ``module.field[i]`` per state.
    stateful : list of str
        The active modules with state (file order).
    problems : list of str
        Why the linearization cannot be trusted (empty: it can): a step that raised,
        a non-finite value, one-sided differences that disagree (a discontinuity).
    """

    A: object
    dt: float
    steps: int
    owners: list[str]
    labels: list[str]
    stateful: list[str]
    problems: list[str] = field(default_factory=list)

    def modes(self, tol: float = MARGINAL_TOL) -> tuple[float, list[Mode], list[Mode]]:
        """``(max |λ| per step, marginal modes, unstable modes)`` (largest first).

        Per strong component of A (dense eigen-decomposition of each; a component of
        more than 2000 states by ARPACK's few largest). |λ| per step is
        ``|λ(A)|^(1/steps)``; a mode is marginal within ``tol`` of 1, unstable above.
        One mode per complex pair.
        """
        A: Any = self.A if issparse(self.A) else np.atleast_2d(np.asarray(self.A, dtype=float))
        n = A.shape[0]
        if n == 0:
            return 0.0, [], []
        comp = strong_components(A)
        if issparse(A) or n > COMPONENTS_DENSE_MAX:
            import scipy.sparse

            A = scipy.sparse.csr_matrix(A)
        owners = self.owners
        found: list[Mode] = []
        worst = 0.0
        order = np.argsort(comp, kind="stable")
        bounds = np.flatnonzero(np.diff(comp[order])) + 1
        for members in np.split(order, bounds):
            if members.size == 1:
                i = int(members[0])
                lam = np.array([A[i, i]])
                vec = np.ones((1, 1))
            elif members.size > 2000:
                from scipy.sparse.linalg import eigs

                lam, vec = eigs(A[members][:, members].astype(float), k=6, which="LM")
            else:
                block = A[members][:, members]
                lam, vec = np.linalg.eig(block.toarray() if issparse(block) else block)
            mags = np.abs(lam) ** (1.0 / self.steps)
            worst = max(worst, float(mags.max()))
            for k in np.flatnonzero(mags > 1.0 - tol):
                if lam[k].imag < 0:
                    continue  # its conjugate stands for the pair
                w = np.abs(vec[:, k]) ** 2
                top = np.argsort(-w, kind="stable")[:3]
                found.append(Mode(float(mags[k]), _shares(w, [owners[i] for i in members]),
                                  [self.labels[int(members[t])] for t in top
                                   if w[t] >= 0.05 * w.sum()], complex(lam[k])))
        found.sort(key=lambda m: -m.magnitude)
        marginal = [m for m in found if m.magnitude <= 1.0 + tol]
        unstable = [m for m in found if m.magnitude > 1.0 + tol]
        return worst, marginal, unstable
