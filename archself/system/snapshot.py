"""Copies of a running system for rollouts: whole or partial snapshots, the rollout scope.

:class:`Snapshots` is the part of :class:`archself.system.executor.LiveSystem` that makes
independent deep copies (same random states, so a rollout is deterministic; the
architecture, factory and immutable plans shared) and partial copies of the
modules a rollout needs for the objective (:meth:`Snapshots.rollout_scope`, by
:meth:`archself.system.step_plan.StepPlan.reach` and the hand-over sources).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Collection
from typing import Any, Self

from archself.model.architecture import Architecture
from archself.modules.base import RuntimeModule
from archself.system.step_plan import StepPlan

__all__ = ["Snapshots"]


class Snapshots:
    """Snapshots and rollout scope of a :class:`~archself.system.executor.LiveSystem` (a mixin)."""

    arch: Architecture
    configuration: str
    outputs: dict[str, dict[str, Any]]
    _factory: Callable[[str], RuntimeModule]
    _plan: StepPlan
    _plans: dict[str, StepPlan]
    _scoped: dict[str, StepPlan]
    _scope: frozenset[str] | None
    _pool: dict[str, RuntimeModule]
    _ok: dict[str, bool]
    _why: dict[str, str]
    _heard: dict[str, float]
    _last: dict[tuple[str, str], Any]
    _repeats: dict[tuple[str, str], int]
    _broken: set[str]
    _faults: dict[str, list[tuple[str, Any]]]
    _delay: dict[int, Any]
    _bound: Any
    _edge_rng: dict[int, Any]
    _obj_actual: Any
    _obj_ref: Any
    _module: Callable[[str], RuntimeModule]  # LiveSystem's methods
    _make_plan: Callable[[str], StepPlan]
    _full_plan: Callable[[str], StepPlan]

    def snapshot(self, only: Collection[str] | None = None) -> Self:
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
        memo.update((id(p), p) for p in (*self._plans.values(), *self._scoped.values()))
        memo[id(self._bound)] = None  # the ops bind this system's modules: made again
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
            "_broken": self._broken & keep,
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
        keep = plan.reach(starts, steps)
        current = self._plan
        if plan.name != current.name:
            gone = [g for g in current.active if g not in plan.active_set]
            for n in [n for n in keep if n not in current.active_set]:
                role = self._module(n).role
                giver = next((g for g in gone if self._pool[g].role == role), None)
                if giver is not None:
                    keep.add(giver)
        return frozenset(keep)
