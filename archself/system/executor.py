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

from collections import deque
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from archself.errors import SimulationError
from archself.model.architecture import Architecture
from archself.modules.base import RuntimeModule
from archself.system.dataflow import algebraic_loop
from archself.system.health import (
    NOT_NUMERIC,
    STALE_REPEATS,
    Publishing,
    declared_limits,
    needs_checks,
)
from archself.system.linearizing import Linearizing
from archself.system.objective import component_error, objective_norm
from archself.system.snapshot import Snapshots
from archself.system.step_plan import StepPlan, build_plan
from archself.system.streams import module_rng, stable_hash

__all__ = ["LiveSystem", "STALE_REPEATS", "algebraic_loop", "stable_hash", "module_rng"]


class LiveSystem(Publishing, Linearizing, Snapshots):
    """A running configuration of an architecture (the compiler → runtime contract).

    Build it with :func:`archself.system.compiler.compile_system`; see
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
        :mod:`archself.system.faults`; applied while the module is active.
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
        self._plans: dict[str, StepPlan] = {}
        self.outputs: dict[str, dict[str, Any]] = {}
        self._ok: dict[str, bool] = {}
        self._why: dict[str, str] = {}
        self._heard: dict[str, float] = {}  # module -> time of its last published value
        self._last: dict[tuple[str, str], Any] = {}  # (module, signal) -> last value
        self._repeats: dict[tuple[str, str], int] = {}
        self._broken: set[str] = set()  # modules whose last value was not finite
        # output types found not to be numbers (model objects): this system skips them
        self._not_numeric: set[type] = set(NOT_NUMERIC)
        self.history: list[dict[str, Any]] = []
        obj = arch.runtime.objective
        self._obj_actual = obj.actual
        self._obj_ref = obj.reference
        self._obj_comp = list(obj.components)
        self._scope: frozenset[str] | None = None  # a partial copy's modules (snapshot(only=))
        self._scoped: dict[str, StepPlan] = {}  # its plans, restricted to them
        self._plan = self._make_plan(configuration)  # instantiates the active modules
        # (plan, publishing ops, state-only ops) of the current plan (_bind); None: to make
        self._bound: tuple[StepPlan, list[tuple[Any, ...]], list[tuple[Any, ...]]] | None = None
        self.configuration = configuration

    # ------------------------------------------------------------------ plans
    def _module(self, name: str) -> RuntimeModule:
        mod = self._pool.get(name)
        if mod is None:
            if name not in self.arch.modules:
                raise SimulationError(f"unknown module {name!r}")
            mod = self._pool[name] = self._factory(name)
        return mod

    def _make_plan(self, configuration: str) -> StepPlan:
        plan = self._full_plan(configuration)
        if self._scope is None:
            return plan
        found = self._scoped.get(configuration)
        if found is None:
            found = self._scoped[configuration] = plan.restricted(self._scope)
        return found

    def _full_plan(self, configuration: str) -> StepPlan:
        plan = self._plans.get(configuration)
        if plan is None:
            plan = self._plans[configuration] = build_plan(
                self.arch, configuration, self._module, self.dt
            )
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

    def _bind(self, plan: StepPlan) -> tuple[list[tuple[Any, ...]], list[tuple[Any, ...]]]:
        """The ops of ``plan`` on this system's modules: what :meth:`step` runs, flat.

        One tuple per publishing module, ``(name, module, stepped, direct routes,
        required inputs, limits)``, and one per state-only module of phase 3,
        ``(name, module, direct routes, required inputs)``. ``limits`` is None for a
        module :func:`~archself.system.health.needs_checks` finds nothing to check on
        (its outputs are published as they are), else its ``(max_silence_s,
        noise_levels)``. Made when the plan or a module's parameters change
        (:meth:`set_params`), never per step.
        """
        pool = self._pool
        publishing = [
            (n, pool[n], stepped, plan.direct[n] if stepped else (), plan.required[n],
             declared_limits(pool[n]) if needs_checks(pool[n], self._faults.get(n)) else None)
            for n, stepped in plan.publishing
        ]
        advancing = [(n, pool[n], plan.direct[n], plan.required[n]) for n in plan.nonft]
        return publishing, advancing

    def step(self) -> None:
        """Advance the system by one step ``dt``."""
        t = self.t
        dt = self.dt
        plan = self._plan
        bound = self._bound
        if bound is None or bound[0] is not plan:
            bound = self._bound = (plan, *self._bind(plan))
        outs = self.outputs
        ok = self._ok
        why = self._why
        publish = self._publish
        gather = self._gather
        inputs: dict[str, Any] = {}
        # phases 1 and 2: the state-only outputs, then the feedthrough modules in order
        for name, mod, stepped, direct, req, limits in bound[1]:
            if stepped:
                if direct is None:
                    inputs = gather(name)
                else:  # inputs that pass unchanged, gathered inline
                    inputs = {}
                    for carries, src in direct:
                        so = outs.get(src)
                        val = None if so is None else so.get(carries)
                        if val is not None or carries not in inputs:
                            inputs[carries] = val
            try:
                out = mod.step(t, dt, inputs) if stepped else mod.output(t)
                if limits is not None:
                    reason = publish(name, out, t, limits)
                else:
                    outs[name] = {} if out is None else out
                    reason = None
            except Exception as exc:  # noqa: BLE001 - a failing module must not stop the run
                reason = f"raised {type(exc).__name__}"
            if reason is None and stepped:
                for s in req:
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
        for name, mod, direct, req in bound[2]:
            if direct is None:
                inputs = gather(name)
            else:
                inputs = {}
                for carries, src in direct:
                    so = outs.get(src)
                    val = None if so is None else so.get(carries)
                    if val is not None or carries not in inputs:
                        inputs[carries] = val
            try:
                mod.step(t, dt, inputs)
            except Exception as exc:  # noqa: BLE001
                ok[name] = False
                why[name] = f"raised {type(exc).__name__}"
                continue
            if ok[name]:
                for s in req:
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
        return component_error(
            self.signal(self._obj_actual), self.signal(self._obj_ref), self._obj_comp
        )

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

    def set_params(self, module: str, values: Mapping[str, Any]) -> None:
        """Apply a parameter update to ``module`` (instantiated if not yet used)."""
        self._module(module).set_params(dict(values))
        self._bound = None  # its noise levels or silence limit may have changed

    def pool(self) -> dict[str, RuntimeModule]:
        """Every module instantiated so far (active or not)."""
        return dict(self._pool)
