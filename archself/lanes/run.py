"""N runs of one scenario as one lane-batched simulation, fixed or adaptive.

:func:`simulate_lanes` is :func:`archself.sim.run.simulate` for many seeds (and
sweep points) at once: it compiles one per-run system per lane, steps them
together in a :class:`~archself.lanes.system.LaneSystem`, records the same series
and returns the same :class:`~archself.sim.result.RunResult` per lane. With
``adapt=True`` every lane has its own MAPE-K loop, called every ``runtime.period_s``
with the lane's :class:`~archself.lanes.view.LaneView`: the same decisions, the same
switches, the lane moving between configuration groups.

Examples
--------
>>> from archself.model.loader import load_architecture
>>> from archself.resources import data_dir
>>> from archself.sim.run import simulate
>>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
>>> lanes = simulate_lanes(arch, "nominal", [1, 2], configuration="a1")
>>> one = simulate(arch, "nominal", seed=2, configuration="a1")
>>> abs(lanes[1].metrics["max_error"] - one.metrics["max_error"]) < 1e-9
True
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from archself.errors import SimulationError, unknown
from archself.lanes.module import ALL
from archself.lanes.monitor import observe_group
from archself.lanes.system import LaneSystem
from archself.lanes.view import LaneView, lane_loop, lane_loops
from archself.model.architecture import Architecture
from archself.model.loader import gc_paused
from archself.runtime.mapek import MapeK
from archself.runtime.monitor import Monitor
from archself.sim.result import RunResult
from archself.sim.run import Recording, fault_spans, note_faults
from archself.system.live import compile_system

__all__ = ["simulate_lanes"]


def _norms(actual: Any, reference: Any, comps: list[int], n: int) -> np.ndarray:
    """J per lane: ``sqrt(Σ d²)`` in component order, as :func:`objective_norm` sums it."""
    if actual is None or reference is None or type(actual) is list or type(reference) is list:
        return np.full(n, math.nan)
    a = actual if actual.ndim == 2 else actual[:, None]
    r = reference if reference.ndim == 2 else reference[:, None]
    s2 = np.zeros(n)
    for c in comps:
        if not (-a.shape[1] <= c < a.shape[1] and -r.shape[1] <= c < r.shape[1]):
            return np.full(n, math.nan)
        d = a[:, c] - r[:, c]
        s2 = s2 + d * d
    return np.sqrt(s2)


def simulate_lanes(
    arch: Architecture | Sequence[Architecture],
    scenario: str,
    seeds: Sequence[int],
    *,
    configuration: str | None = None,
    adapt: bool | Callable[[Architecture], Any] = False,
) -> list[RunResult]:
    """Simulate ``scenario`` for every seed as lanes, fixed or with a MAPE-K loop per lane.

    Parameters
    ----------
    arch : Architecture or sequence of Architecture
        The architecture, or one per lane (sweep points: the same structure, other
        values).
    scenario : str
        A scenario every architecture has.
    seeds : sequence of int
        One seed per lane.
    configuration : str, optional
        The configuration to start in (default: the file's initial one).
    adapt : bool or callable
        True: run each lane with its own :class:`~archself.runtime.MapeK` (the
        ``adapt=MapeK(arch)`` of :func:`~archself.sim.run.simulate`); a callable:
        ``adapt(arch)`` makes each lane's loop (any ``adapt`` object of
        ``simulate``: called every ``runtime.period_s`` with the lane's
        :class:`~archself.lanes.view.LaneView`; its ``updates`` and ``decisions``
        lists, if it has them, are read as MapeK's).

    Returns
    -------
    list of RunResult
        One per lane, in order: what :func:`archself.sim.run.simulate` gives for
        that architecture and seed (errors within 1e-9, the same switches and
        decision log).

    Raises
    ------
    SimulationError
        Unknown scenario, lanes of different structure or duration.
    CompileError
        The configuration cannot be built.
    """
    plan = _plan(arch, scenario, seeds, configuration, adapt)
    with gc_paused():  # no reference cycles are made; the decision logs grow (see _step)
        switches, faults = _step(plan)
    loops = plan.loops
    out = []
    for lane, (a, seed) in enumerate(zip(plan.archs, seeds, strict=True)):
        res = plan.rec.result(
            lane, a, seed, "adaptive" if adapt else "fixed", plan.start,
            plan.lanes.configuration[lane], switches[lane],
            list(getattr(loops[lane], "decisions", None) or []) if loops is not None else [],
        )
        res.faults = fault_spans(faults[lane])
        out.append(res)
    return out


@dataclass
class _Lanes:
    """What :func:`simulate_lanes` plans: the lanes, their loops, the series."""

    archs: list[Architecture]
    start: str
    lanes: LaneSystem
    rec: Recording
    loops: list[Any] | None = None
    views: list[Any] | None = None
    monitors: list[Any] | None = None
    quiet: bool = False  # the loops are MapeK's own: a cycle without residual is MapeK.quiet


def _plan(
    arch: Architecture | Sequence[Architecture],
    scenario: str,
    seeds: Sequence[int],
    configuration: str | None,
    adapt: bool | Callable[[Architecture], Any],
) -> _Lanes:
    """Check the lanes, compile one system per lane, make each lane's loop.

    Raises
    ------
    SimulationError, CompileError
        As :func:`simulate_lanes`.
    """
    archs = [arch] * len(seeds) if isinstance(arch, Architecture) else list(arch)
    if len(archs) != len(seeds) or not len(seeds):
        raise SimulationError("simulate_lanes needs one seed per lane (and one architecture)")
    first = archs[0]
    sc = first.scenarios.get(scenario)
    if sc is None:
        raise SimulationError(unknown("scenario", scenario, first.scenarios))
    start = configuration or first.initial_configuration()
    systems = []
    for a, seed in zip(archs, seeds, strict=True):
        s = a.scenarios.get(scenario)
        if s is None or s.duration_s != sc.duration_s:
            raise SimulationError(f"lanes must share scenario {scenario!r} and its duration")
        systems.append(compile_system(a, start, seed=int(seed), scenario=s))
    lanes = LaneSystem(systems)
    plan = _Lanes(archs, start, lanes, Recording.of(first, scenario, lanes.n))
    if adapt:

        make = MapeK if adapt is True else adapt
        plan.loops = loops = [make(a) for a in archs]
        plan.views = [LaneView(lanes, i) for i in range(lanes.n)]
        # loops observing with the runtime's Monitor take the lanes' bulk Monitor stage
        if all(isinstance(getattr(lp, "monitor", None), Monitor) for lp in loops):
            plan.monitors = [lp.monitor for lp in loops]
        plan.quiet = all(type(lp) is MapeK for lp in loops)  # a subclass may do more a cycle
    return plan


def _layouts(plan: _Lanes) -> Callable[[str], tuple[list, list]]:
    """``layout(conf)``: the recorded sources and residual modules of ``conf`` (found
    once per configuration; the per-run driver looks them up on a change)."""
    per_conf: dict[str, tuple[list, list]] = {}
    lanes, rec = plan.lanes, plan.rec

    def layout(conf: str) -> tuple[list, list]:
        got = per_conf.get(conf)
        if got is None:
            active = lanes.plan(conf)
            pool = lanes.systems[0]
            srcs = []
            for key, sig in rec.record:
                src = next((m for m in active.active if sig in pool._module(m).outputs), None)
                if src is not None:
                    srcs.append((key, src, sig))
            res = [(j, m, s) for j, (m, s) in enumerate(rec.res_mods) if m in active.active_set]
            got = per_conf[conf] = (srcs, res)
        return got

    return layout


def _step(plan: _Lanes) -> tuple[list[list[dict[str, Any]]], list[dict[tuple[str, str], Any]]]:
    """Step the lanes through the scenario, record every step, call each lane's loop
    every ``runtime.period_s``; the switches of each lane and its module faults (as
    :func:`~archself.sim.run.note_faults` counts them; looked at only in the steps where
    some lane has a module down).

    The caller pauses the cyclic garbage collector: stepping and the loops make no
    reference cycles (a 20-lane adaptive run left none to collect), but the lanes'
    decision logs grow by a record per lane and cycle, and the collector walked them
    again and again (14 % of 100 adaptive imu_drift lanes' CPU, 14.2 -> 12.4 s).
    """
    lanes, rec = plan.lanes, plan.rec
    N, rt = lanes.n, plan.archs[0].runtime
    per = max(1, int(round(rt.period_s / rec.dt)))
    act_mod, act_sig = rt.objective.actual.rsplit(".", 1)
    ref_mod, ref_sig = rt.objective.reference.rsplit(".", 1)
    switches: list[list[dict[str, Any]]] = [[] for _ in range(N)]
    layout = _layouts(plan)
    signal = lanes.signal
    faults: list[dict[tuple[str, str], Any]] = [{} for _ in range(N)]
    health = lanes.health
    for i in range(rec.n):
        lanes.step()
        rec.t[i] = lanes.t
        if health.any_down():
            _note_lane_faults(faults, lanes)
        a = signal(act_mod, act_sig)
        r = signal(ref_mod, ref_sig)
        rec.J[i] = _norms(a, r, rec.comps, N)
        rec.put_lanes("reference", i, r, ALL)
        rec.put_lanes("actual", i, a, ALL)
        for conf, idx in lanes.groups.items():
            sel = ALL if len(idx) == N else idx
            rec.conf[i, sel] = rec.conf_index.get(conf, -1)
            srcs, res_idx = layout(conf)
            for key, src, sig in srcs:
                rec.put_lanes(key, i, signal(src, sig), sel)
            for j, m, s in res_idx:
                v = lanes.signal_arrays(m).get(s)
                if v is not None:
                    rec.res[i, sel, j] = v[sel]
        if plan.loops is not None and (i + 1) % per == 0:
            _adapt(plan, rec.J[i], switches)
    return switches, faults


def _note_lane_faults(faults: list[dict[tuple[str, str], Any]], lanes: LaneSystem) -> None:
    """Count this step's unavailable modules of every lane into ``faults`` (one per lane),
    as the per-run step counts its system's ``unavailable``."""
    down: dict[int, dict[str, str]] = {}
    for name, why in lanes.health.why.items():
        for lane, reason in why.items():
            down.setdefault(lane, {})[name] = reason
    for lane, unavailable in down.items():
        note_faults(faults[lane], lanes.t, lanes.active_set(lane), unavailable)


def _adapt(plan: _Lanes, J: np.ndarray, switches: list[list[dict[str, Any]]]) -> None:
    """One cycle of every lane's loop: the Monitor stage in bulk where it can, each loop
    called with its lane's view; the switches appended to ``switches``.

    A lane whose residuals are all 0 (most lanes, most cycles) is recorded from its
    group's numbers (:func:`_quiet`) and is done. A lane's cycle with a residual but
    without a candidate is recorded by :meth:`MapeK.quiet` (its Analyze made there). A
    lane with a candidate (or that observes on its own) is called in a
    :class:`_Worker`, which pauses at the lane's whole-loop check: the checks of the
    cycle are then made together (:func:`~archself.lanes.view.lane_loops`) and the
    paused calls go on, in lane order. Each call touches its own lane only (its loop,
    its per-run system, its streams' pins); the lanes move after every call has ended
    (:meth:`LaneView.done`, in lane order), so the decisions are those of calls one
    after the other.
    """

    lanes, loops, views = plan.lanes, plan.loops, plan.views
    assert loops is not None and views is not None
    lanes.objective = J
    observed: dict[int, Any] = {}
    rest = np.ones(lanes.n, dtype=bool)  # the lanes not recorded by _quiet
    if plan.monitors is not None:
        for conf, idx in lanes.groups.items():
            group = observe_group(plan.monitors, lanes, idx, J)
            if group is None:
                continue
            done = _quiet(loops, conf, lanes.active_set(int(idx[0])), group) if plan.quiet else ()
            for row, lane in enumerate(group.lanes):
                if lane not in done:
                    observed[lane] = group.observation(row)
            rest[list(done)] = False
    busy = np.flatnonzero(rest).tolist()
    outs: dict[int, Any] = {}
    paused: list[tuple[int, _Worker]] = []
    for lane in busy:
        obs = observed.get(lane)
        if obs is not None and plan.quiet and loops[lane].quiet(views[lane], obs):
            continue  # no candidate: recorded, nothing to plan
        if obs is not None and not obs.r.any():  # nothing to plan from: no check to wait for
            outs[lane] = loops[lane](views[lane], observation=obs)
            continue
        worker = _Worker(loops[lane], views[lane], obs)
        if worker.resume():
            paused.append((lane, worker))
        outs[lane] = worker
    while paused:
        answers = _answers([w.request for _, w in paused])
        paused = [(lane, w) for (lane, w), a in zip(paused, answers, strict=True) if w.resume(a)]
    for lane in busy:  # a lane recorded by _quiet never materializes: nothing to be done
        out = outs.get(lane)
        if isinstance(out, _Worker):
            out = out.result()
        views[lane].done(len(getattr(loops[lane], "updates", ())))
        if out:
            switches[lane].extend(dict(s) for s in out)


def _quiet(loops: list[Any], conf: str, active: frozenset[str], group: Any) -> set[int]:
    """The lanes of ``group`` (one configuration) whose cycle
    :meth:`MapeK.quiet_zeros` records: every r_i 0, no κ finding, nothing pending."""
    t, j_ref, j_obs, lanes = group.t, group.j_ref, group.j_obs, group.lanes
    return {
        lanes[row] for row in np.flatnonzero(group.zero).tolist()
        if loops[lanes[row]].quiet_zeros(conf, active, t, j_obs[row], j_ref[row])
    }


def _answers(requests: list[Any]) -> list[Any]:
    """The whole loops of the paused calls' checks, made together; a check that fails
    alone gets its exception (raised in its call, as the check itself would raise)."""

    try:
        return lane_loops(requests)
    except Exception:  # noqa: BLE001 - find which check fails: each made alone
        out: list[Any] = []
        for request in requests:
            try:
                out.append(lane_loop(*request))
            except Exception as exc:  # noqa: BLE001 - handed to the call that asked
                out.append(exc)
        return out


class _Worker(threading.Thread):
    """A lane's loop call in a thread that pauses at the lane's whole-loop check.

    Only one of the threads and the caller runs at a time: :meth:`resume` runs the call
    until it ends or asks for a whole loop (:meth:`ask`, from the lane's view), and waits.
    """

    def __init__(self, loop: Any, view: Any, observation: Any) -> None:
        super().__init__(daemon=True)
        self.loop, self.view, self.observation = loop, view, observation
        self.request: Any = None
        self._answer: Any = None
        self._out: Any = None
        self._error: BaseException | None = None
        self._go, self._back = threading.Semaphore(0), threading.Semaphore(0)

    def run(self) -> None:
        self.view.worker = self
        try:
            obs, loop = self.observation, self.loop
            self._out = loop(self.view) if obs is None else loop(self.view, observation=obs)
        except BaseException as exc:  # noqa: BLE001 - raised in the caller (result)
            self._error = exc
        finally:
            self.view.worker = None
            self.request = None
            self._back.release()

    def ask(self, request: Any) -> Any:
        """In the call: the whole loop of ``request`` (``(system, configuration, steps)``)."""
        self.request = request
        self._back.release()
        self._go.acquire()
        if isinstance(self._answer, Exception):
            raise self._answer
        return self._answer

    def resume(self, answer: Any = None) -> bool:
        """Run the call (on with ``answer``) until it ends or asks; whether it asks."""
        self._answer = answer
        if self.ident is None:
            self.start()
        else:
            self._go.release()
        self._back.acquire()
        return self.request is not None

    def result(self) -> Any:
        """What the call returned (its exception raised here)."""
        self.join()
        if self._error is not None:
            raise self._error
        return self._out
