"""The MAPE-K loop of Algorithm 1, generic over any architecture file.

:class:`MapeK` is called once per ``runtime.period_s`` with the running system
(the LiveSystem contract of docs/develop.md) and performs one cycle:

1. **Monitor** (steps 1–2, :mod:`~archself.runtime.monitor`): J_obs, the global
   residual r = J_ref − J_obs (Eq. 11), the module residuals r_i (Eq. 12) and κ_i.
2. **Analyze** (steps 3–5, :mod:`~archself.runtime.influence`,
   :mod:`~archself.runtime.planner`): W of the active edges (Eq. 13), the
   influence z = (I − Wᵀ)⁻¹ r (Eq. 14) and the candidate set C (Eq. 16).
3. **Plan** (steps 6–8, :mod:`~archself.runtime.planner`): Δ, stability filter,
   dwell time, score and argmax under the constraints (Eq. 17–28).
4. **Execute** (step 9): ``system.apply_configuration(to)`` (hot swap with state
   hand-over) or ``system.set_params(module, values)``; the Knowledge
   (:mod:`~archself.runtime.knowledge`) is synchronized with the system and
   ``t_last`` recorded for architectural changes.

No adaptation happens during the first ``runtime.warmup_s`` seconds (the loop
still monitors, analyzes and logs); besides, each module's residual counts only
once its filter has settled (``runtime.min_confidence``, see
:mod:`~archself.runtime.monitor`), so a fault that starts early is acted on as
soon as the residuals that show it are trusted. After a structural action the
module it was keyed to counts as *compensated* (``runtime.isolate_compensated``):
its residual stays its own (z_i includes r_i) but is not propagated through W,
so the fault that was dealt with does not keep pulling z onto the modules
downstream; the mark is dropped when an action keyed to the module applies
again (the compensation is gone) or it becomes inactive.

Localization: besides z, every cycle estimates the local faults ê that explain the
residuals (:mod:`~archself.runtime.influence`), largest at a fault's origin where z is
largest downstream of it. ``runtime.localization`` chooses what drives the candidate
set and the planner's weight: ``fit`` (default, :class:`SourceFit`: few sources on
observed and hidden modules, modules the residuals cannot tell apart kept together
and logged as ``equivalent``; a hidden module's ê stands for its missing residual in
the planner), ``source`` (:class:`SourceEstimator`, ``max(0, (I − Wᵀ) r)`` on the
observed modules) or ``influence`` (z, the paper's Algorithm 1); the decision log
holds z and ê. The estimate uses every residual as it is (a compensated module's
residual still explains its downstream echoes).
``runtime.ablation`` switches propagation (z = ê = r), the stability filter or the
dwell time off. Every cycle
appends a :class:`~archself.runtime.knowledge.DecisionRecord` to
:attr:`MapeK.decisions`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from archself.contracts import ManagedSystem
from archself.errors import SimulationError
from archself.io.jsondata import DecisionLog, document
from archself.model.architecture import Architecture
from archself.runtime.influence import SourceEstimator, SourceFit
from archself.runtime.knowledge import DecisionRecord, Knowledge, ValueMap, learning_of, online_of
from archself.runtime.monitor import Monitor, Observation
from archself.runtime.planner import (
    HysteresisSelector,
    Planner,
    PlanState,
    ThresholdSelector,
    TopKSelector,
    selector_from_runtime,
)
from archself.runtime.stability import apply_action
from archself.runtime.strategies import Strategies

__all__ = ["MapeK"]


@dataclass(slots=True)
class _Analysis:
    """One cycle's Analyze stage over the active modules (values in ``k.active_index`` order)."""

    r_values: Any
    r_active: ValueMap
    z_active: ValueMap
    e_values: Any
    e_active: ValueMap
    drive: ValueMap  # what drives C and the planner: z or ê (``runtime.localization``)
    candidates: list[str]


class MapeK:
    """One architecture-aware MAPE-K loop (Algorithm 1).

    Parameters
    ----------
    arch : Architecture
        The architecture file's model. Everything the loop knows — modules,
        edges and weights, configurations, actions, budgets and the ``runtime``
        settings — comes from it.
    learned : OutcomeTable or path, optional
        What earlier runs learned (:mod:`~archself.runtime.knowledge`); used when
        ``runtime.learning.enabled``, which a table given here switches on.

    Attributes
    ----------
    knowledge : Knowledge
        The live architecture graph, current configuration, t_last.
    decisions : list of DecisionRecord
        One record per cycle (:meth:`log` is JSON).
    switches : list of dict
        Every architectural change: ``{t_s, from, to, action, module}``.
    updates : list of dict
        Every parameter update: ``{t_s, action, module, set}``.
    cycle : int
        Number of cycles run.

    Examples
    --------
    >>> loop = MapeK(arch)                                 # doctest: +SKIP
    >>> simulate(arch, scenario, adapt=loop)               # doctest: +SKIP
    >>> print(explain(loop.decisions))                     # doctest: +SKIP
    """

    def __init__(self, arch: Architecture, learned: Any = None) -> None:
        if not isinstance(arch, Architecture):
            raise SimulationError(f"MapeK: expected an Architecture (archself.load(path)), "
                                  f"got {type(arch).__name__}")
        self.arch = arch
        self.knowledge = Knowledge(arch)
        self.monitor = Monitor(arch, self.knowledge.names)
        self.selector = selector_from_runtime(arch.runtime)
        self.localization = arch.runtime.localization
        self.planner = Planner(arch)
        self.strategies = Strategies(arch, self.planner)  # the running one: its state
        self.learning = learning_of(arch, learned)  # runtime.learning: None when off
        if self.learning is not None:
            self.knowledge.learned = self.learning.table
        self.planner.learning = self.learning
        self.online = online_of(arch, self.knowledge, self.monitor)  # runtime.online: None off
        if self.online is not None:
            self.knowledge.online = self.online.events
        self.decisions: list[DecisionRecord] = []
        self.switches: list[dict[str, Any]] = []
        self.updates: list[dict[str, Any]] = []
        self.cycle = 0
        rt = arch.runtime
        self.warmup_s = rt.warmup_time_s
        self.propagate = rt.ablation.propagation
        self.t_start: float | None = None
        self.compensated: dict[str, str] = {}  # module -> configuration it was compensated in
        self._checked_conf: str | None = None
        self._observed = [m.residual is not None for m in arch.modules.values()]
        self._observed_array = np.array(self._observed, dtype=bool)
        self._sources_key: Any = None
        self._estimator: SourceEstimator | SourceFit | None = None
        self._equivalent: list[list[str]] = []
        self._pending: tuple[Observation, _Analysis] | None = None  # quiet's analysis
        self._zero: tuple[list[str], _Analysis] | None = None  # quiet_zeros' 0s of an active set

    # ------------------------------------------------------------------ cycle
    def __call__(self, system: ManagedSystem, observation: Any = None) -> list[dict[str, Any]]:
        """Run one MAPE-K cycle on ``system``: monitor, analyze, plan, execute.

        Parameters
        ----------
        system : LiveSystem
            The running system (docs/develop.md, "live-system contract").
        observation : Observation, optional
            This cycle's Monitor stage, made by the caller with this loop's
            :attr:`monitor` (lane batches: :func:`archself.lanes.monitor.observe_group`);
            None: the loop observes ``system`` itself.

        Returns
        -------
        list of dict
            The architectural changes made in this cycle (zero or one), each
            ``{"t_s", "from", "to", "action", "module"}``. Parameter updates are
            not switches; they are in :attr:`updates` and the decision log.
        """
        k = self.knowledge
        k.sync(system)  # the system may start in any configuration: adopt it
        t = float(system.t)
        if self.compensated and k.configuration != self._checked_conf:
            self._still_compensated(k.configuration, k.active)
        # MONITOR (Eq. 11-12)
        obs = observation if observation is not None else self.monitor.observe(system, k.active)
        # ANALYZE (Eq. 13-16), unless :meth:`quiet` made it for this observation
        pending, self._pending = self._pending, None
        cycle = pending[1] if pending is not None and pending[0] is obs else self._analyze(obs, k)
        record = self._record(t, obs, cycle)
        if record.phase == "warmup" or not (cycle.candidates or self.strategies.running):
            return []
        # PLAN (Eq. 17-28)
        action, ev = self._plan(system, t, obs, cycle, record)
        if action is None or ev is None:
            return []
        # EXECUTE (step 9)
        return self._execute(system, t, action, ev, cycle, record)

    def _analyze(self, obs: Observation, k: Knowledge) -> _Analysis:
        """Steps 3-5: r, z and ê of the active modules and the candidate set C."""
        r_values = obs.r[k.active_index]
        r_active = ValueMap(k.active_names, k.active_pos, r_values)
        self._equivalent = []
        if obs.r.any() or not self.propagate:
            z_values = self._influence(obs.r, k)[k.active_index]
            z_active = ValueMap(k.active_names, k.active_pos, z_values)
            e_values = self._sources(obs.r, k)[k.active_index]
            e_active = ValueMap(k.active_names, k.active_pos, e_values)
        else:  # most cycles: nothing to propagate or explain, z = ê = r = 0
            z_values = e_values = r_values
            z_active = e_active = r_active
        if self.localization == "influence":
            drive, drive_values = z_active, z_values
        else:
            drive, drive_values = e_active, e_values
        candidates = self.selector.select(drive, drive_values)
        return _Analysis(r_values, r_active, z_active, e_values, e_active, drive, candidates)

    def _record(self, t: float, obs: Observation, cycle: _Analysis) -> DecisionRecord:
        """This cycle's decision record (warm-up or not), appended to the log and learned from."""
        kappa = {n: s.to_dict() for n, s in obs.kappa.findings()}
        return self._log(t, obs.j_obs, obs.j_ref, obs.r_global, cycle, kappa, obs)

    def _log(self, t: float, j_obs: float, j_ref: float, r_global: float, cycle: _Analysis,
             kappa: dict[str, Any], obs: Observation | None) -> DecisionRecord:
        """:meth:`_record` from the numbers it reads (``obs``: None only with ``online`` off)."""
        if self.t_start is None:
            self.t_start = t
        record = DecisionRecord(
            cycle=self.cycle,
            t=t,
            configuration=self.knowledge.configuration,
            phase="warmup" if self._warm(t) else "adapt",
            j_obs=j_obs,
            j_ref=j_ref,
            r_global=r_global,
            r=cycle.r_active,
            z=cycle.z_active,
            candidates=list(cycle.candidates),
            selector=self.selector.describe(),
            source=cycle.e_active,
            localization=self.localization,
            equivalent=self._equivalent,
            kappa=kappa,
            compensated=sorted(self.compensated) if self.compensated else [],
        )
        self.decisions.append(record)
        self.cycle += 1
        if self.learning is not None:
            self.learning.cycle(record)
        if self.online is not None and self.online.cycle(record, obs):
            self._sources_key = None  # W changed: the source fit is rebuilt
        return record

    def _warm(self, t: float) -> bool:
        """Whether a cycle at ``t`` is in warm-up (the first cycle starts it)."""
        return t - (t if self.t_start is None else self.t_start) < self.warmup_s - 1e-9

    def quiet(self, system: ManagedSystem, observation: Observation) -> bool:
        """Record a cycle without a candidate as :meth:`__call__` would; False: not one.

        A cycle whose selector selects nothing (or in warm-up) only appends its decision
        record (the same :meth:`_record`); no Plan, no whole-loop check. It is made here
        when nothing else is pending — the system in the configuration and active set
        the Knowledge holds, its compensation checked there, no strategy running,
        propagation on. With every residual 0, z = ê = r = 0 and no Analyze is needed
        where the selector selects nothing on zeros (a threshold τ > 0, top-k,
        hysteresis without members); with a residual the cycle's Analyze is made here.
        Otherwise nothing is recorded and False returned: the caller runs the cycle,
        and a call of :meth:`__call__` with the same ``observation`` reuses the Analyze
        made here (the selector is asked once a cycle). Lane batches call it for the
        lanes with a residual (:func:`archself.lanes.run.simulate_lanes`; the lanes
        without one go to :meth:`quiet_zeros`): only lanes with a candidate go on to
        the per-lane call.
        """
        k = self.knowledge
        self._pending = None
        if not self._settled(system.configuration, system.active):
            return False
        t = float(system.t)
        if observation.r.any():
            cycle = self._analyze(observation, k)
            if cycle.candidates and not self._warm(t):
                self._pending = (observation, cycle)
                return False
        elif self._none_on_zeros():
            r_values = observation.r[k.active_index]
            r = ValueMap(k.active_names, k.active_pos, r_values)
            self._equivalent = []
            cycle = _Analysis(r_values, r, r, r_values, r, r, [])
        else:
            return False
        self._record(t, observation, cycle)
        return True

    def quiet_zeros(self, configuration: str, active: Any, t: float, j_obs: float,
                    j_ref: float) -> bool:
        """:meth:`quiet` of an observation with every r_i = +0 and no κ finding, without one.

        What lane batches call for such a lane (most lanes, most cycles): the record is
        the one :meth:`quiet` appends — r = z = ê = 0 (one read-only array and map per
        active set, shared by the records), κ empty, no candidate — from the group's
        numbers alone. ``configuration`` and ``active`` are the system's; the loop must
        have nothing pending as :meth:`quiet` requires, and ``runtime.online`` off (it
        reads the observation's signals). False: nothing recorded, the caller makes the
        lane's :class:`Observation` and goes on as without this call.
        """
        self._pending = None
        if self.online is not None or not self._settled(configuration, active) or (
                not self._none_on_zeros()):
            return False
        k = self.knowledge
        if self._zero is None or self._zero[0] is not k.active_names:
            values = np.zeros(len(k.active_names))
            values.flags.writeable = False
            r = ValueMap(k.active_names, k.active_pos, values)
            self._zero = (k.active_names, _Analysis(values, r, r, values, r, r, []))
        self._equivalent = []
        self._log(t, j_obs, j_ref, j_ref - j_obs, self._zero[1], {}, None)
        return True

    def _settled(self, configuration: str, active: Any) -> bool:
        """Whether a cycle may be recorded by :meth:`quiet`: the system in the Knowledge's
        configuration and active set, its compensation checked there, no strategy running,
        propagation on."""
        k = self.knowledge
        return not (
            not self.propagate or self.strategies.running is not None
            or configuration != k.configuration or active != k.active
            or (self.compensated and k.configuration != self._checked_conf)
        )

    def _none_on_zeros(self) -> bool:
        """Whether the selector selects nothing when every value is 0 (without asking it):
        a threshold τ > 0, top-k, hysteresis without members."""
        sel = self.selector
        return (type(sel) is TopKSelector or (type(sel) is ThresholdSelector and sel.tau > 0)
                or (type(sel) is HysteresisSelector and sel.on > 0 and not sel.members))

    def _plan(self, system: ManagedSystem, t: float, obs: Observation, cycle: _Analysis,
              record: DecisionRecord) -> tuple[Any, Any]:
        """Steps 6-8: the running strategy's tactic or the planner's argmax (and the echo's)."""
        k = self.knowledge
        r_active = cycle.r_active
        if self.localization == "fit" and self.propagate:
            # a hidden module has no residual of its own: the fit's estimate stands for it
            # (an action's sensitivity Δ is proportional to the module's residual)
            r_plan = np.where(self._observed_array[k.active_index], cycle.r_values,
                              cycle.e_values)
            r_active = ValueMap(k.active_names, k.active_pos, r_plan)
        state = PlanState(
            t=t,
            configuration=k.configuration,
            active=k.active,
            edges=k.edges,
            z=cycle.drive,
            r=r_active,
            kappa=obs.kappa,
            params=k.params,
            t_last=k.t_last,
        )
        if self.strategies.wants(cycle.candidates, state, record):  # a strategy runs: its tactic
            evaluations, action, ev = self.strategies.cycle(system, state, record)
        else:
            evaluations, action, ev = self.planner.plan(system, state, cycle.candidates)
            if action is None and self.localization == "fit" and self.propagate:
                evaluations, action, ev = self._echo_plan(system, state, evaluations, record)
        record.evaluations = evaluations
        return action, ev

    def _execute(self, system: ManagedSystem, t: float, action: Any, ev: Any,
                 cycle: _Analysis, record: DecisionRecord) -> list[dict[str, Any]]:
        """Step 9: apply ``action``, synchronize the Knowledge, log the change."""
        k = self.knowledge
        before = k.configuration
        try:
            apply_action(system, action)
        except Exception as exc:  # noqa: BLE001 - a failed execution is logged, not fatal
            ev.rejected, ev.detail = "unavailable", f"execution failed: {exc}"
            record.note = f"execution of {action.id} failed: {exc}"
            k.sync(system)
            return []
        k.sync(system)
        if self.learning is not None:
            self.learning.started(action, before, k.configuration, t, ev.delta)
        z_chosen = (ev.z if self.localization == "influence"
                    else abs(cycle.z_active.get(action.module, 0)))
        chosen: dict[str, Any] = {
            "action": action.id,
            "kind": action.kind,
            "module": action.module,
            "z": z_chosen,
            "source": abs(cycle.e_active.get(action.module, 0.0)),
            "delta": ev.delta,
            "score": ev.score,
        }
        if action.kind == "parameter_update":
            values = dict(action.set or {})
            k.record_parameters(action.module, values)
            chosen["set"] = values
            self.updates.append(
                {"t_s": t, "action": action.id, "module": action.module, "set": values}
            )
            record.chosen = chosen
            return []
        after = k.configuration
        k.record_structural(t)
        if self.arch.runtime.isolate_compensated and action.module in k.active:
            self.compensated[action.module] = after
            self._checked_conf = after
        chosen.update({"from": before, "to": after})
        record.chosen = chosen
        switch = {
            "t_s": t,
            "from": before,
            "to": after,
            "action": action.id,
            "module": action.module,
        }
        self.switches.append(switch)
        return [dict(switch)]

    def _influence(self, r: Any, k: Knowledge) -> Any:
        """z of Eq. 14; compensated modules' residuals stay their own, not propagated."""
        if not self.propagate:
            return r
        if not self.compensated:
            return k.influence(r)
        own = [k.index[m] for m in self.compensated]
        spread = r.copy()
        spread[own] = 0.0
        z = k.influence(spread)
        z[own] += r[own]
        return z

    def _sources(self, r: Any, k: Knowledge) -> Any:
        """ê of the active edges, the estimator built once per edge set.

        :class:`SourceFit` (``localization: fit`` or ``influence``, where it is logged
        beside z), :class:`SourceEstimator` for ``source``. The fit's equivalence
        classes of more than one module go to the decision log (``equivalent``).
        """
        if not self.propagate:
            return r
        if self._estimator is None or (
            self._sources_key is not k.edges and self._sources_key != k.edges
        ):
            kind = SourceEstimator if self.localization == "source" else SourceFit
            self._estimator = kind(k.weight_matrix(), self._observed)
            self._sources_key = k.edges
        e = self._estimator.estimate(r)
        if isinstance(self._estimator, SourceFit):
            names = k.names
            self._equivalent = [
                [names[j] for j in c] for c in self._estimator.classes if len(c) > 1
            ]
        return e

    def _echo_plan(
        self, system: ManagedSystem, state: PlanState, evaluations: list, record: DecisionRecord
    ) -> tuple[list, Any, Any]:
        """While a source's structural action waits out the dwell time: its echo downstream.

        The fit acts at the source, so a module whose residual is the source's echo is no
        candidate. While the source's action is rejected for ``dwell``, the modules
        outside its class are planned on with the paper's z of the residuals the source
        explains (:attr:`SourceFit.shares`): a downstream compensation (a parameter
        update; structural actions wait too) is weighed as z would weigh it if the
        waiting source's residuals were all there was.
        """
        fit, k = self._estimator, self.knowledge
        waiting = {ev.module for ev in evaluations if ev.rejected == "dwell"}
        if not waiting or not isinstance(fit, SourceFit):
            return evaluations, None, None
        echo = np.zeros(len(k.names))
        for members, share in zip(fit.classes, fit.shares, strict=True):
            if waiting.intersection(k.names[j] for j in members):
                echo += fit.influence(share)
                echo[members] = 0.0
        values = echo[k.active_index]
        drive = ValueMap(k.active_names, k.active_pos, values)
        more = self.selector.entering(drive, values)
        if not more:
            return evaluations, None, None
        extra, action, ev = self.planner.plan(system, replace(state, z=drive), more)
        if action is not None:
            record.note = (f"{', '.join(sorted(waiting))} waits out the dwell time: "
                           f"{action.id} on its echo at {action.module}")
        return evaluations + extra, action, ev

    def _still_compensated(self, configuration: str, active: frozenset[str]) -> None:
        """Drop the modules whose compensation is gone in ``configuration``.

        Gone: the module is inactive, or a structural action keyed to it applies
        here (``applies_in`` unset or listing it, leading elsewhere), i.e. the
        loop could compensate it again.
        """
        self._checked_conf = configuration
        for name in list(self.compensated):
            if name not in active:
                del self.compensated[name]
                continue
            for _, a in self.planner.by_module.get(name, ()):
                if a.kind == "parameter_update" or a.to == configuration:
                    continue
                if a.applies_in is None or configuration in a.applies_in:
                    del self.compensated[name]
                    break

    # ------------------------------------------------------------------ output
    def saved_knowledge(self) -> dict[str, Any] | None:
        """What the loop learned, for the trace's ``meta.knowledge``; None when nothing is.

        ``learned``: the outcome table (``runtime.learning``; ``--knowledge TRACE`` reads
        it back) and ``outcomes``, every measured outcome; ``online``: every update of W and
        the bands and what moved (``runtime.online``).
        """
        out: dict[str, Any] = {}
        if self.learning is not None:
            out["learned"] = self.learning.table.to_dict()
            out["outcomes"] = list(self.learning.events)
        if self.online is not None:
            out["online"] = self.online.to_dict()
        return out or None

    # ------------------------------------------------------------------ output
    def log(self) -> list[dict[str, Any]]:
        """The decision log as JSON data (:data:`~archself.io.jsondata.DecisionLog`)."""

        return list(document(DecisionLog, self.decisions, "decisions"))
