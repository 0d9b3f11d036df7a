"""The closed-loop A of a configuration from its modules' linear models, wired by its edges.

A module type may give a :class:`~archself.modules.base.LinearModel` (state space
with named input and output signals, :meth:`RuntimeModule.linear_model`). The
system (:meth:`archself.system.live.LiveSystem.closed_loop`) discretizes each model at
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

The wiring and the dense closed loop are here; the discretization is in
:mod:`archself.linear.discrete`, the sparse assembly in :mod:`archself.linear.assembly`, the
eigenvalue maths in :mod:`archself.linear.closed_loop` and the result types
(:class:`~archself.linear.closed_loop.Interconnection`,
:class:`~archself.linear.closed_loop.ClosedLoop`)
in :mod:`archself.linear.closed_loop`; their public names are re-exported here.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from archself.linear.assembly import Wire, feedback_slices, interconnect_sparse, port_offsets
from archself.linear.closed_loop import (
    COMPONENTS_DENSE_MAX,
    ClosedLoop,
    Interconnection,
    eigenvalues,
    modal_form,
    strong_components,
)
from archself.linear.discrete import LinearizationError, delay_line, discretize
from archself.model.loader import gc_paused
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

#: Interconnections with more states than this are assembled as sparse matrices.
DENSE_STATES = 400


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
        into.setdefault((w.target, w.signal), []).append(w)
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
    names = list(models)
    index = {n: i for i, n in enumerate(names)}
    if routes is None:
        routes = wiring(models, wires)
    pairs = {(index[w.source], index[w.target]) for w, _ in routes}
    if not pairs:
        return set()
    rows, cols = zip(*pairs, strict=True)
    n = len(names)
    if n <= COMPONENTS_DENSE_MAX:
        g: Any = np.zeros((n, n))
        g[rows, cols] = 1.0
    else:
        from scipy.sparse import csr_matrix

        g = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    labels = strong_components(g)
    size = np.bincount(labels)
    on = {names[i] for i in np.flatnonzero(size[labels] > 1).tolist()}
    on.update(names[s] for s, t in pairs if s == t)
    return on


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
    for w in wires:
        if w.delay > 0 and w.source in disc and w.target in disc:
            src = disc[w.source]
            width = next((s for sig, s in src.outputs if sig == w.signal), None)  # type: ignore[misc]
            if width is not None:
                line = f"{w.source}→{w.target}"
                disc[line] = delay_line(w.signal, width, w.delay, dt)
                plain += [Wire(w.source, line, w.signal), Wire(line, w.target, w.signal)]
                continue
        plain.append(w)
    if routes is None or len(plain) > len(wires):  # not made, or delay lines added
        routes = wiring(disc, plain)
    else:  # made for these models or more: those between these models
        routes = [r for r in routes if r[0].source in disc and r[0].target in disc]
    xo, uo, yo = {}, {}, {}
    n = m = p = 0
    owners: list[str] = []
    labels: list[str] = []
    ports = {}
    for name, mod in disc.items():
        xo[name], uo[name], yo[name] = n, m, p
        n, m, p = n + mod.n, m + mod.m, p + mod.p
        owners += [name] * mod.n
        labels += [f"{name}.{s}" for s in mod.states]
        ports[name] = port_offsets(mod)
    feedback = list(feedback_slices(routes, ports, uo, yo))
    if n == 0:
        return Interconnection(np.zeros((0, 0)), dt, owners, labels)
    if n > DENSE_STATES:
        closed = interconnect_sparse(disc, (xo, uo, yo), (n, m, p), feedback)
        return Interconnection(closed, dt, owners, labels)
    A = np.zeros((n, n))
    B = np.zeros((n, m))
    C = np.zeros((p, n))
    D = np.zeros((p, m))
    for name, mod in disc.items():
        x, u, y = xo[name], uo[name], yo[name]
        A[x : x + mod.n, x : x + mod.n] = mod.A
        B[x : x + mod.n, u : u + mod.m] = mod.B
        C[y : y + mod.p, x : x + mod.n] = mod.C
        D[y : y + mod.p, u : u + mod.m] = mod.D
    K = np.zeros((m, p))
    for r, c, size in feedback:
        K[r : r + size, c : c + size] += np.eye(size)
    try:
        Y = np.linalg.solve(np.eye(p) - D @ K, C)  # y = (I − D K)⁻¹ C x
    except np.linalg.LinAlgError:
        raise LinearizationError("the wired models form an algebraic loop") from None
    return Interconnection(A + B @ K @ Y, dt, owners, labels)
