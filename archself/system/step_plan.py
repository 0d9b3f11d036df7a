"""The execution plan of one configuration: what a step runs, in which order, from where.

:func:`build_plan` computes, once per configuration, the active modules in file
order, the modules without direct feedthrough, the step order of the others
(:func:`archself.system.dataflow.topological_order`; an algebraic loop is a
:class:`~archself.errors.CompileError`), the routing of every input (source,
edge, noise, delay, and the source's output a renamed port reads) and the
required inputs. :class:`StepPlan` holds it, immutable, for
:class:`archself.system.executor.LiveSystem`'s step loop, its restriction to a partial copy
and its closed loop (:meth:`StepPlan.wires`); :meth:`StepPlan.reach` is the
rollout scope's search along the routes.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Collection

from archself.errors import CompileError
from archself.linear.assembly import Wire
from archself.model.architecture import Architecture
from archself.modules.base import RuntimeModule
from archself.system.dataflow import algebraic_loop, topological_order

__all__ = ["StepPlan", "build_plan"]


class StepPlan:
    """Precomputed execution plan of one configuration (immutable)."""

    def __init__(
        self,
        name: str,
        active: list[str],
        nonft: list[str],
        order: list[str],
        routes: dict[str, list[tuple[str, str, int, float, int]]],
        required: dict[str, tuple[str, ...]],
        edges: list[int],
        multi: dict[str, frozenset[str]],
        reads: dict[int, str],
    ) -> None:
        self.name = name
        self.active = active
        self.active_set = frozenset(active)
        self.nonft = nonft
        self.order = order
        self.routes = routes
        self.required = required
        self.edges = edges
        # edge index -> the source's output it reads, where the target's input port is
        # named otherwise (archself.model.architecture: routes are keyed by the target's port)
        self.reads = reads
        # (module, whether it steps) of the publishing phases of a step
        self.publishing = [(n, False) for n in nonft] + [(n, True) for n in order]
        # (signal, source) pairs of the modules whose inputs pass unchanged (no edge
        # latency, noise or renamed port): the step gathers them without the general path
        self.direct: dict[str, tuple[tuple[str, str], ...] | None] = {
            n: None
            if n in multi or any(unc or delay or i in reads for _, _, i, unc, delay in r)
            else tuple((carries, src) for carries, src, *_ in r)
            for n, r in routes.items()
        }
        # module -> its inputs that collect a list, one value per active edge
        self.multi = multi
        self.nonft_set = frozenset(nonft)
        # some module type overrides linear_model or linearization (set by the system)
        self.linearizable = True
        self._wires: list[Wire] | None = None

    def wires(self) -> list[Wire]:
        """The active edges as :class:`~archself.linear.wiring.Wire` s (made once)."""
        if self._wires is None:
            self._wires = [
                Wire(src, n, carries, delay)
                for n in self.active
                for carries, src, _i, _unc, delay in self.routes[n]
            ]
        return self._wires

    def restricted(self, keep: Collection[str]) -> StepPlan:
        """The plan of the modules ``keep`` alone (file order and step order kept)."""
        active = [n for n in self.active if n in keep]
        plan = StepPlan(
            self.name,
            active,
            [n for n in self.nonft if n in keep],
            [n for n in self.order if n in keep],
            {n: self.routes[n] for n in active},
            {n: self.required[n] for n in active},
            sorted(r[2] for n in active for r in self.routes[n]),
            {n: v for n, v in self.multi.items() if n in keep},
            self.reads,
        )
        plan.linearizable = self.linearizable
        return plan

    def reach(self, starts: Collection[str], steps: int) -> set[str]:
        """The active modules whose outputs reach ``starts`` within ``steps`` steps.

        Upstream along the routes: an edge into a module without direct
        feedthrough takes a step, a latency its steps, an edge into a feedthrough
        module none (Dijkstra over these step counts).
        """
        dist = {m: 0 for m in starts if m in self.active_set}
        heap = [(0, m) for m in dist]
        nonft = self.nonft_set
        routes = self.routes
        while heap:
            d, m = heapq.heappop(heap)
            if d > dist[m]:
                continue
            hop = d + (1 if m in nonft else 0)
            for _carries, src, _i, _unc, delay in routes[m]:
                nd = hop + delay
                if nd <= steps and nd < dist.get(src, steps + 1):
                    dist[src] = nd
                    heapq.heappush(heap, (nd, src))
        return set(dist)


def build_plan(
    arch: Architecture,
    configuration: str,
    module: Callable[[str], RuntimeModule],
    dt: float,
) -> StepPlan:
    """The plan of ``configuration``; ``module(name)`` gives the (pooled) module instance.

    Raises
    ------
    CompileError
        If the configuration is unknown, names unknown modules or has an algebraic loop.
    """
    conf = arch.configurations.get(configuration)
    if conf is None:
        known = ", ".join(arch.configurations)
        raise CompileError(f"unknown configuration {configuration!r}; known: {known}")
    missing = [m for m in conf.modules if m not in arch.modules]
    if missing:
        raise CompileError(
            f"configuration {configuration!r} names unknown modules: {', '.join(missing)}"
        )
    index = {n: i for i, n in enumerate(arch.modules)}
    active = sorted(set(conf.modules), key=index.__getitem__)
    act = set(active)
    disabled = {tuple(e) for e in conf.disabled_edges}
    classes = {n: type(module(n)) for n in active}
    nonft = [n for n in active if not classes[n].direct_feedthrough]
    nonft_set = set(nonft)
    routes: dict[str, list[tuple[str, str, int, float, int]]] = {n: [] for n in active}
    flow: list[tuple[str, str]] = []  # the data flow of a step: edges into feedthrough
    edges: list[int] = []
    reads: dict[int, str] = {}
    ports = arch.edge_ports  # named ports: archself.model.architecture
    for i, e in enumerate(arch.edges):
        if e.source not in act or e.target not in act or (e.source, e.target) in disabled:
            continue
        edges.append(i)
        if ports.to_port[i] not in (None, e.carries):  # read as the source's output
            reads[i] = e.carries
        delay = int(round(e.latency_s / dt)) if e.latency_s > 0 else 0
        routes[e.target].append((ports.into(i), e.source, i, float(e.uncertainty), delay))
        if e.target not in nonft_set:
            flow.append((e.source, e.target))
    loop = algebraic_loop(flow)
    if loop is not None:
        path = " -> ".join([*loop, loop[0]])
        raise CompileError(
            f"configuration {configuration!r} has an algebraic loop: {path} "
            "(a loop needs a module with direct_feedthrough = False)"
        )
    order = [n for n in topological_order(active, flow, index) if n not in nonft_set]
    required = {n: tuple(classes[n].inputs) for n in active}
    multi = {n: frozenset(classes[n].multi_inputs) for n in active if classes[n].multi_inputs}
    plan = StepPlan(configuration, active, nonft, order, routes, required, edges, multi, reads)
    plan.linearizable = any(
        cls.linear_model is not RuntimeModule.linear_model
        or cls.linearization is not RuntimeModule.linearization
        for cls in set(classes.values())
    )
    return plan
