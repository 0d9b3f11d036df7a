"""The lane executor: N runs of one architecture stepped together, one call per module.

:class:`LaneSystem` takes N per-run systems (:class:`archself.system.live.LiveSystem`,
one per lane: its seed, its sweep point's parameters, its scenario's faults) of
the same structure and steps them as one. Lanes in the same configuration form a
*group*; for every active module of a group a
:class:`~archself.lanes.module.LaneModule` (the type's batched class, or
:class:`~archself.lanes.module.PerLane`) advances the group's lanes with one call,
in the order and with the routing of the per-run plan. What the per-run step does
per value it does per lane: edge noise from each lane's own stream, edge
latencies, the scenario's faults from each lane's own injectors, a lane whose
module raised or whose value a fault made non-finite holds its last outputs, and
every module's availability and its reason (:class:`~archself.lanes.health.LaneHealth`).

:meth:`LaneSystem.move` takes a lane to another configuration (after its per-run
system made the change: hand-over and parameter updates happen there, on the
lane's stored state); :mod:`archself.lanes.view` is the per-lane face the
adaptation loop sees.

Lane values follow :mod:`archself.lanes.module` (NaN = absent in that lane).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from archself.errors import SimulationError
from archself.lanes.batching import lane_module_class
from archself.lanes.edges import Delay, add_noise
from archself.lanes.faults import LaneFault
from archself.lanes.health import LaneHealth
from archself.lanes.module import ALL, LaneModule, LaneNormals, PerLane, distinct, stack
from archself.system.live import LiveSystem, module_rng

__all__ = ["LaneSystem", "lane_copies"]

#: The reasons of a publishing call with nothing to judge (never filled in).
_NONE: dict[int, str] = {}


def _plan_key(plan: Any) -> Any:
    """What lanes must share of a configuration's plan (edge noise may differ)."""
    routes = {n: [r[:3] + r[4:] for r in rs] for n, rs in plan.routes.items()}
    return plan.active, plan.order, plan.nonft, routes


class LaneSystem:
    """N lanes of an architecture, grouped by configuration, stepped together.

    Parameters
    ----------
    systems : sequence of LiveSystem
        One compiled per-run system per lane, all of the same architecture
        structure (modules, types, edges) and step, at t = 0; their parameters,
        seeds, faults and starting configurations may differ.

    Raises
    ------
    SimulationError
        If the systems differ in structure or step.
    """

    def __init__(self, systems: Sequence[LiveSystem]) -> None:
        if not systems:
            raise SimulationError("a lane system needs at least one lane")
        self.systems = list(systems)
        first = self.systems[0]
        self.n = len(self.systems)
        self.dt = first.dt
        self.t = 0.0
        self.k = 0
        if any(s.dt != self.dt for s in self.systems):
            raise SimulationError("lanes must share the architecture's structure and step")
        self.arch = first.arch
        self.configuration = [s.configuration for s in self.systems]
        self.plans: dict[str, Any] = {}
        self.groups: dict[str, np.ndarray] = {}
        self._regroup()
        self.modules: dict[str, LaneModule] = {}
        self.outputs: dict[str, dict[str, Any]] = {}
        self.health = LaneHealth(self.n)
        self.failed: dict[str, np.ndarray] = {}  # module -> lanes that failed in the last step
        self._faults: dict[str, list[LaneFault]] = {}
        for name in self.arch.modules:
            per_lane = [s._faults.get(name, []) for s in self.systems]
            if any(len(f) != len(per_lane[0]) for f in per_lane):
                raise SimulationError(f"lanes must have the same faults on {name!r}")
            if per_lane[0]:  # the j-th fault of every lane: (signal, injector) pairs
                self._faults[name] = [_fault(fs) for fs in zip(*per_lane, strict=True)]
        self._edge_noise: dict[int, tuple[np.ndarray, LaneNormals] | None] = {}
        self._delay: dict[int, Delay] = {}
        self._streams: tuple[int, list[LaneNormals]] | None = None
        #: J of every lane at the current step (set by the run; the loop's J_obs)
        self.objective: np.ndarray | None = None
        self._arrays: dict[str, dict[str, np.ndarray]] = {}
        self._arrays_k = -1
        self._plans_calls: dict[str, tuple[list[tuple], list[tuple]]] = {}

    @classmethod
    def resume(cls, systems: Sequence[LiveSystem], *, smooth: bool = False) -> LaneSystem:
        """Lanes that go on from running per-run systems (one configuration, one time).

        What a per-run step reads besides the modules' state is taken over: the
        outputs of the last step, each module's availability, reason, last heard time
        and stale counts, the edges' latency lines and noise streams. With ``smooth``
        (the whole-loop linearization), a type whose lane class does not follow the
        per-run ``smooth`` flag (``LaneModule.follows_smooth``) runs lane by lane.

        One system may be given for several lanes (:func:`lane_copies`): its per-run
        modules are then shared by those lanes (the lane modules hold each lane's state;
        :meth:`LaneModule.state` and ``set_state`` read and write the lane arrays, or go
        through those instances lane by lane where a class declares no array state), its
        random streams and its faults' injectors are copied per lane at their state.

        Raises
        ------
        SimulationError
            Systems of different structure, configuration or time; a module that runs
            lane by lane (:class:`PerLane`) in lanes that share a system.
        """
        first = systems[0]
        if any(s.configuration != first.configuration or s.k != first.k for s in systems):
            raise SimulationError("resumed lanes must share their configuration and step")
        lanes = cls(systems)
        lanes.t, lanes.k = first.t, first.k
        for name in lanes.plan(first.configuration).active:
            mods = [s._module(name) for s in systems]
            if smooth and not getattr(lane_module_class(mods[0]), "follows_smooth", True):
                lanes.modules[name] = _per_lane(mods)
        for name, out in first.outputs.items():
            lanes.outputs[name] = {
                sig: stack([(s.outputs.get(name) or {}).get(sig) for s in systems]) for sig in out
            }
        lanes.health.resume(systems)
        for e in first._delay:
            lanes._delay[e] = Delay.resume(lanes.n, [s._delay[e] for s in systems])
        for e in first._edge_rng:
            noise = lanes._noise(e)
            if noise is not None:  # the streams where the runs stand, not where they started
                lanes._edge_noise[e] = (noise[0], LaneNormals([s._edge_rng[e] for s in systems]))
        return lanes

    # ------------------------------------------------------------------ structure
    def plan(self, configuration: str) -> Any:
        """The step plan of ``configuration`` (checked once to be the same in every lane)."""
        plan = self.plans.get(configuration)
        if plan is None:
            plans = [s._full_plan(configuration) for s in self.systems]
            key = _plan_key(plans[0])
            if any(_plan_key(p) != key for p in plans[1:]):
                raise SimulationError(
                    "lanes must share the architecture's structure and step "
                    f"(configuration {configuration!r} differs)"
                )
            plan = self.plans[configuration] = plans[0]
        return plan

    def _regroup(self) -> None:
        groups: dict[str, list[int]] = {}
        for i, c in enumerate(self.configuration):
            groups.setdefault(c, []).append(i)
        self.groups = {c: np.array(v, dtype=np.intp) for c, v in groups.items()}
        for c in self.groups:
            self.plan(c)

    def module(self, name: str) -> LaneModule:
        """The lane module of ``name`` (built from the per-run instances on first use)."""
        mod = self.modules.get(name)
        if mod is None:
            mods = [s._module(name) for s in self.systems]
            cls = lane_module_class(mods[0])
            mod = self.modules[name] = _per_lane(mods) if cls is PerLane else cls(mods)
        return mod

    def move(self, lane: int, configuration: str) -> None:
        """Lane ``lane`` now runs ``configuration`` (its per-run system switched already).

        The modules the lane leaves drop their outputs and availability in it, as
        :meth:`LiveSystem.apply_configuration` does; every module of the new
        configuration reloads the lane from its per-run instance (the hand-over).
        """
        old = self.plan(self.configuration[lane])
        new = self.plan(configuration)
        one = np.array([lane])
        for g in old.active:
            if g in new.active_set:
                continue
            out = self.outputs.get(g)
            if out:
                self.outputs[g] = {s: _absent_rows(v, one) for s, v in out.items()}
            self.health.forget(g, one)
        self.configuration[lane] = configuration
        self.reload(lane)
        self._regroup()

    def reload(self, lane: int) -> None:
        """Every module of ``lane``'s configuration reads the lane back (new parameters)."""
        one = np.array([lane])
        for m in self.plan(self.configuration[lane]).active:
            self.module(m).load(one)
        self.health.invalidate()

    # ------------------------------------------------------------------ a step
    def _noise(self, idx: int) -> tuple[np.ndarray, LaneNormals] | None:
        if idx not in self._edge_noise:
            e = self.arch.edges[idx]
            unc = np.array([float(s.arch.edges[idx].uncertainty) for s in self.systems])
            self._edge_noise[idx] = None
            if (unc > 0).any():
                rngs = [
                    module_rng(s.seed, f"edge:{e.source}->{e.target}:{e.carries}")
                    for s in self.systems
                ]
                self._edge_noise[idx] = (unc, LaneNormals(rngs))
        return self._edge_noise[idx]

    def _calls(self, configuration: str) -> tuple[list[tuple], list[tuple]]:
        """The publishing and state-only calls of ``configuration``'s plan (made once).

        A call is ``(name, module, stepped, routes, required, faults)``: the lane module
        itself, and its routes with the signal each reads resolved
        (``(carries, source, signal, edge, noisy, delay, multi)``), so a step does no
        per-module lookups.
        """
        got = self._plans_calls.get(configuration)
        if got is None:
            plan = self.plans[configuration]
            reads = plan.reads

            def call(name: str, stepped: bool) -> tuple:
                multi = plan.multi.get(name, ())
                routes = tuple(
                    (carries, src, reads.get(e, carries), e, bool(unc), delay, carries in multi)
                    for carries, src, e, unc, delay in plan.routes[name]
                )
                self.health.arrays(name)  # its availability is recorded from now on
                return (name, self.module(name), stepped, routes, plan.required[name],
                        self._faults.get(name, ()))

            got = self._plans_calls[configuration] = (
                [call(n, stepped) for n, stepped in plan.publishing],
                [call(n, True) for n in plan.nonft],
            )
        return got

    def _gather(self, routes: tuple, idx: np.ndarray, whole: bool) -> dict[str, Any]:
        outs = self.outputs
        inputs: dict[str, Any] = {}
        for carries, src, sig, e, noisy, delay, multi in routes:
            src_out = outs.get(src)
            val = src_out.get(sig) if src_out is not None else None
            if val is not None and not whole:
                val = [val[i] for i in idx] if type(val) is list else val[idx]
            if delay:
                line = self._delay.get(e)
                if line is None:
                    line = self._delay[e] = Delay(self.n, delay)
                val = line.exchange(val, idx)
            if noisy and val is not None and type(val) is not list:
                noise = self._noise(e)
                if noise is not None:
                    val = add_noise(val, idx, *noise)
            if multi:
                inputs[carries] = (*inputs.get(carries, ()), val)
            elif val is not None or carries not in inputs:
                inputs[carries] = val
        return inputs

    def _publish(self, name: str, mod: LaneModule, faults: Any, out: dict[str, Any] | None,
                 t: float, idx: np.ndarray, whole: bool) -> dict[int, str]:
        """Faults, held outputs and the health reasons of one publishing call."""
        if whole and not mod.failed and not faults and self.health.unjudged(name, mod.modules):
            self.outputs[name] = out if out is not None else {}  # nothing can fail here
            self.failed.pop(name, None)
            return _NONE
        failed = dict(mod.failed)
        mod.failed.clear()
        out = dict(out or {})
        for fault in faults:
            if fault.signal in out:
                out[fault.signal], broken = fault.apply(t, out[fault.signal], idx)
                for i in broken:
                    failed.setdefault(int(i), "non-finite output")
        reasons = self.health.published(name, out, idx, t, failed, mod.modules)
        if failed:
            self.failed[name] = np.array(sorted(failed))
        else:
            self.failed.pop(name, None)
        if whole and not failed:
            self.outputs[name] = out
            return reasons
        keep = np.array([i not in failed for i in idx.tolist()], dtype=bool)
        old = self.outputs.get(name, {})
        self.outputs[name] = {
            s: _put_rows(old.get(s), out.get(s), idx[keep], keep, self.n)
            for s in {*old, *out}
        }
        return reasons

    def step(self) -> None:
        """Advance every lane by one step ``dt``."""
        t, dt = self.t, self.dt
        health = self.health
        for conf, idx in list(self.groups.items()):
            publishing, state_only = self._calls(conf)
            whole = len(idx) == self.n
            lanes = ALL if whole else idx
            for name, mod, stepped, routes, required, faults in publishing:
                inputs = self._gather(routes, idx, whole) if stepped else None
                try:
                    out = (mod.step(t, dt, inputs, lanes) if inputs is not None
                           else mod.output(t, lanes))
                except Exception as exc:  # noqa: BLE001 - every lane of the call failed
                    mod.failed.update({int(i): f"raised {type(exc).__name__}" for i in idx})
                    out = None
                reasons = self._publish(name, mod, faults, out, t, idx, whole)
                if inputs is not None and required:
                    if reasons is _NONE:
                        reasons = {}
                    health.lost_inputs(inputs, required, idx, reasons)
                if reasons or health.why.get(name):
                    health.settle(name, idx, reasons)
            for name, mod, _stepped, routes, required, _faults in state_only:
                inputs = self._gather(routes, idx, whole)
                try:
                    mod.step(t, dt, inputs, lanes)
                except Exception as exc:  # noqa: BLE001
                    mod.failed.update({int(i): f"raised {type(exc).__name__}" for i in idx})
                reasons = dict(mod.failed)
                mod.failed.clear()
                later: dict[int, str] = {}
                health.lost_inputs(inputs, required, idx, later)
                if not reasons and not later:
                    continue
                ok, why = health.arrays(name)
                reasons.update({i: r for i, r in later.items() if i not in reasons and ok[i]})
                for i, r in reasons.items():
                    ok[i] = False
                    why[i] = r
        self.k += 1
        self.t = self.k * dt

    def available(self, lane: int) -> dict[str, bool]:
        """module -> availability in ``lane`` (its configuration's modules), as
        :meth:`LiveSystem.available`."""
        active = self.plan(self.configuration[lane]).active
        health = self.health
        if not health.any_down():
            return dict.fromkeys(active, True)
        return {n: health.available(n, lane) for n in active}

    def reasons(self, lane: int) -> dict[str, str | None]:
        """module -> why it is unavailable in ``lane`` (None: available), as
        :meth:`LiveSystem.health`."""
        return {n: self.health.reason(n, lane)
                for n in self.plan(self.configuration[lane]).active}

    def active_set(self, lane: int) -> frozenset[str]:
        """The active modules of ``lane``'s configuration."""
        return self.plan(self.configuration[lane]).active_set

    def signal(self, module: str, signal: str) -> Any:
        """The lane value of ``module.signal`` in every lane (None when no lane has it)."""
        out = self.outputs.get(module)
        return None if out is None else out.get(signal)

    def streams(self) -> list[LaneNormals]:
        """Every per-lane random stream the lane modules draw from (for :meth:`LaneNormals.pin`)."""
        if self._streams is None or self._streams[0] != len(self.modules):
            found = [v for m in self.modules.values() for v in vars(m).values()
                     if isinstance(v, LaneNormals)]
            self._streams = (len(self.modules), found)
        return self._streams[1]

    def local_signals_of(self, lane: int) -> dict[str, dict[str, float]]:
        """module -> residual signal -> value in ``lane``, as :meth:`LiveSystem.local_signals`."""
        return {n: {s: float(v[lane]) for s, v in self.signal_arrays(n).items()}
                for n in self.plan(self.configuration[lane]).active}

    def signal_arrays(self, name: str) -> dict[str, np.ndarray]:
        """Residual signal -> its values in every lane, of module ``name`` (once per step)."""
        if self._arrays_k != self.k:
            self._arrays.clear()
            self._arrays_k = self.k
        got = self._arrays.get(name)
        if got is None:
            got = self._arrays[name] = self.module(name).local_signals(ALL)
        return got

    def store(self, lanes: slice | np.ndarray = ALL) -> None:
        """Write ``lanes``' state into their per-run systems' modules."""
        for mod in self.modules.values():
            mod.store(lanes)


def lane_copies(system: LiveSystem, n: int, *, smooth: bool = False) -> list[LiveSystem]:
    """``system`` for ``n`` lanes of :meth:`LaneSystem.resume` (the whole-loop check's probes).

    The first is ``system``; the others are shallow copies that share its per-run
    modules, except those that run lane by lane (:class:`PerLane`: no lane class, or
    under ``smooth`` one that does not follow it), which step their per-run instance and
    so get a deep copy each.
    """
    own = []
    for name in system._plan.active:
        cls = lane_module_class(system._module(name))
        if cls is PerLane or (smooth and not getattr(cls, "follows_smooth", True)):
            own.append(name)
    if not own:
        return [system] * n
    memo = {id(system.arch): system.arch, id(system._factory): system._factory}
    out = [system]
    for _ in range(n - 1):
        lane = copy.copy(system)
        lane._pool = dict(system._pool)
        for name in own:
            lane._pool[name] = copy.deepcopy(system._pool[name], dict(memo))
        out.append(lane)
    return out


def _per_lane(mods: list[Any]) -> PerLane:
    """:class:`PerLane` of ``mods``: each lane steps its own instance, so none is shared."""
    if len({id(m) for m in mods}) < len(mods):
        raise SimulationError(f"{mods[0].name}: lanes that share a system cannot run it lane "
                              "by lane (its per-run instance would step once per lane)")
    return PerLane(mods)


def _fault(faults: Sequence[tuple[str, Any]]) -> LaneFault:
    """The lane fault of one ``(signal, injector)`` per lane; an injector named by several
    lanes (a shared system) is copied per lane where the kind keeps state in it."""
    fault = LaneFault(faults[0][0], [f[1] for f in faults])
    if not fault.vector:  # noise from the injector's stream, a held value
        fault.injectors = distinct(fault.injectors)
    return fault


def _absent_rows(value: Any, lanes: np.ndarray) -> Any:
    """``value`` with ``lanes`` absent."""
    if value is None:
        return None
    if type(value) is list:
        kept = list(value)
        for i in lanes:
            kept[i] = None
        return kept
    out = np.array(value, dtype=float)
    out[lanes] = math.nan
    return out


def _put_rows(full: Any, new: Any, lanes: np.ndarray, keep: np.ndarray, n: int) -> Any:
    """``full`` (all lanes) with ``lanes`` set from the rows ``keep`` of ``new`` (None: absent)."""
    if not len(lanes):
        return full
    if new is None and full is None:
        return None
    if type(new) is list or type(full) is list:
        objs = list(full) if full is not None else [None] * n
        rows = [v for v, k in zip(new or [None] * len(keep), keep, strict=True) if k]
        for i, v in zip(lanes.tolist(), rows, strict=True):
            objs[i] = v
        return objs
    ref = new if new is not None else full
    shape = (n,) + tuple(np.shape(ref)[1:])
    out = np.full(shape, math.nan) if full is None else np.array(full, dtype=float)
    out[lanes] = math.nan if new is None else new[keep]
    return out
