"""Assembling the matrices of wired models: port offsets, and the sparse path of large loops.

:func:`port_offsets` gives where each input port and output signal of a model sits
in its B/D columns and C/D rows; :func:`interconnect_sparse` is
:func:`archself.linear.wiring.interconnect` above :data:`archself.linear.wiring.DENSE_STATES`
states, with the block diagonals stacked per model shape into ``scipy.sparse``
matrices.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from archself.linear.discrete import LinearizationError
from archself.modules.base import LinearModel

if TYPE_CHECKING:  # scipy is imported where a large loop needs it, not with the system
    import scipy.sparse

__all__ = ["Wire", "feedback_slices", "interconnect_sparse", "port_offsets"]


class Wire(NamedTuple):
    """An active edge as the interconnection sees it: ``source --signal--> target``.

    ``delay`` is the edge's latency in steps (a chain of unit delays). A named
    tuple, not a dataclass: a configuration of 10^5 edges makes 10^5 of them.
    """

    source: str
    target: str
    signal: str
    delay: int = 0


def port_offsets(
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


def feedback_slices(
    routes: Sequence[tuple[Wire, int]],
    ports: Mapping[str, tuple[list[tuple[str, int, int | None, int]], dict[str, tuple[int, int]]]],
    uo: Mapping[str, int],
    yo: Mapping[str, int],
) -> Iterator[tuple[int, int, int]]:
    """``(row, column, size)`` of each route's identity block in K (``u = K y``).

    The row is the target's input port in the stacked u, the column the source's
    output in the stacked y; ``ports`` is :func:`port_offsets` of each model.

    Raises
    ------
    LinearizationError
        When a port's width differs from its source's.
    """
    for w, j in routes:
        _sig, size, _edge, off = ports[w.target][0][j]
        y_off, y_size = ports[w.source][1][w.signal]
        if y_size != size:
            raise LinearizationError(
                f"{w.source}.{w.signal} has {y_size} component(s), {w.target} takes {size}"
            )
        yield uo[w.target] + off, yo[w.source] + y_off, size


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


def interconnect_sparse(
    disc: Mapping[str, LinearModel],
    offsets: tuple[dict[str, int], dict[str, int], dict[str, int]],
    sizes: tuple[int, int, int],
    feedback: Sequence[tuple[int, int, int]],
) -> scipy.sparse.csr_matrix:
    """The closed-loop A of :func:`interconnect` for many states, as a ``scipy.sparse`` matrix.

    ``disc`` are the discrete models at their state, input and output ``offsets``,
    ``sizes`` the stacked widths (n, m, p) and ``feedback`` :func:`feedback_slices`.
    The block diagonals of A, B, C and D are assembled from arrays: the models are
    grouped by shape and each group's blocks are stacked and placed at once.
    """
    import scipy.sparse
    from scipy.sparse.csgraph import connected_components

    xo, uo, yo = offsets
    n, m, p = sizes
    parts: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {k: [] for k in "ABCDK"}
    shapes: dict[tuple[int, ...], list[str]] = {}
    for name, mod in disc.items():
        shapes.setdefault(mod.B.shape + mod.C.shape[:1], []).append(name)
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
    for r0, c0, size in feedback:
        krows += range(r0, r0 + size)
        kcols += range(c0, c0 + size)
    k_at = (np.array(krows, dtype=np.intp), np.array(kcols, dtype=np.intp))
    parts["K"].append((*k_at, np.ones(len(krows))))

    def mat(key: str, shape: tuple[int, int]) -> scipy.sparse.csr_matrix:
        if not parts[key]:
            return scipy.sparse.csr_matrix(shape)
        rows, cols, vals = (np.concatenate(g) for g in zip(*parts[key], strict=True))
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
    return (A + B @ K @ Y).tocsr()
