"""One lane as the adaptation loop sees it: the live-system contract over a lane system.

The MAPE-K loop of a lane (:class:`archself.runtime.MapeK`, one per lane, with its
own Monitor filters, knowledge and decision log) is called with a :class:`LaneView`.
Monitor and Analyze read the time, the configuration, the objective error, the
residual signals, the availability and (for declared limits) the outputs: the view
answers these from the lane system's arrays, lane ``i``'s entries, without touching
the per-run system.

Anything else (the Plan's rollouts, snapshots, linear models, the Execute's
``apply_configuration`` and ``set_params``) needs the lane as a per-run system: the
view then *materializes* it — every module's state stored into the lane's per-run
instances, their random streams put at the per-run position
(:meth:`~archself.lanes.module.LaneNormals.pin`), the outputs, availability, edge
streams and latency lines copied — and hands the call to that
:class:`~archself.system.live.LiveSystem`. After the cycle :meth:`LaneView.done` gives the
streams back and moves the lane if the loop switched it or changed a parameter.

The whole-loop linearization of a lane's stability check (:func:`lane_loop`):
:func:`archself.system.linearizing.numerical_loop` steps one copy per perturbation
(the nominal, then +h and −h of every column group: 29 of the diff-drive's a2) for
``steps`` steps each, one per-run step at a time. :func:`lane_loop` takes the same
base copy and perturbations (:func:`~archself.system.linearizing.loop_probes`) and steps
them together as the lanes of one :class:`~archself.lanes.system.LaneSystem`: the base
is resumed once per perturbation (:meth:`LaneSystem.resume` of one system for several
lanes: its per-run modules shared, its random streams and fault injectors copied per
lane), the lanes' perturbed states set through each lane module in one call
(:meth:`~archself.lanes.module.LaneModule.set_state`) and read back after the steps in one
array read per module (:meth:`~archself.lanes.module.LaneModule.state_rows`, or lane by
lane through the per-run bridge where a class declares no array state); the same
:meth:`~archself.system.linearizing.LoopProbes.assemble` makes A. No per-probe copy is
made (before: 29 copies a check, loaded from one pickle, then packed into lanes again:
0.4 ms a copy, a third of the check). The lane classes compute what the per-run classes
compute (docs/lanes.md), so A is the per-run path's (bit for bit on the diff-drive's
a1 → a2 and a2 and the motor drive's m1 → m2 checks, tests/test_lanes_linearize.py).

A type that runs lane by lane there (no lane class, or one that does not follow
``smooth``: :class:`~archself.lanes.module.PerLane`) steps its per-run instances, so each
probe lane gets a deep copy of that module alone
(:func:`~archself.lanes.system.lane_copies`). Copies of the whole base stay deep where
they are made (the per-run check's, :class:`~archself.system.linearizing.Clones`): shallow
copies with their own streams stepped state shared with the other copies (a lane ended
a ``sensor_dropout`` run of ``thermal_zone.yaml`` in another configuration than its
per-run twin, tests/test_blocks_domain.py).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Collection, Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from archself.lanes.module import ALL, row
from archself.lanes.system import LaneSystem, lane_copies
from archself.system.linearizing import LoopProbes, loop_probes

if TYPE_CHECKING:
    from archself.linear.closed_loop import ClosedLoop, WholeLoop
    from archself.model.architecture import Architecture
    from archself.modules.base import RuntimeModule
    from archself.system.live import LiveSystem

__all__ = ["LaneView", "lane_loop", "lane_loops"]


class _Outputs(Mapping):
    """Lane ``i``'s outputs of the active modules, made on demand."""

    def __init__(self, view: LaneView) -> None:
        self.view = view

    def __getitem__(self, name: str) -> dict[str, Any]:
        if name not in self.view.active:
            raise KeyError(name)
        out = self.view.lanes.outputs.get(name) or {}
        i = self.view.i
        return {s: row(v, i) for s, v in out.items()}

    def __iter__(self) -> Iterator[str]:
        return iter(n for n in self.view.lanes.plan(self.view.configuration).active
                    if n in self.view.lanes.outputs)

    def __len__(self) -> int:
        return sum(1 for _ in self)


class LaneView:
    """Lane ``i`` of a :class:`~archself.lanes.system.LaneSystem` as a live system.

    Parameters
    ----------
    lanes : LaneSystem
    i : int
        The lane.
    """

    def __init__(self, lanes: Any, i: int) -> None:
        self.lanes = lanes
        self.i = i
        self.live: LiveSystem = lanes.systems[i]
        self._materialized = False
        self._params_seen = 0
        #: the worker running the lane's loop call, when its checks are batched
        self.worker: Any = None

    # ------------------------------------------------------------------ the quiet path
    @property
    def t(self) -> float:
        return self.lanes.t

    @property
    def configuration(self) -> str:
        return self.live.configuration if self._materialized else self.lanes.configuration[self.i]

    @property
    def active(self) -> set[str] | frozenset[str]:
        if self._materialized:
            return self.live.active
        return self.lanes.active_set(self.i)

    @property
    def outputs(self) -> Mapping[str, dict[str, Any]]:
        return self.live.outputs if self._materialized else _Outputs(self)

    def objective_error(self) -> float:
        """J_obs of the lane: the run's J of this step (the per-run system's number)."""
        if self._materialized:
            return self.live.objective_error()
        return float(self.lanes.objective[self.i])

    def local_signals(self) -> dict[str, dict[str, float]]:
        """module -> residual signals of lane ``i`` (its configuration's modules)."""
        if self._materialized:
            return self.live.local_signals()
        return self.lanes.local_signals_of(self.i)

    def available(self) -> dict[str, bool]:
        return self.live.available() if self._materialized else self.lanes.available(self.i)

    def health(self) -> dict[str, str | None]:
        return self.live.health() if self._materialized else self.lanes.reasons(self.i)

    # ------------------------------------------------------------------ everything else
    # the lane's own per-run system answers, made what the lane is now (materialize)
    @property
    def arch(self) -> Architecture:
        return self.live.arch

    @property
    def dt(self) -> float:
        return self.live.dt

    def _live(self) -> LiveSystem:
        self.materialize()
        return self.live

    def step(self) -> None:
        self._live().step()

    def apply_configuration(self, name: str) -> None:
        self._live().apply_configuration(name)

    def set_params(self, module: str, values: Mapping[str, Any]) -> None:
        self._live().set_params(module, values)

    def snapshot(self, only: Collection[str] | None = None) -> LiveSystem:
        return self._live().snapshot(only)

    def rollout_scope(self, configuration: str | None = None, steps: int = 0) -> frozenset[str]:
        return self._live().rollout_scope(configuration, steps)

    def dependencies(self, configuration: str | None = None) -> dict[str, frozenset[str]]:
        return self._live().dependencies(configuration)

    def linearization(self, configuration: str | None = None) -> np.ndarray | None:
        return self._live().linearization(configuration)

    def closed_loop(self, configuration: str | None = None) -> ClosedLoop:
        return self._live().closed_loop(configuration)

    def whole_loop(self, configuration: str | None = None, steps: int = 1) -> WholeLoop:
        """The lane's whole loop, its perturbed copies stepped as lanes (:func:`lane_loop`;
        inside a loop call run by :func:`archself.lanes.run._adapt` in a worker, with the
        other lanes' checks of the cycle: :func:`lane_loops`)."""
        if self.worker is not None:
            return self.worker.ask((self._live(), configuration, steps))
        return lane_loop(self._live(), configuration, steps)

    def state_error(self) -> np.ndarray:
        return self._live().state_error()

    @property
    def modules(self) -> dict[str, RuntimeModule]:
        return self._live().modules

    def materialize(self) -> None:
        """Make the per-run system of the lane what the lane is now (once per cycle)."""
        if self._materialized:
            return
        lanes, i, live = self.lanes, self.i, self.live
        one = np.array([i])
        lanes.store(one)
        for ln in lanes.streams():
            ln.pin(i)
        plan = lanes.plan(lanes.configuration[i])
        live.t, live.k = lanes.t, lanes.k
        live.outputs = {
            n: {s: row(v, i) for s, v in lanes.outputs[n].items()}
            for n in plan.active if n in lanes.outputs
        }
        health = lanes.health
        live._ok = {n: health.available(n, i) for n in plan.active if n in health.ok}
        live._why = {n: r for n in plan.active if (r := health.reason(n, i)) is not None}
        live._heard = {n: float(h[i]) for n, h in health.heard.items()
                       if n in plan.active_set and not math.isnan(h[i])}
        live._broken = {n for n, b in health.broken.items() if b[i] and n in plan.active_set}
        for e, noise in lanes._edge_noise.items():
            if noise is not None:
                g = np.random.Generator(type(noise[1].rngs[i].bit_generator)())
                g.bit_generator.state = noise[1].exact_state(i)
                live._edge_rng[e] = g
        for e, line in lanes._delay.items():
            vals = [None] * line.delay
            if line.buf is not None:
                h = int(line.head[i])
                vals = [row(line.buf[(h + j) % line.delay], i) for j in range(line.delay)]
            live._delay[e] = deque(vals)
        self._materialized = True

    def done(self, updates: int) -> None:
        """End of the lane's cycle: streams back, and the lane moved or reloaded if changed.

        ``updates`` is the number of parameter updates the lane's loop has made so far.
        """
        if not self._materialized:
            return
        for ln in self.lanes.streams():
            ln.unpin()
        if self.live.configuration != self.lanes.configuration[self.i]:
            self.lanes.move(self.i, self.live.configuration)
        elif updates != self._params_seen:
            self.lanes.reload(self.i)
        self._params_seen = updates
        self._materialized = False


# ---------------------------------------------------------------------- the whole loop
def lane_loop(system: Any, configuration: str | None = None, steps: int = 1) -> WholeLoop:
    """:func:`~archself.system.linearizing.numerical_loop` of the per-run ``system``, its
    probes stepped as the lanes of one base.

    Parameters
    ----------
    system : LiveSystem
        A running per-run system (a lane's, materialized); never changed.
    configuration : str, optional
        The configuration to linearize (default: the active one).
    steps : int
        Steps of the map.
    """
    return lane_loops([(system, configuration, steps)])[0]


def lane_loops(checks: Sequence[tuple[Any, str | None, int]]) -> list[WholeLoop]:
    """:func:`lane_loop` of several ``(system, configuration, steps)`` at once: the probes
    of the checks of one configuration, step and step count stepped as the lanes of one
    :class:`~archself.lanes.system.LaneSystem` (the lanes that check in the same cycle)."""
    made = [loop_probes(*check) for check in checks]
    groups: dict[tuple[str, int, int], list[int]] = {}
    for j, probes in enumerate(made):
        base = probes.probe.base
        groups.setdefault((base.configuration, base.k, checks[j][2]), []).append(j)
    out: list[Any] = [None] * len(checks)
    for (_conf, _k, steps), js in groups.items():
        for j, loop in zip(js, _stepped([made[j] for j in js], steps), strict=True):
            out[j] = loop
    return out


def _stepped(group: list[LoopProbes], steps: int) -> list[WholeLoop]:
    """The whole loops of checks at one configuration and step, their probes stepped as
    the lanes of one lane system (:func:`_probe_lanes`)."""
    lanes = _probe_lanes(group)
    for _ in range(steps):
        lanes.step()
    states = _States(lanes)
    out = []
    first = 0
    for probes in group:
        runs = range(first, first + len(probes.shifts))
        for lane in runs:
            probes.probe.raised({n: lanes.health.reason(n, lane) for n in lanes.health.why})

        def read(lane: int, n: str, probe: Any = probes.probe) -> np.ndarray:
            return probe.checked(n, states(n, lane))

        out.append(probes.assemble(runs, read))
        first += len(probes.shifts)
    return out


class _States:
    """Each lane's state of a module after the steps: one array read of every lane per
    module (:meth:`~archself.lanes.module.LaneModule.state_rows`), or lane by lane through
    the per-run bridge where the class declares no layout (or a lane's differs in size)."""

    def __init__(self, lanes: LaneSystem) -> None:
        self.lanes = lanes
        self.rows: dict[str, np.ndarray | None] = {}

    def __call__(self, n: str, lane: int) -> np.ndarray:
        mod = self.lanes.module(n)
        if n not in self.rows:
            self.rows[n] = mod.state_rows(ALL)
        rows = self.rows[n]
        if rows is None:  # the method on the class: a relay's lanes keep a ``state``
            return type(mod).state(mod, np.array([lane]))[0]
        return rows[lane]


def _probe_lanes(group: list[LoopProbes]) -> LaneSystem:
    """One lane per probe of each check, all resumed from the check's base
    (:func:`~archself.lanes.system.lane_copies`); each lane's perturbed states set through
    the lane modules."""
    lanes = LaneSystem.resume(
        [s for p in group for s in lane_copies(p.probe.base, len(p.shifts), smooth=True)],
        smooth=True,
    )
    for n in lanes.plan(lanes.configuration[0]).active:
        lanes.module(n)  # every lane loaded from the base before any state is moved in it
    moved: dict[str, tuple[list[int], list[np.ndarray]]] = {}
    lane = 0
    for probes in group:
        for shift in probes.shifts:
            for n in shift:
                at, rows = moved.setdefault(n, ([], []))
                at.append(lane)
                rows.append(probes.probe.moved(n, shift))
            lane += 1
    for n, (at, rows) in moved.items():  # one write per module (lane by lane: the bridge)
        mod = lanes.module(n)
        type(mod).set_state(mod, np.stack(rows), np.array(at))
    return lanes
