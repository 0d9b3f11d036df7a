"""Small graph algorithms for the checker, without importing networkx.

``archself validate`` must start fast, and ``import networkx`` alone costs a
quarter of a second; the checks need only strongly and weakly connected
components and one cycle, which are a few lines each. The runtime's Knowledge
graph and the reports use networkx.

Examples
--------
>>> succ = {"a": ["b"], "b": ["c"], "c": ["a"], "d": ["a"]}
>>> strongly_connected_components(succ)
[['a', 'b', 'c'], ['d']]
>>> find_cycle(succ)
['a', 'b', 'c']
>>> weakly_connected_components(["a", "b", "c", "x"], [("a", "b"), ("c", "b")])
[['a', 'b', 'c'], ['x']]
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Mapping, Sequence
from typing import TypeVar

Node = TypeVar("Node", bound=Hashable)


def strongly_connected_components(succ: Mapping[Node, Sequence[Node]]) -> list[list[Node]]:
    """Strongly connected components (iterative Tarjan), each in first-seen order.

    ``succ`` maps every node to its successors; nodes that appear only as
    successors are included.
    """
    nodes = list(dict.fromkeys([*succ, *(v for vs in succ.values() for v in vs)]))
    order = {n: i for i, n in enumerate(nodes)}
    index: dict[Node, int] = {}
    low: dict[Node, int] = {}
    on_stack: set[Node] = set()
    stack: list[Node] = []
    comps: list[list[Node]] = []
    counter = 0
    for root in nodes:
        if root in index:
            continue
        work = [(root, iter(succ.get(root, ())))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, it = work[-1]
            for nxt in it:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(succ.get(nxt, ()))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == node:
                            break
                    comps.append(sorted(comp, key=order.__getitem__))
    return sorted(comps, key=lambda c: order[c[0]])


def find_cycle(succ: Mapping[Node, Sequence[Node]]) -> list[Node] | None:
    """The nodes of one directed cycle (self-loops included), or None for a DAG."""
    for n, vs in succ.items():
        if n in vs:
            return [n]
    for comp in strongly_connected_components(succ):
        if len(comp) < 2:
            continue
        inside = set(comp)
        path, seen = [comp[0]], {comp[0]: 0}
        while True:
            nxt = next(v for v in succ.get(path[-1], ()) if v in inside)
            if nxt in seen:
                return path[seen[nxt]:]
            seen[nxt] = len(path)
            path.append(nxt)
    return None


def weakly_connected_components(
    nodes: Iterable[Node], edges: Iterable[tuple[Node, Node]]
) -> list[list[Node]]:
    """Connected components of the undirected version of a graph (union-find)."""
    order = list(dict.fromkeys(nodes))
    parent = {n: n for n in order}

    def root(n: Node) -> Node:
        while parent[n] != n:
            parent[n] = parent[parent[n]]
            n = parent[n]
        return n

    for a, b in edges:
        if a in parent and b in parent:
            ra, rb = root(a), root(b)
            if ra != rb:
                parent[rb] = ra
    groups: dict[Node, list[Node]] = {}
    for n in order:
        groups.setdefault(root(n), []).append(n)
    return list(groups.values())
