"""The data flow of one step: the algebraic-loop check and the step order (pure graph maths).

A step of :class:`archself.system.executor.LiveSystem` runs along the active edges into
modules with direct feedthrough. :func:`algebraic_loop` finds a cycle of that flow
(the executor's and ``archself validate``'s one check); :func:`topological_order`
orders an acyclic flow, ties by file order.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence

import numpy as np

__all__ = ["algebraic_loop", "topological_order"]


def algebraic_loop(flow: Sequence[tuple[str, str]]) -> list[str] | None:
    """One cycle of the data flow ``flow`` (pairs source → target), or None if it has none.

    The data flow of a step runs along the active edges into modules with direct
    feedthrough; a cycle of it is an algebraic loop, and the step cannot be
    ordered. This is the one check of it, used by the executor
    (:class:`LiveSystem`) and by ``archself validate`` (:mod:`archself.check`).
    The strong components come from :mod:`scipy.sparse.csgraph`. The cycle
    returned is a self-loop if there is one, else it starts at the module that
    is first a source in ``flow`` among those on a cycle and follows, from each
    module, its first edge that stays in the strong component.

    Examples
    --------
    >>> algebraic_loop([("a", "b"), ("b", "c"), ("c", "b")])
    ['b', 'c']
    >>> algebraic_loop([("a", "b"), ("a", "c")]) is None
    True
    """
    import scipy.sparse
    import scipy.sparse.csgraph

    for s, t in flow:
        if s == t:
            return [s]
    names = list(dict.fromkeys([s for s, _ in flow] + [t for _, t in flow]))  # sources first
    index = {name: i for i, name in enumerate(names)}
    n = len(index)
    rows = [index[s] for s, _ in flow]
    cols = [index[t] for _, t in flow]
    graph = scipy.sparse.coo_matrix((np.ones(len(flow)), (rows, cols)), shape=(n, n))
    ncomp, labels = scipy.sparse.csgraph.connected_components(
        graph, directed=True, connection="strong"
    )
    if ncomp == n:
        return None
    on_cycle = np.bincount(labels)[labels] > 1
    start = names[int(np.flatnonzero(on_cycle)[0])]
    comp = labels[index[start]]
    succ: dict[str, list[str]] = {}
    for s, t in flow:
        if labels[index[t]] == comp:
            succ.setdefault(s, []).append(t)
    path, seen = [start], {start: 0}
    while True:
        nxt = succ[path[-1]][0]
        if nxt in seen:
            return path[seen[nxt] :]
        seen[nxt] = len(path)
        path.append(nxt)


def topological_order(
    nodes: Sequence[str], flow: Sequence[tuple[str, str]], rank: dict[str, int]
) -> list[str]:
    """``nodes`` in topological order of the acyclic ``flow``, ties by ``rank`` (Kahn)."""
    succ: dict[str, list[str]] = {n: [] for n in nodes}
    indegree = dict.fromkeys(nodes, 0)
    for s, t in flow:
        succ[s].append(t)
        indegree[t] += 1
    ready = [(rank[n], n) for n in nodes if indegree[n] == 0]
    heapq.heapify(ready)
    order = []
    while ready:
        _, n = heapq.heappop(ready)
        order.append(n)
        for t in succ[n]:
            indegree[t] -= 1
            if indegree[t] == 0:
                heapq.heappush(ready, (rank[t], t))
    return order
