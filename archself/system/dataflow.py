"""The data flow of one step: the algebraic-loop check and the step order (pure graph maths).

A step of :class:`archself.system.live.LiveSystem` runs along the active edges into
modules with direct feedthrough. :func:`algebraic_loop` finds a cycle of that flow
(the executor's and ``archself validate``'s one check); :func:`topological_order`
orders an acyclic flow, ties by file order.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence

__all__ = ["algebraic_loop", "strong_components", "topological_order"]


def algebraic_loop(flow: Sequence[tuple[str, str]]) -> list[str] | None:
    """One cycle of the data flow ``flow`` (pairs source → target), or None if it has none.

    The data flow of a step runs along the active edges into modules with direct
    feedthrough; a cycle of it is an algebraic loop, and the step cannot be
    ordered. This is the one check of it, used by the executor
    (:class:`LiveSystem`) and by ``archself validate`` (:mod:`archself.check`).
    The strong components come from :func:`strong_components`. The cycle
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
    for s, t in flow:
        if s == t:
            return [s]
    names = list(dict.fromkeys([s for s, _ in flow] + [t for _, t in flow]))  # sources first
    labels = strong_components(names, flow)
    size = dict.fromkeys(labels.values(), 0)
    for c in labels.values():
        size[c] += 1
    start = next((m for m in names if size[labels[m]] > 1), None)
    if start is None:
        return None
    comp = labels[start]
    succ: dict[str, list[str]] = {}
    for s, t in flow:
        if labels[t] == comp:
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


def strong_components(
    nodes: Sequence[str], flow: Sequence[tuple[str, str]]
) -> dict[str, int]:
    """The strongly connected component of each node (Tarjan's algorithm, iterative):
    two nodes have the same label when each reaches the other.

    Examples
    --------
    >>> c = strong_components(["a", "b", "c"], [("a", "b"), ("b", "c"), ("c", "b")])
    >>> c["b"] == c["c"] != c["a"]
    True
    """
    succ: dict[str, list[str]] = {n: [] for n in nodes}
    for s, t in flow:
        succ[s].append(t)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    label: dict[str, int] = {}
    stack: list[str] = []
    for root in nodes:
        if root in index:
            continue
        work = [(root, 0)]
        while work:
            v, i = work.pop()
            if i == 0:
                index[v] = low[v] = len(index)
                stack.append(v)
            elif (w := succ[v][i - 1]) not in label:  # returned from w
                low[v] = min(low[v], low[w])
            for j in range(i, len(succ[v])):
                w = succ[v][j]
                if w not in index:
                    work += [(v, j + 1), (w, 0)]
                    break
                if w not in label:
                    low[v] = min(low[v], index[w])
            else:
                if low[v] == index[v]:
                    while True:
                        w = stack.pop()
                        label[w] = index[v]
                        if w == v:
                            break
    return label
