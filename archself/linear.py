"""The closed-loop A of a configuration from its modules' linear models, wired by its edges.

A module type may give a :class:`~archself.modules.base.LinearModel` (state space
with named input and output signals, :meth:`RuntimeModule.linear_model`). The
system (:meth:`archself.system.LiveSystem.closed_loop`) discretizes each model at
the run's step, wires them as the executor does — an input port receives the
outputs of the active edges that carry its signal into the module, an edge with a
latency becomes a chain of unit delays — and closes the loop::

    x⁺ = A x + B u,   y = C x + D u,   u = K y
    ⇒ x⁺ = (A + B K (I − D K)⁻¹ C) x

(``I − D K`` is invertible when the data flow has no algebraic loop, which the
executor requires.) Discrete time at the run's step is what the executor really
runs: a gain that is stable in continuous time but not at the sampling rate is
caught. For the eigenvalue margin of Eq. 21 (a continuous-time test) each
discrete eigenvalue λ is mapped to ``μ = ln(λ)/dt`` (``Re μ = ln|λ|/dt``).

Modules that give no model but a ``linearization()`` contribute that matrix as a
diagonal block, as before; so does a module whose model closes no loop with the
other models (a controller over a plant that has no model), because its own
dynamics alone (an open integrator) say less than its closed loop over a model.
The eigenvalues of a cascade are the union of those of its parts, so leaving such a
module out of the interconnection changes no other eigenvalue.

Large loops are sparse. Above :data:`DENSE_STATES` states the interconnection is
assembled as a ``scipy.sparse`` matrix, and :func:`eigenvalues` takes the
eigenvalues of each strong component of its pattern (a block triangular matrix
has those of its diagonal blocks): a 10^4-module cascade is 10^4 1×1 blocks, not
a dense 10^4 × 10^4 eigenproblem. Small loops keep the dense path as before.

Examples
--------
A plant ``x⁺ = 0.9 x + u`` under the static feedback ``u = −k y``:

>>> from archself.modules.base import LinearModel
>>> plant = LinearModel([[0.9]], [[1.0]], [[1.0]], [[0.0]], [("u", 1)], [("y", 1)], dt=0.1)
>>> gain = LinearModel([], [], [], [[-0.5]], [("y", 1)], [("u", 1)], dt=0.1)
>>> cl = interconnect({"p": plant, "k": gain}, [Wire("p", "k", "y"), Wire("k", "p", "u")], 0.1)
>>> cl.A.round(6).tolist()
[[0.4]]
"""

from __future__ import annotations

import contextlib
import gc
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import scipy.sparse

from archself.modules.base import LinearModel

__all__ = [
    "ClosedLoop",
    "DENSE_STATES",
    "Interconnection",
    "LinearizationError",
    "Wire",
    "discretize",
    "eigenvalues",
    "gc_paused",
    "interconnect",
    "loop_modules",
    "modal_form",
    "wiring",
]

#: Floor of |λ| when mapping a discrete eigenvalue to ln|λ|/dt (a pure delay has λ = 0).
_LAMBDA_FLOOR = 1e-12

#: Interconnections with more states than this are assembled as sparse matrices.
DENSE_STATES = 400


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
    if not scipy.sparse.issparse(A):
        A = np.atleast_2d(np.asarray(A, dtype=float))
        return np.linalg.eigvals(A) if A.size else np.zeros(0, dtype=complex)
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


@contextlib.contextmanager
def gc_paused() -> Iterator[None]:
    """Pause Python's cyclic garbage collector while the block runs (restored after).

    Wiring the models of 10^4 modules allocates some 10^5 small objects (models,
    ports, wires, index lists), none of them in a reference cycle; each allocation
    burst makes the collector walk every object of the process again (the running
    system's 10^5 and more), which cost a third of the closed loop's CPU at 10^4
    modules. Reference counting frees everything as before.

    Examples
    --------
    >>> import gc
    >>> with gc_paused():
    ...     gc.isenabled()
    False
    >>> gc.isenabled()
    True
    """
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


class LinearizationError(ValueError):
    """The models of a configuration cannot be wired (widths or periods disagree)."""


class Wire(NamedTuple):
    """An active edge as the interconnection sees it: ``source --signal--> target``.

    ``delay`` is the edge's latency in steps (a chain of unit delays). A named
    tuple, not a dataclass: a configuration of 10^5 edges makes 10^5 of them.
    """

    source: str
    target: str
    signal: str
    delay: int = 0


def discretize(model: LinearModel, dt: float) -> LinearModel:
    """``model`` at period ``dt``: zero-order hold of a continuous one, a discrete one as is.

    Raises
    ------
    LinearizationError
        For a discrete model whose period is not ``dt``.

    Examples
    --------
    >>> m = LinearModel([[-1.0]], [[1.0]], [[1.0]], [[0.0]], [("u", 1)], [("y", 1)])
    >>> d = discretize(m, 0.1)
    >>> round(float(d.A[0, 0]), 6), round(float(d.B[0, 0]), 6), d.dt
    (0.904837, 0.095163, 0.1)
    """
    if model.dt > 0:
        if abs(model.dt - dt) > 1e-9 * max(1.0, dt):
            raise LinearizationError(
                f"a discrete model of period {model.dt:g} s in a run with step {dt:g} s"
            )
        return model
    n, m = model.n, model.m
    if n == 0:
        Ad, Bd = model.A, model.B
    else:
        from scipy.linalg import expm

        big = np.zeros((n + m, n + m))
        big[:n, :n] = model.A * dt
        big[:n, n:] = model.B * dt
        e = expm(big)
        Ad, Bd = e[:n, :n], e[:n, n:]
    return LinearModel(Ad, Bd, model.C, model.D, model.inputs, model.outputs, dt, model.states)


def _delay_line(signal: str, width: int, steps: int, dt: float) -> LinearModel:
    """``steps`` unit delays of a ``width``-vector: ``y_k = u_{k−steps}``."""
    n = width * steps
    A = np.zeros((n, n))
    A[width:, :-width] = np.eye(n - width)
    B = np.zeros((n, width))
    B[:width] = np.eye(width)
    C = np.zeros((width, n))
    C[:, -width:] = np.eye(width)
    states = [f"{signal}[t-{k + 1}]" for k in range(steps) for _ in range(width)]
    return LinearModel(
        A, B, C, np.zeros((width, width)), [(signal, width)], [(signal, width)], dt, states
    )


def _ports(
    model: LinearModel,
) -> tuple[list[tuple[str, int, int | None, int]], dict[str, tuple[int, int]]]:
    """Input ports ``(signal, size, edge, offset)``; outputs signal -> ``(offset, size)``."""
    ins = []
    k = 0
    for sig, size, edge in model.inputs:  # type: ignore[misc]
        ins.append((sig, size, edge, k))
        k += size
    outs: dict[str, tuple[int, int]] = {}
    k = 0
    for sig, size in model.outputs:  # type: ignore[misc]
        outs.setdefault(sig, (k, size))
        k += size
    return ins, outs


def wiring(models: Mapping[str, LinearModel], wires: Sequence[Wire]) -> list[tuple[Wire, int]]:
    """The wires that connect a model's output to a model's input port, with the port's index.

    The one pass over the wires that :func:`loop_modules` and :func:`interconnect`
    share (``routes=``): a caller that needs both computes it once.

    Examples
    --------
    >>> m = LinearModel([], [], [], [[1.0]], [("a", 1)], [("a", 1)], dt=0.1)
    >>> wiring({"x": m, "y": m}, [Wire("x", "y", "a"), Wire("y", "z", "a")])
    [(Wire(source='x', target='y', signal='a', delay=0), 0)]
    """
    into: dict[tuple[str, str], list[Wire]] = {}
    for w in wires:
        key = (w.target, w.signal)
        found = into.get(key)
        if found is None:
            into[key] = [w]
        else:
            found.append(w)
    gives = {name: {o[0] for o in model.outputs} for name, model in models.items()}
    out = []
    for name, model in models.items():
        for j, (sig, _size, edge) in enumerate(model.inputs):  # type: ignore[misc]
            found = into.get((name, sig))
            if not found:
                continue
            for w in found if edge is None else found[edge : edge + 1]:
                src = gives.get(w.source)
                if src is not None and sig in src:
                    out.append((w, j))
    return out


def loop_modules(
    models: Mapping[str, LinearModel],
    wires: Sequence[Wire],
    *,
    routes: Sequence[tuple[Wire, int]] | None = None,
) -> set[str]:
    """The modules that lie on a feedback loop of wires between models.

    ``routes`` is :func:`wiring` of the same models and wires, if already made.

    Examples
    --------
    >>> m = LinearModel([], [], [], [[1.0]], [("a", 1)], [("a", 1)], dt=0.1)
    >>> sorted(loop_modules({"x": m, "y": m, "z": m},
    ...                     [Wire("x", "y", "a"), Wire("y", "x", "a"), Wire("y", "z", "a")]))
    ['x', 'y']
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    names = list(models)
    index = {n: i for i, n in enumerate(names)}
    if routes is None:
        routes = wiring(models, wires)
    pairs = {(index[w.source], index[w.target]) for w, _ in routes}
    if not pairs:
        return set()
    rows, cols = zip(*pairs, strict=True)
    g = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(names), len(names)))
    _, labels = connected_components(g, directed=True, connection="strong")
    size = np.bincount(labels)
    on = {names[i] for i in np.flatnonzero(size[labels] > 1).tolist()}
    on.update(names[s] for s, t in pairs if s == t)
    return on


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


def interconnect(
    models: Mapping[str, LinearModel],
    wires: Sequence[Wire],
    dt: float,
    *,
    routes: Sequence[tuple[Wire, int]] | None = None,
) -> Interconnection:
    """Wire the models along ``wires`` and close the loop (discrete at ``dt``).

    Outputs of modules without a model, and inputs that no modelled source drives,
    are exogenous: they do not enter the closed-loop A. An edge with a ``delay``
    between two models becomes a delay line of its own states. ``routes`` is
    :func:`wiring` of these wires and of ``models`` or more models, if already
    made (the routes between ``models`` are taken from it).

    Raises
    ------
    LinearizationError
        When a port's width differs from its source's, a model's period is not
        ``dt``, or the loop is algebraic (``I − D K`` singular).
    """
    disc: dict[str, LinearModel] = {}
    for name, model in models.items():
        try:
            disc[name] = discretize(model, dt)
        except LinearizationError as exc:
            raise LinearizationError(f"{name}: {exc}") from None
    # latency: a delay line between the two models, wired in place of the edge
    plain: list[Wire] = []
    lines = False
    for w in wires:
        if w.delay > 0 and w.source in disc and w.target in disc:
            src = disc[w.source]
            width = next((s for sig, s in src.outputs if sig == w.signal), None)  # type: ignore[misc]
            if width is not None:
                line = f"{w.source}→{w.target}"
                disc[line] = _delay_line(w.signal, width, w.delay, dt)
                plain += [Wire(w.source, line, w.signal), Wire(line, w.target, w.signal)]
                lines = True
                continue
        plain.append(w)
    if routes is None or lines:
        routes = wiring(disc, plain)
    else:  # made for these models or more: those between these models
        routes = [r for r in routes if r[0].source in disc and r[0].target in disc]
    names = list(disc)
    xo, uo, yo = {}, {}, {}
    n = m = p = 0
    for name in names:
        mod = disc[name]
        xo[name], uo[name], yo[name] = n, m, p
        n, m, p = n + mod.n, m + mod.m, p + mod.p
    if n > DENSE_STATES:
        return _interconnect_sparse(disc, routes, (xo, uo, yo), (n, m, p), dt)
    A = np.zeros((n, n))
    B = np.zeros((n, m))
    C = np.zeros((p, n))
    D = np.zeros((p, m))
    owners: list[str] = []
    labels: list[str] = []
    ports = {}
    for name in names:
        mod = disc[name]
        x, u, y = xo[name], uo[name], yo[name]
        A[x : x + mod.n, x : x + mod.n] = mod.A
        B[x : x + mod.n, u : u + mod.m] = mod.B
        C[y : y + mod.p, x : x + mod.n] = mod.C
        D[y : y + mod.p, u : u + mod.m] = mod.D
        owners += [name] * mod.n
        labels += [f"{name}.{s}" for s in mod.states]
        ports[name] = _ports(mod)
    K = np.zeros((m, p))
    for w, j in routes:
        sig, size, _edge, off = ports[w.target][0][j]
        y_off, y_size = ports[w.source][1][w.signal]
        if y_size != size:
            raise LinearizationError(
                f"{w.source}.{w.signal} has {y_size} component(s), {w.target} takes {size}"
            )
        r = uo[w.target] + off
        c = yo[w.source] + y_off
        K[r : r + size, c : c + size] += np.eye(size)
    if n == 0:
        return Interconnection(np.zeros((0, 0)), dt, owners, labels)
    M = np.eye(p) - D @ K
    try:
        Y = np.linalg.solve(M, C)  # y = (I − D K)⁻¹ C x
    except np.linalg.LinAlgError:
        raise LinearizationError("the wired models form an algebraic loop") from None
    return Interconnection(A + B @ K @ Y, dt, owners, labels)


def _blocks(
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    blocks: list[np.ndarray],
    r0: np.ndarray,
    c0: np.ndarray,
) -> None:
    """Append the nonzero entries of equal-shaped ``blocks`` placed at ``(r0[k], c0[k])``."""
    arr = np.stack(blocks)  # (count, rows, cols)
    if not arr.size:
        return
    _, r, c = arr.shape
    rows = np.broadcast_to(r0[:, None, None] + np.arange(r)[None, :, None], arr.shape)
    cols = np.broadcast_to(c0[:, None, None] + np.arange(c)[None, None, :], arr.shape)
    nz = arr != 0
    parts.append((rows[nz], cols[nz], arr[nz]))


def _interconnect_sparse(
    disc: Mapping[str, LinearModel],
    routes: Sequence[tuple[Wire, int]],
    offsets: tuple[dict[str, int], dict[str, int], dict[str, int]],
    sizes: tuple[int, int, int],
    dt: float,
) -> Interconnection:
    """:func:`interconnect` of many states, with ``scipy.sparse`` matrices.

    The block diagonals of A, B, C and D are assembled from arrays: the models are
    grouped by shape and each group's blocks are stacked and placed at once.
    """
    from scipy.sparse.csgraph import connected_components

    xo, uo, yo = offsets
    n, m, p = sizes
    parts: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {k: [] for k in "ABCDK"}
    owners: list[str] = []
    labels: list[str] = []
    ports = {}
    shapes: dict[tuple[int, ...], list[str]] = {}
    for name, mod in disc.items():
        shapes.setdefault(mod.B.shape + mod.C.shape[:1], []).append(name)
        owners += [name] * mod.n
        labels += [f"{name}.{s}" for s in mod.states]
        ports[name] = _ports(mod)
    for names in shapes.values():
        x = np.array([xo[k] for k in names], dtype=np.intp)
        u = np.array([uo[k] for k in names], dtype=np.intp)
        y = np.array([yo[k] for k in names], dtype=np.intp)
        group = [disc[k] for k in names]
        _blocks(parts["A"], [g.A for g in group], x, x)
        _blocks(parts["B"], [g.B for g in group], x, u)
        _blocks(parts["C"], [g.C for g in group], y, x)
        _blocks(parts["D"], [g.D for g in group], y, u)
    krows: list[int] = []
    kcols: list[int] = []
    for w, j in routes:
        sig, size, _edge, off = ports[w.target][0][j]
        y_off, y_size = ports[w.source][1][w.signal]
        if y_size != size:
            raise LinearizationError(
                f"{w.source}.{w.signal} has {y_size} component(s), {w.target} takes {size}"
            )
        r0, c0 = uo[w.target] + off, yo[w.source] + y_off
        krows += range(r0, r0 + size)
        kcols += range(c0, c0 + size)
    k_at = (np.array(krows, dtype=np.intp), np.array(kcols, dtype=np.intp))
    parts["K"].append((*k_at, np.ones(len(krows))))

    def mat(key: str, shape: tuple[int, int]) -> scipy.sparse.csr_matrix:
        got = parts[key]
        rows = np.concatenate([g[0] for g in got]) if got else np.zeros(0, dtype=np.intp)
        cols = np.concatenate([g[1] for g in got]) if got else np.zeros(0, dtype=np.intp)
        vals = np.concatenate([g[2] for g in got]) if got else np.zeros(0)
        coo = (vals.astype(float), (rows.astype(np.intp), cols.astype(np.intp)))
        return scipy.sparse.csr_matrix(coo, shape=shape)  # duplicates add up, as += does

    A, B, C = mat("A", (n, n)), mat("B", (n, m)), mat("C", (p, n))
    D, K = mat("D", (p, m)), mat("K", (m, p))
    DK = (D @ K).tocsr()
    DK.eliminate_zeros()
    Y = C  # y = (I − D K)⁻¹ C x
    if DK.nnz:
        count, _ = connected_components(DK, directed=True, connection="strong")
        if count == p and not DK.diagonal().any():
            # no loop through feed-through models: D K is nilpotent, the series ends
            term = C
            for _ in range(p):
                term = (DK @ term).tocsr()
                term.eliminate_zeros()
                if not term.nnz:
                    break
                Y = Y + term
        else:
            from scipy.sparse.linalg import splu

            try:
                lu = splu((scipy.sparse.identity(p, format="csc") - DK).tocsc())
            except RuntimeError:
                raise LinearizationError("the wired models form an algebraic loop") from None
            Y = scipy.sparse.csr_matrix(lu.solve(C.toarray()))
    closed = (A + B @ K @ Y).tocsr()
    return Interconnection(closed, dt, owners, labels)


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
    if scipy.sparse.issparse(Ad):
        return _modal_sparse(eigenvalues(Ad), dt)
    lam = np.linalg.eigvals(np.atleast_2d(Ad)) if Ad.size else np.zeros(0)
    blocks = []
    for z in lam:
        a = math.log(max(abs(z), _LAMBDA_FLOOR)) / dt
        if z.imag > 1e-12:
            w = math.atan2(z.imag, z.real) / dt
            blocks.append(np.array([[a, w], [-w, a]]))
        elif z.imag >= -1e-12:
            blocks.append(np.array([[a]]))
    return _block_diag(blocks)


def _modal_sparse(lam: np.ndarray, dt: float) -> scipy.sparse.csr_matrix:
    """:func:`modal_form` of the eigenvalues ``lam``, as a sparse matrix."""
    a = np.log(np.maximum(np.abs(lam), _LAMBDA_FLOOR)) / dt
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
    return scipy.sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(size, size)
    )


def _block_diag(blocks: Sequence[Any]) -> Any:
    if any(scipy.sparse.issparse(b) for b in blocks):
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
        return _block_diag(parts)

    @property
    def modules(self) -> list[str]:
        """The modules that contribute states."""
        seen = dict.fromkeys(self.loop.owners if self.loop is not None else [])
        seen.update(dict.fromkeys(n for n, _ in self.blocks))
        return list(seen)

    def worst_mode(self) -> tuple[float, float | None, list[tuple[str, float]]] | None:
        """``(max Re μ, |λ| or None, [(module, share), ...])`` of the least stable mode.

        ``μ`` is the continuous-equivalent eigenvalue; ``|λ|`` its discrete
        magnitude when it comes from the wired part (per step). The shares are the
        fractions of the mode's eigenvector (``|v_j|²``, normalized) in each module's
        states, largest first. None when there are no states.
        """
        best: tuple[float, float | None, list[tuple[str, float]]] | None = None
        if self.loop is not None and scipy.sparse.issparse(self.loop.A):
            best = _worst_sparse(self.loop)
        elif self.loop is not None and self.loop.A.size:
            lam, vec = np.linalg.eig(self.loop.A)
            mag = np.maximum(np.abs(lam), _LAMBDA_FLOOR)
            k = int(np.argmax(mag))
            best = (
                math.log(mag[k]) / self.loop.dt,
                float(np.abs(lam[k])),
                _shares(np.abs(vec[:, k]) ** 2, self.loop.owners),
            )
        for name, b in self.blocks:
            if not b.size:
                continue
            worst = float(np.max(np.linalg.eigvals(b).real))
            if best is None or worst > best[0]:
                best = (worst, None, [(name, 1.0)])
        return best


def _worst_sparse(loop: Interconnection) -> tuple[float, float, list[tuple[str, float]]] | None:
    """``worst_mode`` of a sparse loop: the largest |λ| of the strong components' blocks.

    The shares are those of the eigenvector of the component's own block (the
    mode's states in that component; its echo in the components downstream is
    not counted).
    """
    from scipy.sparse.csgraph import connected_components

    A = scipy.sparse.csr_matrix(loop.A)
    if not A.shape[0]:
        return None
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
    return (math.log(max(mag, _LAMBDA_FLOOR)) / loop.dt, mag, _shares(weight, owners))


def _shares(weight: np.ndarray, owners: Sequence[str]) -> list[tuple[str, float]]:
    total = float(weight.sum()) or 1.0
    acc: dict[str, float] = {}
    for w, o in zip(weight.tolist(), owners, strict=True):
        acc[o] = acc.get(o, 0.0) + w / total
    return sorted(acc.items(), key=lambda kv: -kv[1])
