"""The live system: a generic synchronous data-flow executor of runtime modules.

:class:`LiveSystem` runs the active modules of one configuration of an
architecture with the semantics of :mod:`archself.modules.base`:

1. modules with ``direct_feedthrough = False`` publish ``output(t)``;
2. the other modules ``step`` in topological order of the active edges, with
   the edges *into* non-feedthrough modules cut (an remaining cycle is an
   algebraic loop: :class:`~archself.errors.CompileError`);
3. the non-feedthrough modules ``step`` to advance their state to ``t + dt``.

It knows module *roles* and declared signals, never a module's name, so any
architecture file runs. Everything that can be precomputed (the order, the
routing of each input, edge delays and noise) is computed once per
configuration; the step loop touches plain dicts and lists only.

Design decisions
----------------
* **Hand-over.** On :meth:`LiveSystem.apply_configuration` every newly active
  module receives ``import_state(old.export_state())`` from the deactivated
  module with the same ``role`` (first in file order), e.g. odometry pose and
  covariance → EKF.
* **Persistence.** Module instances live in a pool for the whole run: a
  deactivated module keeps its state and resumes from it when reactivated (after
  the hand-over above, which refreshes what a successor can give it). Module
  types that should not carry stale state reset it in ``import_state``.
* **Robustness.** A module that raises, or publishes a non-finite number, is
  marked unavailable for that step and its last good outputs are held; a module
  whose required input is ``None`` is marked unavailable too (it still runs and
  must tolerate it). A module whose last value was NaN stays unavailable until
  it publishes a good one (a GPS between fixes gives ``None``, not news). Two
  checks need a declaration by the module type: a module with ``max_silence_s``
  (a GPS receiver: a few fix periods) that has published no value for longer
  than that is *silent* (a dropout), and a signal with a declared noise level
  (``noise_levels``, > 0) that repeats the same value ``STALE_REPEATS`` times in
  a row is *stale* (a frozen sensor: real noise never repeats bit for bit).
  :meth:`LiveSystem.health` gives the reason of each unavailable module and
  :meth:`LiveSystem.dependencies` the modules each module of a configuration
  cannot run without.
* **Edges.** ``uncertainty`` adds zero-mean Gaussian noise (own random stream per
  edge) to numeric values; ``latency_s`` delays the value by
  ``round(latency_s / dt)`` steps (``None`` until the line fills).
* **Randomness.** Each module gets ``numpy.random.default_rng([seed,
  stable_hash(name)])``; edges and faults get their own streams the same way.
"""

from __future__ import annotations

import copy
import hashlib
import heapq
import math
from collections import deque
from collections.abc import Callable, Collection, Sequence
from typing import Any

import numpy as np

from archself.errors import CompileError, SimulationError
from archself.linear import ClosedLoop, Wire, gc_paused, interconnect, loop_modules, wiring
from archself.model import Architecture
from archself.modules.base import LinearModel, Port, RuntimeModule
from archself.objective import objective_norm

__all__ = ["LiveSystem", "STALE_REPEATS", "algebraic_loop", "stable_hash", "module_rng"]

_isfinite = math.isfinite
_NOT_NUMERIC: frozenset[type] = frozenset({str, bool, type(None)})  # never numbers

#: A noisy signal repeating the same value this many times in a row is stale.
STALE_REPEATS = 3


def stable_hash(text: str) -> int:
    """A 64-bit hash of ``text`` that is the same in every process (unlike ``hash``).

    Examples
    --------
    >>> stable_hash("imu") == stable_hash("imu")
    True
    """
    return int.from_bytes(hashlib.blake2b(text.encode("utf-8"), digest_size=8).digest(), "little")


def module_rng(seed: int, name: str) -> np.random.Generator:
    """The deterministic random stream of module (or edge, fault) ``name`` for ``seed``."""
    return np.random.default_rng([int(seed), stable_hash(name)])


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
    index: dict[str, int] = {}
    for s, _ in flow:
        index.setdefault(s, len(index))
    for _, t in flow:
        index.setdefault(t, len(index))
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
    names = list(index)
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


def _topological_order(
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


class _Shared:
    """Holder of immutable data shared by snapshots (``deepcopy`` returns it as is)."""

    __slots__ = ("value",)

    def __init__(self, value: Any) -> None:
        self.value = value

    def __deepcopy__(self, memo: dict) -> _Shared:
        return self


class _Plan:
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
    ) -> None:
        self.name = name
        self.active = active
        self.active_set = frozenset(active)
        self.nonft = nonft
        self.order = order
        self.routes = routes
        self.required = required
        self.edges = edges
        # (module, whether it steps) of the publishing phases of a step
        self.publishing = [(n, False) for n in nonft] + [(n, True) for n in order]
        # (signal, source) pairs of the modules whose inputs pass unchanged (no edge
        # latency or noise): the step gathers them without the general path
        self.direct: dict[str, tuple[tuple[str, str], ...] | None] = {
            n: None
            if n in multi or any(unc or delay for *_, unc, delay in r)
            else tuple((carries, src) for carries, src, *_ in r)
            for n, r in routes.items()
        }
        # module -> its inputs that collect a list, one value per active edge
        self.multi = multi
        self.nonft_set = frozenset(nonft)
        # some module type overrides linear_model or linearization (set by the system)
        self.linearizable = True
        self._wires: list[Wire] | None = None
        # edge index -> the source's output it reads, where the target's input port is
        # named otherwise (archself.ports: routes are keyed by the target's port)
        self.reads: dict[int, str] = {}

    def wires(self) -> list[Wire]:
        """The active edges as :class:`~archself.linear.Wire` s (made once)."""
        if self._wires is None:
            self._wires = [
                Wire(src, n, carries, delay)
                for n in self.active
                for carries, src, _i, _unc, delay in self.routes[n]
            ]
        return self._wires

    def restricted(self, keep: Collection[str]) -> _Plan:
        """The plan of the modules ``keep`` alone (file order and step order kept)."""
        active = [n for n in self.active if n in keep]
        plan = _Plan(
            self.name,
            active,
            [n for n in self.nonft if n in keep],
            [n for n in self.order if n in keep],
            {n: self.routes[n] for n in active},
            {n: self.required[n] for n in active},
            sorted(r[2] for n in active for r in self.routes[n]),
            {n: v for n, v in self.multi.items() if n in keep},
        )
        plan.linearizable = self.linearizable
        plan.reads = self.reads
        plan.direct.update({n: None for n in active if self.direct[n] is None})
        return plan


def _is_bad(value: Any) -> bool:
    """True for a non-finite float or an array with a non-finite entry."""
    tp = type(value)
    if tp is float:
        return not math.isfinite(value)
    if tp is np.ndarray:
        if value.dtype.kind != "f":
            return False
        flat = value.tolist() if value.ndim == 1 else value.ravel().tolist()
        return not math.isfinite(sum(flat))
    if isinstance(value, (float, np.floating)):
        return not math.isfinite(float(value))
    return False


class LiveSystem:
    """A running configuration of an architecture (the compiler → runtime contract).

    Build it with :func:`archself.compiler.compile_system`; see
    ``docs/develop.md`` for the contract table.

    Parameters
    ----------
    arch : Architecture
        The architecture.
    configuration : str
        The active configuration.
    factory : callable
        ``factory(name) -> RuntimeModule``: instantiates a module with its
        nominal parameters and own random stream.
    seed : int
        Seed of the edge noise streams.
    faults : dict, optional
        module name -> list of ``(signal, injector)`` from
        :mod:`archself.sim.faults`; applied while the module is active.
    """

    def __init__(
        self,
        arch: Architecture,
        configuration: str,
        factory: Callable[[str], RuntimeModule],
        *,
        seed: int = 0,
        faults: dict[str, list[tuple[str, Any]]] | None = None,
    ) -> None:
        self.arch = arch
        self.seed = int(seed)
        self.dt = float(arch.runtime.step_s)
        self.t = 0.0
        self.k = 0
        self._factory = factory
        self._pool: dict[str, RuntimeModule] = {}
        self._faults = faults or {}
        self._edge_rng: dict[int, np.random.Generator] = {}
        self._delay: dict[int, deque] = {}
        self._plans: dict[str, _Plan] = {}
        self.outputs: dict[str, dict[str, Any]] = {}
        self._ok: dict[str, bool] = {}
        self._why: dict[str, str] = {}
        self._heard: dict[str, float] = {}  # module -> time of its last published value
        self._last: dict[tuple[str, str], Any] = {}  # (module, signal) -> last value
        self._repeats: dict[tuple[str, str], int] = {}
        self._broken: set[str] = set()  # modules whose last value was not finite
        # output types found not to be numbers (model objects): this system skips them
        self._not_numeric: set[type] = set(_NOT_NUMERIC)
        self.history: list[dict[str, Any]] = []
        obj = arch.runtime.objective
        self._obj_actual = obj.actual
        self._obj_ref = obj.reference
        self._obj_comp = list(obj.components)
        self._scope: frozenset[str] | None = None  # a partial copy's modules (snapshot(only=))
        self._scoped: dict[str, _Plan] = {}  # its plans, restricted to them
        self._plan = self._make_plan(configuration)
        for name in self._plan.active:
            self._module(name)
        self.configuration = configuration

    # ------------------------------------------------------------------ plans
    def _module(self, name: str) -> RuntimeModule:
        mod = self._pool.get(name)
        if mod is None:
            if name not in self.arch.modules:
                raise SimulationError(f"unknown module {name!r}")
            mod = self._factory(name)
            self._pool[name] = mod
        return mod

    def _make_plan(self, configuration: str) -> _Plan:
        plan = self._full_plan(configuration)
        if self._scope is None:
            return plan
        found = self._scoped.get(configuration)
        if found is None:
            found = self._scoped[configuration] = plan.restricted(self._scope)
        return found

    def _full_plan(self, configuration: str) -> _Plan:
        cached = self._plans.get(configuration)
        if cached is not None:
            return cached
        arch = self.arch
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
        classes = {n: type(self._module(n)) for n in active}
        nonft = [n for n in active if not classes[n].direct_feedthrough]
        nonft_set = set(nonft)
        routes: dict[str, list[tuple[str, str, int, float, int]]] = {n: [] for n in active}
        flow: list[tuple[str, str]] = []  # the data flow of a step: edges into feedthrough
        edges: list[int] = []
        for i, e in enumerate(arch.edges):
            if e.source not in act or e.target not in act or (e.source, e.target) in disabled:
                continue
            edges.append(i)
            delay = int(round(e.latency_s / self.dt)) if e.latency_s > 0 else 0
            routes[e.target].append((e.into, e.source, i, float(e.uncertainty), delay))
            if e.target not in nonft_set:
                flow.append((e.source, e.target))
        loop = algebraic_loop(flow)
        if loop is not None:
            path = " -> ".join([*loop, loop[0]])
            raise CompileError(
                f"configuration {configuration!r} has an algebraic loop: {path} "
                "(a loop needs a module with direct_feedthrough = False)"
            )
        order = _topological_order(active, flow, index)
        order = [n for n in order if n not in nonft_set]
        required = {n: tuple(classes[n].inputs) for n in active}
        multi = {n: frozenset(classes[n].multi_inputs) for n in active if classes[n].multi_inputs}
        plan = _Plan(configuration, active, nonft, order, routes, required, edges, multi)
        for i in edges:  # named ports: read as the source's output, delivered as the port
            e = arch.edges[i]
            if e.into != e.carries:
                plan.reads[i] = e.carries
                plan.direct[e.target] = None
        plan.linearizable = any(
            cls.linear_model is not RuntimeModule.linear_model
            or cls.linearization is not RuntimeModule.linearization
            for cls in set(classes.values())
        )
        self._plans[configuration] = plan
        return plan

    # ------------------------------------------------------------------ contract
    @property
    def active(self) -> set[str]:
        """Names of the active modules."""
        return set(self._plan.active)

    @property
    def modules(self) -> dict[str, RuntimeModule]:
        """Active modules by name (file order)."""
        return {n: self._pool[n] for n in self._plan.active}

    @property
    def execution_order(self) -> list[str]:
        """Order of one step: non-feedthrough outputs, then the feedthrough modules."""
        return list(self._plan.nonft) + list(self._plan.order)

    @property
    def active_edges(self) -> list[int]:
        """Indices into ``arch.edges`` of the edges active in this configuration."""
        return list(self._plan.edges)

    def _gather(self, name: str) -> dict[str, Any]:
        outs = self.outputs
        inputs: dict[str, Any] = {}
        direct = self._plan.direct[name]
        if direct is not None:
            for carries, src in direct:
                src_out = outs.get(src)
                val = src_out.get(carries) if src_out is not None else None
                if val is not None or carries not in inputs:
                    inputs[carries] = val
            return inputs
        multi = self._plan.multi.get(name, ())
        reads = self._plan.reads
        for carries, src, idx, unc, delay in self._plan.routes[name]:
            src_out = outs.get(src)
            sig = reads.get(idx, carries) if reads else carries
            val = src_out.get(sig) if src_out is not None else None
            if delay:
                line = self._delay.get(idx)
                if line is None:
                    line = self._delay[idx] = deque([None] * delay)
                line.append(val)
                val = line.popleft()
            if unc and val is not None and isinstance(val, (float, int, np.ndarray)):
                rng = self._edge_rng.get(idx)
                if rng is None:
                    e = self.arch.edges[idx]
                    rng = self._edge_rng[idx] = module_rng(
                        self.seed, f"edge:{e.source}->{e.target}:{e.carries}"
                    )
                if isinstance(val, np.ndarray):
                    val = val + unc * rng.standard_normal(val.shape)
                else:
                    val = val + unc * float(rng.standard_normal())
            if carries in multi:
                inputs.setdefault(carries, []).append(val)
            elif val is not None or carries not in inputs:
                inputs[carries] = val
        return inputs

    def _publish(self, name: str, out: dict[str, Any] | None, t: float) -> str | None:
        """Apply the faults and publish ``out``; the reason the module is unavailable, or None.

        The reason covers the module's own output only: a non-finite value, silence
        longer than its ``max_silence_s``, or a noisy signal (``noise_levels``) that
        repeated itself ``STALE_REPEATS`` times.
        """
        if out is None:
            out = {}
        faults = self._faults.get(name)
        if faults:
            out = dict(out)
            for sig, inj in faults:
                if sig in out:
                    out[sig] = inj.apply(t, out[sig])
        heard = False
        for v in out.values():
            if v is None:
                continue
            tp = type(v)
            if tp is float:  # inlined _is_bad for the common types (a hot loop)
                bad = not _isfinite(v)
            elif tp is np.ndarray:
                bad = v.dtype.kind == "f" and not _isfinite(
                    sum(v.tolist() if v.ndim == 1 else v.ravel().tolist())
                )
            elif tp in self._not_numeric:  # model objects, strings: nothing to check
                bad = False
            else:
                bad = _is_bad(v)
                if not bad and not isinstance(v, (float, int, np.number)):
                    self._not_numeric.add(tp)
            if bad:
                self._broken.add(name)
                return "non-finite output"
            heard = True
        self.outputs[name] = out
        mod = self._pool[name]
        levels = getattr(mod, "noise_levels", None)
        if heard:
            self._heard[name] = t
            if self._broken:
                self._broken.discard(name)
            if levels:
                stale = self._count_repeats(name, levels, out)
                if stale is not None:
                    return stale
        elif name in self._broken:  # its last value was NaN: broken until a good one comes
            return "non-finite output"
        limit = getattr(mod, "max_silence_s", None)
        if limit is not None:
            quiet = t - self._heard.setdefault(name, t)
            if quiet > float(limit) + 1e-9:
                return f"silent for {quiet:.3g} s"
        if not heard and levels and self._repeats:
            for sig in levels:
                n = self._repeats.get((name, sig), 0)
                if n >= STALE_REPEATS:
                    return f"stale {sig} ({n + 1} identical values)"
        return None

    def _count_repeats(
        self, name: str, levels: dict[str, float], out: dict[str, Any]
    ) -> str | None:
        """Count bit-identical repeats of the noisy signals; the stale reason, or None."""
        last = self._last
        repeats = self._repeats
        reason = None
        for sig, level in levels.items():
            v = out.get(sig)
            if v is None or not level or level <= 0:
                n = repeats.get((name, sig), 0)
            else:
                key = (name, sig)
                cur = v.tobytes() if type(v) is np.ndarray else v
                n = repeats[key] = repeats.get(key, 0) + 1 if last.get(key) == cur else 0
                last[key] = cur
            if n >= STALE_REPEATS and reason is None:
                reason = f"stale {sig} ({n + 1} identical values)"
        return reason

    def step(self) -> None:
        """Advance the system by one step ``dt``."""
        t = self.t
        dt = self.dt
        pool = self._pool
        plan = self._plan
        req = plan.required
        ok = self._ok
        why = self._why
        publish = self._publish
        gather = self._gather
        # phases 1 and 2: the state-only outputs, then the feedthrough modules in order
        for name, stepped in plan.publishing:
            inputs = gather(name) if stepped else None
            try:
                mod = pool[name]
                out = mod.output(t) if inputs is None else mod.step(t, dt, inputs)
                reason = publish(name, out, t)
            except Exception as exc:  # noqa: BLE001 - a failing module must not stop the run
                reason = f"raised {type(exc).__name__}"
            if reason is None and inputs is not None:
                for s in req[name]:
                    if inputs.get(s) is None:
                        reason = f"lost input {s}"
                        break
            if reason is None:
                ok[name] = True
                if why:
                    why.pop(name, None)
            else:
                ok[name] = False
                why[name] = reason
        # phase 3: the state-only modules advance to t + dt
        for name in plan.nonft:
            inputs = gather(name)
            try:
                pool[name].step(t, dt, inputs)
            except Exception as exc:  # noqa: BLE001
                ok[name] = False
                why[name] = f"raised {type(exc).__name__}"
                continue
            if ok[name]:
                for s in req[name]:
                    if inputs.get(s) is None:
                        ok[name] = False
                        why[name] = f"lost input {s}"
                        break
        self.k += 1
        self.t = self.k * dt

    def run(self, duration_s: float) -> None:
        """Step for ``duration_s`` seconds."""
        for _ in range(int(round(duration_s / self.dt))):
            self.step()

    def local_signals(self) -> dict[str, dict[str, float]]:
        """module -> signal -> value of the active modules' residual signals (Eq. 12)."""
        return {n: self._pool[n].local_signals() for n in self._plan.active}

    def available(self) -> dict[str, bool]:
        """module -> False when it raised, gave NaN, lost a required input, fell silent or
        stale in the last step."""
        return {n: self._ok.get(n, True) for n in self._plan.active}

    def health(self) -> dict[str, str | None]:
        """module -> why it is unavailable (None when available), for the active modules.

        Reasons: ``raised <Exception>``, ``non-finite output``, ``lost input <signal>``
        (an upstream failure, not the module's own), ``silent for <t> s``,
        ``stale <signal> (<n> identical values)``.
        """
        why = self._why
        return {n: (None if self._ok.get(n, True) else why.get(n)) for n in self._plan.active}

    def dependencies(self, configuration: str | None = None) -> dict[str, frozenset[str]]:
        """module -> the modules it cannot run without in ``configuration`` (default: active).

        A module depends on the providers of its required inputs (the type's
        ``inputs``) along the configuration's edges, and on the modules its
        ``constraints.requires`` names. Optional inputs create no dependency.
        """
        plan = self._make_plan(configuration or self.configuration)
        out: dict[str, frozenset[str]] = {}
        for n in plan.active:
            need = set(plan.required[n])
            deps = {src for carries, src, *_ in plan.routes[n] if carries in need}
            deps.update(
                m for m in self.arch.modules[n].constraints.requires if m in plan.active_set
            )
            deps.discard(n)
            out[n] = frozenset(deps)
        return out

    def signal(self, ref: str | tuple[str, str]) -> Any:
        """The current value of ``'module.signal'`` (None when not published)."""
        mod, sig = ref.rsplit(".", 1) if isinstance(ref, str) else ref
        out = self.outputs.get(mod)
        return None if out is None else out.get(sig)

    def state_error(self) -> np.ndarray:
        """``x − x_ref`` of the ``runtime.objective`` components (NaN when unknown, Eq. 22)."""
        a = self.signal(self._obj_actual)
        r = self.signal(self._obj_ref)
        n = len(self._obj_comp)
        if a is None or r is None:
            return np.full(n, np.nan)
        a = np.atleast_1d(np.asarray(a, dtype=float))  # a scalar signal is a 1-vector
        r = np.atleast_1d(np.asarray(r, dtype=float))
        c = self._obj_comp
        return a[c] - r[c]

    def objective_error(self) -> float:
        """J_obs: norm of :meth:`state_error` (NaN before the first step).

        The same number as the run's J series at this step (:func:`objective_norm`).
        """
        return objective_norm(
            self.signal(self._obj_actual), self.signal(self._obj_ref), self._obj_comp
        )

    # ------------------------------------------------------------------ changes
    def apply_configuration(self, name: str) -> None:
        """Hot swap to configuration ``name`` with state hand-over by role.

        Raises
        ------
        CompileError
            If the configuration is unknown or has an algebraic loop.
        """
        if name == self.configuration:
            return
        old = self._plan
        new = self._make_plan(name)
        gone = [n for n in old.active if n not in new.active_set]
        for n in new.active:
            if n in old.active_set:
                continue
            mod = self._module(n)
            for g in gone:
                prev = self._pool[g]
                if prev.role == mod.role:
                    mod.import_state(prev.export_state())
                    break
        for g in gone:
            self.outputs.pop(g, None)
            self._ok.pop(g, None)
            self._why.pop(g, None)
            self._heard.pop(g, None)
            self._broken.discard(g)
        self._plan = new
        self.history.append({"t_s": self.t, "from": old.name, "to": name})
        self.configuration = name

    def set_params(self, module: str, values: dict[str, Any]) -> None:
        """Apply a parameter update to ``module`` (instantiated if not yet used)."""
        self._module(module).set_params(dict(values))

    def snapshot(self, only: Collection[str] | None = None) -> LiveSystem:
        """An independent deep copy (same RNG states, so a rollout is deterministic).

        With ``only``, a partial copy of those modules alone (with their outputs,
        health, faults and the edges into them): it steps them as the whole system
        would as long as what it is asked about depends on them only, e.g. the
        objective over a rollout when ``only`` is :meth:`rollout_scope`. Its
        ``modules``, ``available()``, ``dependencies()`` and the like answer for
        those modules; a module outside ``only`` that it is given an update for is
        created from the file and never stepped.
        """
        memo = {id(self.arch): self.arch, id(self._factory): self._factory}
        for p in self._plans.values():
            memo[id(p)] = p
        for p in self._scoped.values():
            memo[id(p)] = p
        if only is None:
            return copy.deepcopy(self, memo)
        keep = frozenset(only) if self._scope is None else self._scope.intersection(only)
        edges = self.arch.edges
        per_module = {
            "_pool": {n: m for n, m in self._pool.items() if n in keep},
            "outputs": {n: v for n, v in self.outputs.items() if n in keep},
            "_ok": {n: v for n, v in self._ok.items() if n in keep},
            "_why": {n: v for n, v in self._why.items() if n in keep},
            "_heard": {n: v for n, v in self._heard.items() if n in keep},
            "_last": {k: v for k, v in self._last.items() if k[0] in keep},
            "_repeats": {k: v for k, v in self._repeats.items() if k[0] in keep},
            "_broken": {n for n in self._broken if n in keep},
            "_faults": {n: v for n, v in self._faults.items() if n in keep},
            "_delay": {i: v for i, v in self._delay.items() if edges[i].target in keep},
            "_edge_rng": {i: v for i, v in self._edge_rng.items() if edges[i].target in keep},
            "_scoped": {},
            "_plan": None,
        }
        rest = {k: v for k, v in self.__dict__.items() if k not in per_module}
        part = object.__new__(type(self))
        rest, per_module = copy.deepcopy((rest, per_module), memo)
        part.__dict__.update(rest)
        part.__dict__.update(per_module)
        part._scope = keep
        part._plan = part._make_plan(self.configuration)
        return part

    def rollout_scope(self, configuration: str | None = None, steps: int = 0) -> frozenset[str]:
        """The modules a rollout of ``steps`` steps in ``configuration`` needs for the objective.

        Those whose outputs reach a ``runtime.objective`` signal within ``steps``
        steps along the configuration's edges (an edge into a module without
        direct feed-through takes a step, a latency its steps; an edge into a
        feed-through module none), and for each of them that a switch to
        ``configuration`` brings in, the module it would take its state from
        (hand-over by role). :meth:`snapshot` ``(only=…)`` of these gives the same
        objective error, step by step, as a copy of the whole system.
        """
        plan = self._full_plan(configuration or self.configuration)
        refs = (self._obj_actual, self._obj_ref)
        starts = {(r.rsplit(".", 1)[0] if isinstance(r, str) else r[0]) for r in refs}
        dist = {m: 0 for m in starts if m in plan.active_set}
        heap = [(0, m) for m in dist]
        nonft = plan.nonft_set
        routes = plan.routes
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
        keep = set(dist)
        current = self._plan
        if plan.name != current.name:
            gone = [g for g in current.active if g not in plan.active_set]
            for n in [n for n in keep if n not in current.active_set]:
                role = self._module(n).role
                giver = next((g for g in gone if self._pool[g].role == role), None)
                if giver is not None:
                    keep.add(giver)
        return frozenset(keep)

    def _linear_module(self, name: str, plan: _Plan) -> RuntimeModule:
        """The module as it would run in ``plan``: live if active now, else a hand-over copy.

        An inactive module is evaluated on a copy that is first given the state of
        the active module of the same role (as a hand-over would); the live
        system is not changed.
        """
        mod = self._module(name)
        if name in self._plan.active_set:
            return mod
        mod = copy.deepcopy(mod)  # never change the live system
        for a in self._plan.active:
            other = self._pool[a]
            if other.role == mod.role and a not in plan.active_set:
                mod.import_state(other.export_state())
                break
        return mod

    def closed_loop(self, configuration: str | None = None) -> ClosedLoop:
        """The closed loop of ``configuration`` (default: the active one) around now.

        Modules whose type gives :meth:`RuntimeModule.linear_model` are wired along
        the configuration's active edges (:func:`archself.linear.interconnect`, in
        discrete time at the step); a module that gives none, or whose model closes
        no loop with the others, contributes its ``linearization()`` as a diagonal
        block. Inactive modules are evaluated on hand-over copies.

        Raises
        ------
        LinearizationError
            When the models cannot be wired (widths or periods disagree).
        """
        conf_name = configuration or self.configuration
        plan = self._make_plan(conf_name)
        if not plan.linearizable:  # no type of the configuration gives a model or a matrix
            return ClosedLoop(None, [])
        with gc_paused():  # many small acyclic objects (archself.linear.gc_paused)
            return self._closed_loop(plan)

    def _closed_loop(self, plan: _Plan) -> ClosedLoop:
        """:meth:`closed_loop` of a plan that has modules giving models or matrices."""
        mods = {n: self._linear_module(n, plan) for n in plan.active}
        base = RuntimeModule.linear_model
        models: dict[str, LinearModel] = {}
        widths: dict[tuple[str, str], int] = {}
        outs = self.outputs
        for n in (*plan.nonft, *plan.order):
            mod = mods[n]
            if type(mod).linear_model is base:
                continue
            ports: dict[str, list[Port]] = {}
            for carries, src, idx, *_ in plan.routes[n]:  # carries: n's input port
                sig = plan.reads.get(idx, carries)
                value = (outs.get(src) or {}).get(sig) if src in self._plan.active_set else None
                ports.setdefault(carries, []).append(Port(src, widths.get((src, sig)), value))
            lm = mod.linear_model(self.dt, ports)
            if lm is None:
                continue
            models[n] = lm
            for sig, size in lm.outputs:  # type: ignore[misc]
                widths.setdefault((n, sig), size)
        wires = plan.wires() if models else []
        if plan.reads and models:
            wires = self._port_wires(plan, wires, models, widths)
        routes = wiring(models, wires) if models else []
        in_loop = loop_modules(models, wires, routes=routes) if models else set()
        blocks: list[tuple[str, np.ndarray]] = []
        for n in plan.active:
            if n in models and n in in_loop:
                continue
            try:
                A = mods[n].linearization()
            except Exception:  # noqa: BLE001 - a failing linearization is no model
                A = None
            if A is not None:
                blocks.append((n, np.atleast_2d(np.asarray(A, dtype=float))))
                models.pop(n, None)
        loop = interconnect(models, wires, self.dt, routes=routes) if models else None
        return ClosedLoop(loop, blocks)

    def _port_wires(
        self, plan: _Plan, wires: list[Wire], models: dict[str, LinearModel],
        widths: dict[tuple[str, str], int],
    ) -> list[Wire]:
        """``wires`` with each renamed edge (``from: a.y, to: b.u``) through a pass-through.

        The edge becomes ``a --y--> [y→u] --u--> b``, a static identity model named
        ``a.y→b.u`` added to ``models``: no state, so the closed loop's eigenvalues are
        those of the direct wire.
        """
        out = list(wires)
        for n in plan.active:
            for port, src, idx, _unc, delay in plan.routes[n]:
                sig = plan.reads.get(idx)
                if sig is None:
                    continue
                out.remove(Wire(src, n, port, delay))
                width = widths.get((src, sig))
                if width is None or n not in models:
                    continue  # the source gives no model of it: the input is exogenous
                alias = f"{src}.{sig}→{n}.{port}"
                models[alias] = LinearModel([], [], [], np.eye(width), [(sig, width)],
                                            [(port, width)], dt=self.dt)
                out += [Wire(src, alias, sig, delay), Wire(alias, n, port)]
        return out

    def linearization(self, configuration: str | None = None) -> np.ndarray | None:
        """Closed-loop A (Eq. 20) of ``configuration`` (default: the active one), or None.

        The continuous-time matrix of :meth:`closed_loop` (:meth:`ClosedLoop.matrix`):
        the wired models' discrete closed loop as ``ln(λ)/dt`` in modal form, and the
        ``linearization()`` blocks of the modules without a model. None when no
        module provides either.
        """
        return self.closed_loop(configuration).matrix()

    def pool(self) -> dict[str, RuntimeModule]:
        """Every module instantiated so far (active or not)."""
        return dict(self._pool)
