"""Design Structure Matrix (DSM) of an architecture: the report model, no rendering.

Convention (the paper's Eq. 13): the cell in **row j, column i** is
``W_ji = ω_ji``, the influence of the row module m_j on the column module m_i,
i.e. the summed weight of the edges ``m_j → m_i`` (parallel edges add up, as in
:func:`archself.runtime.influence.weight_matrix`). A row reads "what this module
feeds", a column "what this module depends on".

Three orderings of the same matrix:

``kind``
    Modules grouped by kind (physical M_P, functional M_F, model M_M), in file order.
``sequenced``
    Strongly connected components of the dependency digraph (networkx
    condensation) in topological order; inside a component the members are
    ordered by the greedy heuristic of Eades, Lin and Smyth (1993) so that little
    weight falls below the diagonal (ties: kind, then file order). Components
    with more than one module are the *coupled blocks*; with this convention a
    dependency on a later module (an entry below the diagonal, row after column)
    is a *feedback* mark and only occurs inside coupled blocks.
``clustered``
    Weighted communities (networkx Louvain on the weighted digraph with a fixed
    seed), largest first, members in sequenced order.

In every ordering a cell is *coupled* when its row and column modules belong to one
coupled block (the same strongly connected component of two or more modules), wherever
the ordering puts them: a community or a kind group may hold uncoupled modules beside
coupled ones, and only the truly coupled pairs are marked.

Examples
--------
>>> from archself.model.loader import load_architecture
>>> from archself.resources import data_dir
>>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
>>> dsm = build_dsm(arch, "a1")
>>> dsm.weight("imu", "odometry")
0.6
>>> [b.members for b in sequence(dsm).blocks if b.coupled][0][:3]
('chassis', 'encoders', 'imu')
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cached_property

import networkx as nx

from archself.check.rules import active_edges
from archself.model.architecture import Architecture

__all__ = [
    "KINDS",
    "Block",
    "Dsm",
    "DsmCell",
    "DsmModule",
    "Ordering",
    "build_dsm",
    "cluster",
    "condense",
    "orderings",
    "order_by_kind",
    "scope_edges",
    "sequence",
]

KINDS = ("physical", "functional", "model")
KIND_TITLES = {
    "physical": "physical (M_P)",
    "functional": "functional (M_F)",
    "model": "model (M_M)",
}
CLUSTER_SEED = 0
#: a scope with more modules is reported between its communities (:func:`condense`)
FULL_MATRIX_MAX = 150


@dataclass(frozen=True)
class DsmModule:
    """A row/column of the DSM."""

    name: str
    kind: str
    type: str
    description: str = ""


@dataclass(frozen=True)
class Dsm:
    """The weighted dependency matrix of one scope (whole architecture or a configuration).

    Attributes
    ----------
    scope : str
        ``"architecture"`` or the configuration name.
    title : str
        Human title of the scope.
    modules : tuple of DsmModule
        The modules of the scope in file order.
    weights : dict of (source, target) -> float
        ``W_ji`` for every (m_j, m_i) with at least one edge.
    carries : dict of (source, target) -> tuple of str
        The signals of those edges.
    max_weight : float
        Largest ``W_ji`` of the whole architecture (the shading scale, shared by all scopes).
    """

    scope: str
    title: str
    modules: tuple[DsmModule, ...]
    weights: dict[tuple[str, str], float]
    carries: dict[tuple[str, str], tuple[str, ...]]
    max_weight: float
    description: str = ""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.modules)

    @cached_property
    def _by_name(self) -> dict[str, DsmModule]:
        return {m.name: m for m in self.modules}

    def module(self, name: str) -> DsmModule:
        return self._by_name[name]

    def weight(self, source: str, target: str) -> float:
        """``W_ji`` with j = ``source`` (row) and i = ``target`` (column); 0 without an edge."""
        return self.weights.get((source, target), 0.0)

    def digraph(self) -> nx.DiGraph:
        """The scope as a weighted networkx digraph (nodes in file order)."""
        g = nx.DiGraph()
        g.add_nodes_from(self.names)
        for (s, t), w in self.weights.items():
            g.add_edge(s, t, weight=w)
        return g


@dataclass(frozen=True)
class Block:
    """A diagonal block of an ordering: a kind group, a component or a community.

    ``coupled`` is true only for a strongly connected component of two or more modules
    (a block of the sequenced ordering, or one of :attr:`Ordering.coupled_blocks`).
    """

    label: str
    members: tuple[str, ...]
    coupled: bool = False


@dataclass(frozen=True)
class DsmCell:
    """One cell of an ordered DSM, with what a renderer needs to draw it."""

    row: str
    col: str
    weight: float
    carries: tuple[str, ...]
    shade: float  # weight / max_weight, 0..1
    diagonal: bool
    in_block: bool  # row and column in the same diagonal block
    coupled: bool  # row and column in the same coupled block (strongly connected component)
    feedback: bool  # a mark below the diagonal (row after column)
    block_top: bool  # the row is the first of its block (draw a border above)
    block_left: bool  # the column is the first of its block (draw a border left)


@dataclass(frozen=True)
class Ordering:
    """A permutation of the DSM with its diagonal blocks."""

    key: str  # "kind", "sequenced", "clustered"
    title: str
    explanation: str
    order: tuple[str, ...]
    blocks: tuple[Block, ...]
    modules: tuple[DsmModule, ...] = field(default=())
    coupled_blocks: tuple[Block, ...] = field(default=())  # the scope's coupled components

    def block_of(self) -> dict[str, int]:
        return {m: k for k, b in enumerate(self.blocks) for m in b.members}

    def coupled_block(self, name: str) -> str:
        """Label of the coupled block (strongly connected component) holding ``name``, or ""."""
        return next((b.label for b in self.coupled_blocks if name in b.members), "")

    def rows(self, dsm: Dsm) -> list[tuple[DsmModule, Block, list[DsmCell]]]:
        """The matrix in this order: one ``(module, its block, cells)`` per row."""
        where = self.block_of()
        component = {m: k for k, b in enumerate(self.coupled_blocks) for m in b.members}
        pos = {n: k for k, n in enumerate(self.order)}
        first = {b.members[0] for b in self.blocks if b.members}
        out = []
        for j in self.order:
            bj = self.blocks[where[j]]
            cells = []
            for i in self.order:
                w = dsm.weight(j, i)
                same = where[j] == where[i]
                cells.append(
                    DsmCell(
                        row=j,
                        col=i,
                        weight=w,
                        carries=dsm.carries.get((j, i), ()),
                        shade=(w / dsm.max_weight) if dsm.max_weight > 0 else 0.0,
                        diagonal=i == j,
                        in_block=same,
                        coupled=j in component and component.get(i) == component[j],
                        feedback=w > 0 and pos[j] > pos[i],
                        block_top=j in first,
                        block_left=i in first,
                    )
                )
            out.append((dsm.module(j), bj, cells))
        return out

    def feedback_marks(self, dsm: Dsm) -> int:
        """Number of marks below the diagonal (dependencies on a later module)."""
        pos = {n: k for k, n in enumerate(self.order)}
        return sum(1 for (s, t) in dsm.weights if pos[s] > pos[t])


# --------------------------------------------------------------------------- building
def scope_edges(
    arch: Architecture, configuration: str | None = None
) -> list[tuple[str, str, float, str]]:
    """``(source, target, weight, carries)`` of the scope's edges, in file order.

    For a configuration: the edges whose two ends are active and that it does not
    switch off (``disabled_edges``, :func:`archself.check.rules.active_edges`).
    """
    edges = arch.edges if configuration is None else [
        e for _, e in active_edges(arch, configuration)]
    return [(e.source, e.target, float(e.weight), e.carries) for e in edges]


def _max_weight(arch: Architecture) -> float:
    sums: dict[tuple[str, str], float] = {}
    for e in arch.edges:
        sums[(e.source, e.target)] = sums.get((e.source, e.target), 0.0) + float(e.weight)
    return max(sums.values(), default=0.0)


def build_dsm(arch: Architecture, configuration: str | None = None) -> Dsm:
    """The DSM of the whole architecture (``configuration=None``) or of one configuration."""
    if configuration is None:
        names: Iterable[str] = arch.modules
        scope, title, desc = "architecture", f"{arch.name}: all modules", arch.description
    else:
        conf = arch.configurations[configuration]
        active = set(conf.modules)
        names = [n for n in arch.modules if n in active]
        scope, title, desc = configuration, f"configuration {configuration}", conf.description
    modules = tuple(
        DsmModule(n, arch.modules[n].kind, arch.modules[n].type, arch.modules[n].description or "")
        for n in names
    )
    weights: dict[tuple[str, str], float] = {}
    carries: dict[tuple[str, str], tuple[str, ...]] = {}
    for s, t, w, c in scope_edges(arch, configuration):
        weights[(s, t)] = weights.get((s, t), 0.0) + w
        carries[(s, t)] = (*carries.get((s, t), ()), c)
    weights = {k: round(v, 12) for k, v in weights.items()}
    return Dsm(scope, title, modules, weights, carries, _max_weight(arch), desc or "")


def _kind_key(dsm: Dsm) -> dict[str, tuple[int, int]]:
    return {m.name: (KINDS.index(m.kind), k) for k, m in enumerate(dsm.modules)}


def _ordering(dsm: Dsm, key: str, title: str, explanation: str, blocks: Iterable[Block],
              coupled_blocks: tuple[Block, ...]) -> Ordering:
    """The :class:`Ordering` of ``blocks``, their members one block after the other."""
    blocks = tuple(blocks)
    order = tuple(n for b in blocks for n in b.members)
    return Ordering(key, title, explanation, order, blocks, tuple(dsm.module(n) for n in order),
                    coupled_blocks)


def order_by_kind(dsm: Dsm, seq: Ordering | None = None) -> Ordering:
    """Modules grouped by kind (physical, functional, model), file order inside a kind."""
    blocks = [Block(KIND_TITLES[kind], names) for kind in KINDS
              if (names := tuple(m.name for m in dsm.modules if m.kind == kind))]
    return _ordering(dsm, "kind", "grouped by kind",
                     "Physical, functional and model modules in file order.", blocks,
                     (seq or sequence(dsm)).coupled_blocks)


def _eades(g: nx.DiGraph, nodes: list[str], key: dict[str, tuple[int, int]]) -> list[str]:
    """Order ``nodes`` to keep the weight of backward edges small (greedy, Eades et al.)."""
    sub = g.subgraph(nodes).copy()
    head: list[str] = []
    tail: list[str] = []
    while sub.number_of_nodes():
        progress = True
        while progress:
            progress = False
            sinks = sorted((n for n in sub.nodes if sub.out_degree(n) == 0), key=key.__getitem__)
            if sinks:
                tail[:0] = sinks
                sub.remove_nodes_from(sinks)
                progress = True
            sources = sorted((n for n in sub.nodes if sub.in_degree(n) == 0), key=key.__getitem__)
            if sources:
                head.extend(sources)
                sub.remove_nodes_from(sources)
                progress = True
        if sub.number_of_nodes():
            def gain(n: str) -> float:
                out = sum(d["weight"] for _, _, d in sub.out_edges(n, data=True))
                inn = sum(d["weight"] for _, _, d in sub.in_edges(n, data=True))
                return out - inn

            best = min(sub.nodes, key=lambda n: (-round(gain(n), 12), key[n]))
            head.append(best)
            sub.remove_node(best)
    return head + tail


def sequence(dsm: Dsm) -> Ordering:
    """Strongly connected blocks in topological order (networkx condensation)."""
    key = _kind_key(dsm)
    g = dsm.digraph()
    cond = nx.condensation(g)
    members = {c: sorted(cond.nodes[c]["members"], key=key.__getitem__) for c in cond.nodes}
    topo = list(nx.lexicographical_topological_sort(cond, key=lambda c: key[members[c][0]]))
    blocks = []
    n_coupled = 0
    for c in topo:
        mem = tuple(members[c])
        if len(mem) > 1:
            mem = tuple(_eades(g, list(mem), key))
            n_coupled += 1
            blocks.append(Block(f"coupled block {n_coupled}", mem, coupled=True))
        else:
            blocks.append(Block(mem[0], mem, coupled=False))
    return _ordering(
        dsm, "sequenced", "sequenced",
        "Strongly connected blocks in topological order (providers before users); "
        "marks below the diagonal are feedback and only occur inside coupled blocks.",
        blocks, tuple(b for b in blocks if b.coupled))


def cluster(dsm: Dsm, seed: int = CLUSTER_SEED, seq: Ordering | None = None) -> Ordering:
    """Weighted communities (Louvain, fixed seed), largest first, sequenced inside."""
    seq = seq or sequence(dsm)
    pos = {n: k for k, n in enumerate(seq.order)}
    g = dsm.digraph()
    if g.number_of_edges() == 0:
        comms = [{n} for n in dsm.names]
    else:
        comms = nx.community.louvain_communities(g, weight="weight", seed=seed)
    groups = [sorted(c, key=pos.__getitem__) for c in comms]
    groups.sort(key=lambda grp: (-len(grp), pos[grp[0]]))
    return _ordering(
        dsm, "clustered", "clustered",
        f"Weighted communities (networkx Louvain, seed {seed}), largest first. A cluster "
        "may mix coupled and uncoupled modules: only pairs of modules of one coupled "
        "(strongly connected) block are shaded as coupled.",
        (Block(f"cluster {k + 1}", tuple(grp)) for k, grp in enumerate(groups)),
        seq.coupled_blocks)


def orderings(dsm: Dsm) -> tuple[Ordering, Ordering, Ordering]:
    """The three orderings of a DSM: by kind, sequenced, clustered."""
    seq = sequence(dsm)
    return order_by_kind(dsm, seq), seq, cluster(dsm, seq=seq)


def condense(dsm: Dsm, max_modules: int = FULL_MATRIX_MAX, seed: int = CLUSTER_SEED) -> Dsm:
    """``dsm`` itself, or above ``max_modules`` modules its matrix between communities.

    A matrix of n modules is n² cells: past a few hundred it is neither readable nor
    cheap (10^4 modules are 10^8 cells). Its Louvain communities (weighted, fixed seed;
    the resolution halved until there are at most ``max_modules``) become the rows and
    columns: the cell of two communities is the summed weight of the edges between
    their members, the signals those edges carry are listed (at most five), and the
    weight inside a community is given in its description. Each community is named
    ``cluster k`` and takes its members' most common kind.

    Examples
    --------
    >>> big = Dsm("architecture", "big", tuple(DsmModule(f"m{k}", "functional", "t")
    ...           for k in range(6)), {("m0", "m1"): 1.0, ("m1", "m2"): 1.0,
    ...           ("m3", "m4"): 1.0, ("m4", "m5"): 1.0, ("m2", "m3"): 0.5}, {}, 1.0)
    >>> small = condense(big, max_modules=3)
    >>> len(small.modules), sorted(small.weights.values())
    (2, [0.5])
    """
    n = len(dsm.modules)
    if n <= max_modules:
        return dsm
    g = dsm.digraph()
    resolution = 1.0
    while True:
        comms = nx.community.louvain_communities(g, weight="weight", seed=seed,
                                                 resolution=resolution)
        if len(comms) <= max_modules or resolution < 1e-6:
            break
        resolution /= 2
    order = {m: k for k, m in enumerate(dsm.names)}
    groups = sorted((sorted(c, key=order.__getitem__) for c in comms),
                    key=lambda grp: (-len(grp), order[grp[0]]))
    if len(groups) > max_modules:  # unconnected modules stay apart at any resolution
        rest = sorted((m for grp in groups[max_modules - 1:] for m in grp),
                      key=order.__getitem__)
        groups = [*groups[:max_modules - 1], rest]
    label = {m: f"cluster {k + 1}" for k, grp in enumerate(groups) for m in grp}
    weights: dict[tuple[str, str], float] = {}
    carries: dict[tuple[str, str], tuple[str, ...]] = {}
    inside: dict[str, float] = dict.fromkeys((f"cluster {k + 1}" for k in range(len(groups))), 0.0)
    for (s, t), w in dsm.weights.items():
        a, b = label.get(s), label.get(t)
        if a is None or b is None:
            continue
        if a == b:
            inside[a] += w
            continue
        weights[(a, b)] = weights.get((a, b), 0.0) + w
        seen = carries.get((a, b), ())
        new = tuple(c for c in dsm.carries.get((s, t), ()) if c not in seen)
        carries[(a, b)] = (seen + new)[:5]
    modules = []
    for k, grp in enumerate(groups):
        name = f"cluster {k + 1}"
        kind = Counter(dsm.module(m).kind for m in grp).most_common(1)[0][0]
        head = ", ".join(grp[:5]) + (f", … ({len(grp)} modules)" if len(grp) > 5 else "")
        modules.append(DsmModule(name, kind, f"{len(grp)} modules",
                                 f"{head}; weight inside {inside[name]:.6g}"))
    note = (f"{n} modules condensed into {len(modules)} clusters (Louvain communities): "
            f"a full matrix is shown up to {max_modules} modules.")
    return Dsm(dsm.scope, f"{dsm.title} (clusters)", tuple(modules),
               {k: round(v, 12) for k, v in weights.items()}, carries,
               max(weights.values(), default=0.0),
               f"{dsm.description} {note}".strip())
