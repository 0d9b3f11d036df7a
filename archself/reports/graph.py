"""The architecture graph in the style of the paper's Fig. 1, and configuration diffs.

Report models only (no DOT text here: ``templates/graph.dot.j2`` renders them).

Which diffs are drawn
---------------------
:func:`diff_pairs` gives one diff per ordered pair ``(from, to)`` that a
structural action of the file can perform: ``to`` is the action's target and
``from`` each configuration in its ``applies_in`` (all configurations when it
is not given), except ``to`` itself. For diffdrive that is a1 → a2, a1 → a3,
a2 → a1 and a2 → a3, and the a3 ↔ a4 fallbacks. A file without structural
actions gets the consecutive pairs of its
configurations in file order instead.

Examples
--------
>>> from archself.model.loader import load_architecture
>>> from archself.resources import data_dir
>>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
>>> diff_pairs(arch)
[('a1', 'a2'), ('a1', 'a3'), ('a2', 'a1'), ('a2', 'a3'), ('a3', 'a4'), ('a4', 'a3')]
>>> d = config_diff(arch, "a1", "a2")
>>> d.added_modules, d.removed_modules
(('ekf', 'lqr_fused'), ('odometry', 'lqr'))
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from archself.model.architecture import Architecture
from archself.reports.dsm import KINDS, scope_edges

__all__ = ["ArchGraph", "ConfigDiff", "GraphEdge", "GraphNode", "build_graph", "config_diff",
           "diff_graph", "diff_pairs"]


@dataclass(frozen=True)
class GraphNode:
    name: str
    kind: str
    type: str
    description: str = ""
    status: str = "normal"  # normal | kept | added | removed | hidden


@dataclass(frozen=True)
class GraphEdge:
    source: str
    target: str
    weight: float
    carries: str
    penwidth: float
    status: str = "normal"  # normal | kept | added | removed | hidden


@dataclass(frozen=True)
class ArchGraph:
    """A drawable graph: nodes grouped by kind, weighted edges."""

    title: str
    subtitle: str
    nodes: tuple[GraphNode, ...]
    edges: tuple[GraphEdge, ...]
    diff: bool = False

    def nodes_of(self, kind: str) -> tuple[GraphNode, ...]:
        return tuple(n for n in self.nodes if n.kind == kind)

    @property
    def kinds(self) -> tuple[str, ...]:
        return tuple(k for k in KINDS if self.nodes_of(k))

    def shown(self, kind: str) -> bool:
        """True when a node of ``kind`` is visible (a cluster of hidden nodes is hidden)."""
        return any(n.status != "hidden" for n in self.nodes_of(kind))


@dataclass(frozen=True)
class ConfigDiff:
    """What moving from configuration ``a`` to ``b`` adds and removes."""

    a: str
    b: str
    actions: tuple[str, ...]
    added_modules: tuple[str, ...]
    removed_modules: tuple[str, ...]
    kept_modules: tuple[str, ...]
    added_edges: tuple[tuple[str, str, str], ...]  # (source, target, carries)
    removed_edges: tuple[tuple[str, str, str], ...]


def _nodes(arch: Architecture, status: Callable[[str], str]) -> tuple[GraphNode, ...]:
    """Every module of the file in file order, ``status(name)`` each."""
    return tuple(GraphNode(n, m.kind, m.type, m.description or "", status(n))
                 for n, m in arch.modules.items())


def _edges(arch: Architecture, status: Callable[[tuple[str, str, str]], str]
           ) -> tuple[GraphEdge, ...]:
    """Every edge of the file in file order, ``status((source, target, carries))`` each."""
    wmax = max((float(e.weight) for e in arch.edges), default=0.0)
    return tuple(
        GraphEdge(s, t, w, c, round(0.8 + 4.2 * (w / wmax if wmax > 0 else 0.0), 2),
                  status((s, t, c)))
        for s, t, w, c in scope_edges(arch)
    )


def build_graph(arch: Architecture, configuration: str | None = None) -> ArchGraph:
    """The graph of the whole architecture or of one configuration (its active part).

    Every drawing holds every module and edge of the file, in file order, the ones outside
    the configuration ``hidden`` (drawn invisible): Graphviz lays out the same graph with
    the same label sizes each time, so a module sits at the same place in the drawing of
    every configuration, of every diff and of the whole architecture.
    """
    if configuration is None:
        active = set(arch.modules)
        title, sub = arch.name, "all modules and edges"
    else:
        conf = arch.configurations[configuration]
        active = set(conf.modules)
        title, sub = f"{arch.name}: {configuration}", conf.description or ""
    shown = {(s, t, c) for s, t, _w, c in scope_edges(arch, configuration)}
    edges = _edges(arch, lambda key: "normal" if key in shown else "hidden")
    nodes = _nodes(arch, lambda n: "normal" if n in active else "hidden")
    return ArchGraph(title, sub, nodes, edges)


def diff_pairs(arch: Architecture) -> list[tuple[str, str]]:
    """The (from, to) configuration pairs to diff (see the module docstring)."""
    confs = list(arch.configurations)
    pairs: set[tuple[str, str]] = set()
    for act in arch.actions:
        if act.kind == "parameter_update" or act.to is None:
            continue
        for src in act.applies_in or confs:
            if src != act.to and src in arch.configurations and act.to in arch.configurations:
                pairs.add((src, act.to))
    if not pairs:
        pairs = set(zip(confs, confs[1:], strict=False))
    idx = {c: k for k, c in enumerate(confs)}
    return sorted(pairs, key=lambda p: (idx[p[0]], idx[p[1]]))


def config_diff(arch: Architecture, a: str, b: str) -> ConfigDiff:
    """Modules and edges that configuration ``b`` adds to and removes from ``a``."""
    ma, mb = set(arch.configurations[a].modules), set(arch.configurations[b].modules)
    ea = {(s, t, c) for s, t, _w, c in scope_edges(arch, a)}
    eb = {(s, t, c) for s, t, _w, c in scope_edges(arch, b)}
    order = {n: k for k, n in enumerate(arch.modules)}
    eorder = {(e.source, e.target, e.carries): k for k, e in enumerate(arch.edges)}
    acts = tuple(
        act.id for act in arch.actions
        if act.to == b and act.kind != "parameter_update" and (act.applies_in is None
                                                               or a in act.applies_in)
    )
    return ConfigDiff(
        a, b, acts,
        tuple(sorted(mb - ma, key=order.__getitem__)),
        tuple(sorted(ma - mb, key=order.__getitem__)),
        tuple(sorted(ma & mb, key=order.__getitem__)),
        tuple(sorted(eb - ea, key=eorder.__getitem__)),
        tuple(sorted(ea - eb, key=eorder.__getitem__)),
    )


def diff_graph(arch: Architecture, d: ConfigDiff) -> ArchGraph:
    """The union of both configurations, every node and edge marked kept, added or removed."""
    added, removed, kept_modules = set(d.added_modules), set(d.removed_modules), set(d.kept_modules)
    nodes = _nodes(arch, lambda n: "added" if n in added else "removed" if n in removed
                   else "kept" if n in kept_modules else "hidden")
    ea, eb = set(d.removed_edges), set(d.added_edges)
    kept = {(s, t, c) for s, t, _w, c in scope_edges(arch, d.a)} - ea
    edges = _edges(arch, lambda key: "added" if key in eb else "removed" if key in ea
                   else "kept" if key in kept else "hidden")
    via = ", ".join(d.actions) if d.actions else "consecutive configurations"
    return ArchGraph(f"{arch.name}: {d.a} → {d.b}", f"via {via}", nodes, edges, diff=True)
