"""The checker's small graph algorithms agree with networkx."""

from __future__ import annotations

import networkx as nx
from hypothesis import given, settings
from hypothesis import strategies as st

from archself.graphs import find_cycle, strongly_connected_components, weakly_connected_components

edges_st = st.lists(st.tuples(st.integers(0, 12), st.integers(0, 12)), max_size=40)


def _succ(edges: list[tuple[int, int]]) -> dict[int, list[int]]:
    succ: dict[int, list[int]] = {n: [] for n in range(13)}
    for a, b in edges:
        if b not in succ[a]:
            succ[a].append(b)
    return succ


@settings(max_examples=200, deadline=None)
@given(edges_st)
def test_components_and_cycles_match_networkx(edges: list[tuple[int, int]]) -> None:
    g = nx.DiGraph()
    g.add_nodes_from(range(13))
    g.add_edges_from(edges)
    ours = {frozenset(c) for c in strongly_connected_components(_succ(edges))}
    assert ours == {frozenset(c) for c in nx.strongly_connected_components(g)}
    weak = {frozenset(c) for c in weakly_connected_components(range(13), edges)}
    assert weak == {frozenset(c) for c in nx.weakly_connected_components(g)}
    cycle = find_cycle(_succ(edges))
    assert (cycle is None) == nx.is_directed_acyclic_graph(g)
    if cycle is not None:
        ring = list(zip(cycle, cycle[1:] + cycle[:1], strict=True))
        assert all(g.has_edge(a, b) for a, b in ring)
