"""The Knowledge of the MAPE-K loop: the live architecture graph a = (M, Γ).

:class:`Knowledge` holds a :class:`networkx.DiGraph` of *all* modules of the
architecture file (node attributes ``kind``, ``type``, ``active``, ``params``)
and of all edges (attributes ``weight``, ``carries``, ``active``), the name of
the current configuration, the parameter values changed at run time and
``t_last``, the time of the last architectural change (Eq. 28). It is kept in
step with the running system: :meth:`Knowledge.sync` reads the active modules
and configuration from the system after each executed action. The graph is
built when it is first asked for and its ``active`` flags are brought up to date
when it is read, not at every change: the loop itself works on the arrays and the
edge set (a switch in a 10^5-module graph would otherwise set 3·10^5 flags).

It also owns the index order of the influence vector and the weighted adjacency
matrix W of the *active* edges (Eq. 13), with the factorization of ``I − Wᵀ``
cached per active edge set (:class:`archself.runtime.influence.InfluenceSolver`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse

from archself.contracts import ManagedSystem
from archself.model.architecture import Architecture
from archself.runtime.influence import InfluenceSolver, spectral_radius, weight_matrix

if TYPE_CHECKING:  # networkx (~0.1 s to import) only when the graph is asked for
    import networkx as nx

__all__ = ["Knowledge", "active_edges"]

EdgeKey = tuple[str, str, str]  # (source, target, carries)


def active_edges(
    arch: Architecture, active: Iterable[str], disabled: Iterable[Iterable[str]] = ()
) -> frozenset[EdgeKey]:
    """Edges whose two ends are active and which the configuration does not switch off.

    Parameters
    ----------
    arch : Architecture
        The architecture.
    active : iterable of str
        Active module names.
    disabled : iterable of (source, target)
        The configuration's ``disabled_edges``.

    Returns
    -------
    frozenset of (source, target, carries)
    """
    on = set(active)
    off = {tuple(pair) for pair in disabled}
    return frozenset(
        (e.source, e.target, e.carries)
        for e in arch.edges
        if e.source in on and e.target in on and (e.source, e.target) not in off
    )


class Knowledge:
    """The live architecture graph, the current configuration and ``t_last``.

    Parameters
    ----------
    arch : Architecture
        The architecture file's model.
    configuration : str, optional
        The starting configuration (default: the one marked ``initial``).

    Attributes
    ----------
    graph : networkx.DiGraph
        All modules and edges; ``active`` flags follow the running system.
    names : list of str
        Module names in the index order of ``z``, ``r`` and ``W``.
    configuration : str
        Name of the current configuration.
    active : frozenset of str
        Active modules.
    active_index : numpy.ndarray of int
        Positions of the active modules in :attr:`names`, ascending.
    active_names : list of str
        The active modules in index order.
    active_pos : dict
        name -> position in :attr:`active_names`.
    edges : frozenset of (source, target, carries)
        Active edges.
    params : dict
        module -> {parameter: value}: current parameter values (nominal values
        updated by executed parameter updates).
    t_last : float
        Time of the last architectural change (−inf before the first).
    learned : OutcomeTable or None
        What the loop learned from its actions' outcomes (``runtime.learning``).
    online : list of dict or None
        Every update of W and of the bands (``runtime.online``), accepted or rejected.
    w_scale : float
        Factor applied to every weight so that ρ(W) ≤ ``runtime.max_spectral_radius``
        (1.0 when the file's weights already satisfy it).
    """

    def __init__(self, arch: Architecture, configuration: str | None = None) -> None:
        self.arch = arch
        self.names: list[str] = list(arch.modules)
        self.index = {n: k for k, n in enumerate(self.names)}
        self._graph: nx.DiGraph | None = None
        self._graph_state: tuple[str, frozenset[str]] | None = None  # what its flags show
        self.params: dict[str, dict[str, Any]] = {
            name: {p: spec.value for p, spec in mod.params.items()}
            for name, mod in arch.modules.items()
        }
        # every edge as (source, target, carries) and its ends' positions in names
        self._edge_keys = [(e.source, e.target, e.carries) for e in arch.edges]
        index = self.index
        self._edge_ends = np.array(
            [(index.get(e.source, -1), index.get(e.target, -1)) for e in arch.edges],
            dtype=np.intp,
        ).reshape(-1, 2)
        self._weights: dict[EdgeKey, float] = {}
        for e in arch.edges:
            key = (e.source, e.target, e.carries)
            self._weights[key] = self._weights.get(key, 0.0) + e.weight
        self.t_last = -math.inf
        self.learned: Any = None  # runtime.learning: the OutcomeTable (runtime/learning.py)
        self.online: Any = None  # runtime.online: its updates, accepted or rejected (events)
        self.solver = InfluenceSolver()
        # Normalize W so that ρ(W) stays below the declared bound (paper: "the
        # weights are normalized such that ρ(W) < 1"). W of any active subset is
        # entrywise ≤ W of all edges, so by Perron–Frobenius its ρ is no larger.
        full = weight_matrix(self.names, [(e.source, e.target, e.weight) for e in arch.edges])
        self.rho_full = spectral_radius(full)
        bound = arch.runtime.max_spectral_radius
        self.w_scale = 1.0 if self.rho_full <= bound else bound / self.rho_full
        conf = configuration or arch.initial_configuration()
        self._set_active(conf, arch.configurations[conf].modules)

    # ------------------------------------------------------------------ state
    def _set_active(self, configuration: str, active: Iterable[str]) -> None:
        self.configuration = configuration
        self.active: frozenset[str] = frozenset(active)
        index = self.index
        on = np.zeros(len(self.names) + 1, dtype=bool)  # the last slot: unknown names
        on[[index[n] for n in self.active if n in index]] = True
        self.active_index = np.flatnonzero(on[:-1])
        self.active_names = [self.names[k] for k in self.active_index.tolist()]
        self.active_pos = {n: i for i, n in enumerate(self.active_names)}
        conf = self.arch.configurations.get(configuration)
        off = {tuple(pair) for pair in (conf.disabled_edges if conf is not None else [])}
        ends = self._edge_ends
        live = (on[ends[:, 0]] & on[ends[:, 1]]).tolist()
        keys = self._edge_keys
        self.edges: frozenset[EdgeKey] = frozenset(
            keys[i] for i, ok in enumerate(live) if ok and keys[i][:2] not in off
        )

    @property
    def graph(self) -> nx.DiGraph:
        """All modules and edges; ``active`` flags follow the running system."""
        g = self._graph
        if g is None:
            import networkx as nx

            g = self._graph = nx.DiGraph()
            for name, mod in self.arch.modules.items():
                # the params dict is Knowledge's own: it stays in step
                g.add_node(name, kind=mod.kind, type=mod.type, active=False,
                           params=self.params[name])
            for e in self.arch.edges:
                if g.has_edge(e.source, e.target):
                    data = g.edges[e.source, e.target]
                    data["weight"] += e.weight
                    data["carries"].append(e.carries)
                else:
                    g.add_edge(e.source, e.target, weight=e.weight, carries=[e.carries],
                               active=False)
        state = (self.configuration, self.active)
        if self._graph_state != state:
            pairs = {(s, t) for s, t, _ in self.edges}
            for n, data in g.nodes(data=True):
                data["active"] = n in self.active
            for s, t, data in g.edges(data=True):
                data["active"] = (s, t) in pairs
            self._graph_state = state
        return g

    def sync(self, system: ManagedSystem) -> None:
        """Read configuration and active modules from the running system."""
        conf = str(system.configuration)
        active = system.active
        if not isinstance(active, (set, frozenset)):
            active = frozenset(active)
        if conf != self.configuration or active != self.active:  # no copy when unchanged
            self._set_active(conf, active)

    def record_structural(self, t: float) -> None:
        """Note an executed architectural change; sets ``t_last`` (Eq. 28)."""
        self.t_last = float(t)

    def record_parameters(self, module: str, values: dict) -> None:
        """Note an executed parameter update."""
        self.params.setdefault(module, {}).update(values)

    # ------------------------------------------------------------------ analysis
    def weight_matrix(self) -> scipy.sparse.csr_matrix:
        """W of the active edges (Eq. 13), normalized by :attr:`w_scale`."""
        return weight_matrix(
            self.names,
            [(s, t, self.arch_weight(s, t, c)) for s, t, c in sorted(self.edges)],
            scale=self.w_scale,
        )

    def set_weight(self, source: str, target: str, weight: float) -> None:
        """Set the weight of the pair ``source → target`` (online W, runtime/online.py).

        Parallel edges of the pair keep their shares; the factorization and the
        weights' users re-read W at their next use.
        """
        keys = [k for k in self._weights if k[0] == source and k[1] == target]
        total = sum(self._weights[k] for k in keys)
        for k in keys:
            self._weights[k] = weight * (self._weights[k] / total if total else 1 / len(keys))
        self.solver.key = None
        if self._graph is not None and self._graph.has_edge(source, target):
            self._graph.edges[source, target]["weight"] = weight

    def arch_weight(self, source: str, target: str, carries: str) -> float:
        """Declared weight of an edge (parallel edges with the same ``carries`` add up)."""
        return self._weights.get((source, target, carries), 0.0)

    def influence(self, r: np.ndarray) -> np.ndarray:
        """``z = (I − Wᵀ)⁻¹ r`` (Eq. 14) for the active edges, factorization cached."""
        key = self.solver.key
        if key is not self.edges and key != self.edges:
            self.solver.set_matrix(self.weight_matrix(), key=self.edges)
        return self.solver.solve(r)
