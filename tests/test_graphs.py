"""The data-flow graph algorithms (scipy.sparse.csgraph based) agree with networkx."""

from __future__ import annotations

import networkx as nx
from hypothesis import given, settings
from hypothesis import strategies as st

from archself.system.dataflow import algebraic_loop, topological_order

NODES = [f"n{i:02d}" for i in range(13)]
edges_st = st.lists(st.tuples(st.integers(0, 12), st.integers(0, 12)), max_size=40)


@settings(max_examples=200, deadline=None)
@given(edges_st)
def test_algebraic_loop_and_order_match_networkx(pairs: list[tuple[int, int]]) -> None:
    flow = [(NODES[a], NODES[b]) for a, b in pairs]
    g = nx.DiGraph()
    g.add_nodes_from(NODES)
    g.add_edges_from(flow)
    loop = algebraic_loop(flow)
    assert (loop is None) == nx.is_directed_acyclic_graph(g)
    if loop is not None:
        ring = list(zip(loop, loop[1:] + loop[:1], strict=True))
        assert all(g.has_edge(a, b) for a, b in ring)
        assert len(set(loop)) == len(loop)
        return
    rank = {n: -k for k, n in enumerate(NODES)}  # ties by a rank that is not the name order
    expected = list(nx.lexicographical_topological_sort(g, key=rank.__getitem__))
    assert topological_order(NODES, flow, rank) == expected


def test_loop_starts_at_the_first_source_and_follows_first_edges() -> None:
    flow = [("x", "a"), ("c", "a"), ("a", "b"), ("b", "c"), ("b", "a")]
    assert algebraic_loop(flow) == ["c", "a", "b"]  # c is the first source on a cycle
    assert algebraic_loop([("a", "b"), ("b", "b")]) == ["b"]
    assert algebraic_loop([]) is None
