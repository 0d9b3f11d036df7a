"""The whole-loop linearization of one lane with its perturbed copies stepped as lanes.

:func:`archself.system.linearizing.numerical_loop` steps one snapshot per perturbation
(the nominal copy, then +h and −h of every column group: 29 copies of the diff-drive's
a2) for ``steps`` steps each, one per-run step at a time. :func:`lane_loop` takes the
same base copy and perturbations (:func:`~archself.system.linearizing.loop_probes`) and
steps them together as the lanes of a :class:`~archself.lanes.system.LaneSystem`
resumed from them (:meth:`LaneSystem.resume`); each lane's state is read back through
its lane class's :meth:`~archself.lanes.module.LaneModule.store`, and the same
:meth:`~archself.system.linearizing.LoopProbes.assemble` makes A. The lane classes
compute what the per-run classes compute (docs/lanes.md), so A is the per-run path's
(bit for bit on the diff-drive's a1 → a2, a1 → a3 and a2 checks, tests/test_lanes.py).

A lane does not need a deep copy of the whole system (the copies were three quarters of
the check's time): a batched lane class reads its per-run instance only in ``load``
and writes it only in ``store``, so each lane gets a shallow copy of the base's module
with its own random stream, and a deep copy only where it is perturbed (its state set)
or where the type runs lane by lane (:class:`~archself.lanes.module.PerLane` steps its
instance). The faults' injectors and the edges' streams are each lane's own.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from archself.lanes.batching import lane_module_class
from archself.lanes.faults import VECTOR_KINDS
from archself.lanes.module import PerLane
from archself.lanes.system import LaneSystem
from archself.linear.closed_loop import WholeLoop
from archself.system.linearizing import loop_probes

__all__ = ["lane_loop"]


def lane_loop(system: Any, configuration: str | None = None, steps: int = 1) -> WholeLoop:
    """:func:`~archself.system.linearizing.numerical_loop` of the per-run ``system``, its
    perturbed copies stepped as lanes.

    Parameters
    ----------
    system : LiveSystem
        A running per-run system (a lane's, materialized); never changed.
    configuration : str, optional
        The configuration to linearize (default: the active one).
    steps : int
        Steps of the map.
    """
    probes = loop_probes(system, configuration, steps)
    base = probes.probe.base
    shells = [_shell(base, shift, probes.probe.x0) for shift in probes.shifts]
    lanes = LaneSystem.resume(shells, smooth=True)
    for _ in range(steps):
        lanes.step()
    for i in range(lanes.n):
        probes.probe.raised({n: lanes.health.reason(n, i) for n in lanes.health.why})
    states: list[dict[str, np.ndarray]] = [{} for _ in range(lanes.n)]
    for n in probes.stateful:
        mod = lanes.module(n)
        for i in range(lanes.n):  # one lane at a time: lanes may share nested objects
            mod.store(np.array([i]))
            inst = mod.modules[i]
            states[i][n] = type(inst).state(inst)
    return probes.assemble(states, read=lambda run, n: run[n])


def _fresh(rng: np.random.Generator) -> np.random.Generator:
    """An independent generator at ``rng``'s state."""
    g = np.random.Generator(type(rng.bit_generator)())
    g.bit_generator.state = rng.bit_generator.state
    return g


def _shell(base: Any, shift: dict[str, tuple[int, float]], x0: dict[str, np.ndarray]) -> Any:
    """A lane's copy of ``base``: its active modules shallow copies with their own random
    streams (deep copies where ``shift`` moves their state or the type runs lane by
    lane), its own fault injectors and edge streams; the rest shared and only read."""
    memo = {id(base.arch): base.arch}
    pool = dict(base._pool)
    for n in base._plan.active:
        mod = base._pool[n]
        if n in shift or lane_module_class(mod) is PerLane:
            m = copy.deepcopy(mod, dict(memo))
        else:
            m = copy.copy(mod)
            if isinstance(getattr(mod, "rng", None), np.random.Generator):
                m.rng = _fresh(mod.rng)
        pool[n] = m
    for n, (i, h) in shift.items():
        x = x0[n].copy()
        x[i] += h
        type(pool[n]).set_state(pool[n], x)
    shell = copy.copy(base)
    shell._pool = pool
    shell._faults = {n: [(sig, inj if inj.kind in VECTOR_KINDS else copy.deepcopy(inj))
                         for sig, inj in fs]
                     for n, fs in base._faults.items()}  # (the vector kinds keep no state)
    shell._edge_rng = {e: _fresh(g) for e, g in base._edge_rng.items()}
    return shell
