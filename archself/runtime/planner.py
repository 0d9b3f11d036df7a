"""Plan stage of Algorithm 1: admissible actions, Δ, stability, dwell, score, argmax.

For the state ``s = (M, Γ, z, r, κ)`` (Eq. 17, :class:`PlanState`) and each
candidate module ``m_i`` (Eq. 16), every declared action with ``module == m_i``
is evaluated in this order (the first failing check is logged as the rejection
reason; cheap checks come before the costly ones):

1. *applicable* — ``applies_in`` is unset or contains the current configuration;
   a structural action leads somewhere else (``to`` ≠ current); a parameter update
   targets an active module (``not applicable``) and changes a value (``no change``);
2. *available* — the target configuration does not rely on an unavailable module
   (κ; an action whose modules are unavailable is not admissible, §4.2). When the
   system reports ``dependencies(to)`` (module -> modules it cannot run without:
   providers of required inputs, ``constraints.requires``), a target is rejected
   if one of its modules depends on an unavailable one; an unavailable module
   nothing depends on (a dead sensor used only for monitoring) does not block it.
   Without that information every module of the target must be available;
3. *constraints* C(a, θ, e) ≤ 0 (Eq. 27) of the resulting architecture: each
   module's ``requires``/``excludes`` (``constraint``) and each budget
   ``Σ_{m in target} resources[resource] ≤ max`` (``budget``) — these depend on
   the target's module set only and are cached per set; then the operating
   ``limits`` (``limit``), evaluated every time: on θ, a parameter update whose new
   value breaks the module's ``max_<p>``/``min_<p>`` or leaves the range its type
   declares (``Param(min=, max=)``: validate refuses such a file, but an architecture
   built in Python or edited by a sweep may hold one); on e, an action a module's
   ``blocks`` names (or, with ``blocks: all``, any action whose target keeps that
   module active) while the Monitor measures one of its limits violated (κ);
4. *dwell time* — a structural change only if ``t − t_last ≥ T_min`` (Eq. 28);
5. *improvement* Δ_k (Eq. 18) by the method the action declares, and the score
   ``|z_i|·Δ_k − λ·Cost(a_k)`` (Eq. 25); a score ≤ 0 is ``no improvement``. With
   ``runtime.risk``, a rollout's Δ is the rule's value over K noise draws
   (:mod:`archself.runtime.risk`); with ``runtime.learning``, Δ is scaled by what the
   action did in this context before, and an action whose last outcome here failed
   is ``held back`` (:mod:`archself.runtime.learning`);
6. *stability* (Eq. 21 or Eq. 24, :mod:`archself.runtime.stability`): ``unstable``.

The chosen action is the argmax of the score over the survivors (Eq. 26), ties
broken by lower cost, then by declaration order. Nothing is chosen when no
survivor scores above 0.

Improvement estimates Δ (positive = better):

- ``sensitivity``: ``Δ = −Δθ·|r_i|`` with Δθ (``delta_theta``) a fraction of the
  module's current deviation (Eq. 18 with ``r_i = (∂J/∂θ_i)·δθ_i``);
- ``rollout``: ``Δ = mean J(no action) − mean J(action)`` over ``horizon_s`` on two
  snapshots of the running system;
- ``table``: ``values[m_i]`` (or ``default``).

``z_i`` and ``r_i`` enter as magnitudes: their sign only reflects the sign of a
declared sensitivity.

The constraints are in :mod:`archself.runtime.constraints`, the Δ estimates in
:mod:`archself.runtime.improvement`; their names are re-exported here.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from archself.contracts import ManagedSystem
from archself.model.architecture import Action, Architecture
from archself.runtime.constraints import (
    budget_violations,
    constraint_violations,
    declared_ranges,
)
from archself.runtime.decisions import ActionEvaluation
from archself.runtime.improvement import estimate_improvement, rollout_improvement
from archself.runtime.paths import Detours
from archself.runtime.risk import RiskRanking
from archself.runtime.stability import StabilityVerdict, check_action_stability
from archself.runtime.status import StatusMap, is_limit_violation
from archself.runtime.utility import Utility

__all__ = [
    "PlanState",
    "Planner",
    "budget_violations",
    "declared_ranges",
    "constraint_violations",
    "estimate_improvement",
    "rollout_improvement",
]


@dataclass
class PlanState:
    """The state s = (M, Γ, z, r, κ) of Eq. 17 plus what the planner needs to act.

    Attributes
    ----------
    t : float
        Current time.
    configuration : str
        Current configuration (M and Γ follow from it).
    active : frozenset of str
        M: active modules.
    edges : frozenset
        Γ: active edges (source, target, carries).
    z, r : dict
        Influence and local residual per module.
    kappa : StatusMap
        Module status κ_i.
    params : dict
        Current parameter values per module.
    t_last : float
        Time of the last architectural change.
    """

    t: float
    configuration: str
    active: frozenset[str]
    edges: frozenset
    z: Mapping[str, float]
    r: Mapping[str, float]
    kappa: StatusMap
    params: Mapping[str, Mapping[str, Any]]
    t_last: float


class Planner:
    """Plan stage: evaluates the candidates' actions and picks the best admissible one.

    Parameters
    ----------
    arch : Architecture
        Reads ``actions``, ``configurations``, ``constraints`` and ``runtime``.
    """

    def __init__(self, arch: Architecture) -> None:
        self.arch = arch
        self.by_module: dict[str, list[tuple[int, Action]]] = {}
        for k, a in enumerate(arch.actions):
            self.by_module.setdefault(a.module, []).append((k, a))
        # the configurations each action applies in, and the rejection detail elsewhere
        self._applies: dict[str, tuple[frozenset[str], str]] = {
            a.id: (frozenset(a.applies_in), f"only in {', '.join(a.applies_in)}")
            for a in arch.actions
            if a.applies_in is not None
        }
        rt = arch.runtime
        self.cost_weight = rt.cost_weight
        self.dwell_s = rt.dwell_s if rt.ablation.dwell else 0.0
        self.stability_on = rt.ablation.stability
        self.margin = rt.stability.margin
        self.alpha = rt.stability.lyapunov_alpha
        self.horizon_steps = rt.stability.horizon_steps
        self.loop_steps = max(1, round(float(rt.stability.linearize_s) / float(rt.step_s)))
        self.marginal = rt.stability.marginal
        acceptable = rt.objective.acceptable
        self.v_floor = acceptable**2 if acceptable > 0 else 1e-6
        self._deps: dict[str, Mapping[str, Iterable[str]] | None] = {}
        # C(a) of a module set depends on the file only: computed once per set
        self._static: dict[tuple[str, ...], tuple[str | None, str]] = {}
        # modules whose measured limits block actions: name -> action ids, or "all"
        self._blocking: dict[str, frozenset[str] | str] = {
            n: ("all" if m.constraints.blocks == "all" else frozenset(m.constraints.blocks))
            for n, m in arch.modules.items()
            if m.constraints.limits and m.constraints.blocks
        }
        # the modules of every configuration, the targets of the structural actions
        self._conf_modules = {c: tuple(conf.modules) for c, conf in arch.configurations.items()}
        # θ: the range each parameter an update sets has by its module type's declaration
        self._declared = declared_ranges(arch)
        self._constrained = frozenset(
            n for n, m in arch.modules.items() if m.constraints.requires or m.constraints.excludes
        )
        self.detours = Detours(arch)  # synthesized switches around an unavailable target
        self.utility = Utility(arch)  # quality attributes: U(C) under the preferences
        self.learning: Any = None  # runtime.learning (set by MapeK): review() per action
        self.risk = RiskRanking(rt.risk) if rt.risk.draws > 1 or rt.risk.rule != "mean" else None

    def dependencies(
        self, system: ManagedSystem, configuration: str
    ) -> Mapping[str, Iterable[str]] | None:
        """``system.dependencies(configuration)``, cached (None if the system has none)."""
        if configuration not in self._deps:
            fn = getattr(system, "dependencies", None)
            try:
                self._deps[configuration] = fn(configuration) if fn is not None else None
            except Exception:  # noqa: BLE001 - fall back to the strict rule
                self._deps[configuration] = None
        return self._deps[configuration]

    # ------------------------------------------------------------------ checks
    def _admissible(
        self, a: Action, s: PlanState, system: ManagedSystem
    ) -> tuple[str | None, str, tuple[str, ...]]:
        """(rejection, detail, target modules) of the cheap checks 1–4.

        ``system`` gives the target configuration's dependency map (module ->
        modules it needs, :meth:`dependencies`), asked for only when a target
        module is unavailable; when it has none the strict rule holds: every
        target module must be available.
        """
        applies = self._applies.get(a.id)
        if applies is not None and s.configuration not in applies[0]:
            return "not applicable", applies[1], ()
        if a.kind == "parameter_update":
            if a.module not in s.active:
                return "not applicable", f"{a.module} is not active", ()
            current = s.params.get(a.module, {})
            if all(current.get(k) == v for k, v in (a.set or {}).items()):
                return "no change", "parameters already set", ()
            target = tuple(sorted(s.active))
        else:
            if a.to == s.configuration:
                return "not applicable", f"already in {a.to}", ()
            if a.to not in self._conf_modules:
                return "not applicable", f"unknown configuration {a.to}", ()
            target = self._conf_modules[a.to]
        off = s.kappa.unavailable()  # no κ object built for the available modules
        down = [m for m in target if m in off] if off else []
        deps = None
        if down:
            dest = s.configuration if a.kind == "parameter_update" else a.to
            deps = self.dependencies(system, dest) if dest else None
        if down and deps is not None:
            dead = set(down)
            needed = {
                u: sorted(m for m in target if m not in dead and u in set(deps.get(m, ())))
                for u in down
            }
            down = [f"{u} (needed by {', '.join(by)})" for u, by in needed.items() if by]
        if down:
            return "unavailable", ", ".join(down), target
        reason, detail = self._constraints(target)
        if reason is None:
            reason, detail = self._limits(a, s, target)
        if reason is not None:
            return reason, detail, target
        if a.kind != "parameter_update" and s.t - s.t_last < self.dwell_s:
            wait = self.dwell_s - (s.t - s.t_last)
            return (
                "dwell",
                f"t − t_last = {s.t - s.t_last:.3g} s < T_min = {self.dwell_s:g} s "
                f"({wait:.3g} s to go)",
                target,
            )
        return None, "", target

    def _constraints(self, target: tuple[str, ...]) -> tuple[str | None, str]:
        """(``"constraint"``/``"budget"``/None, detail) of a module set, cached per set."""
        found = self._static.get(target)
        if found is None:
            bad = constraint_violations(self.arch, target, self._constrained)
            if bad:
                found = ("constraint", "; ".join(bad))
            elif over := budget_violations(self.arch, target):
                found = ("budget", "; ".join(over))
            else:
                found = (None, "")
            self._static[target] = found
        return found

    def _limits(self, a: Action, s: PlanState, target: tuple[str, ...]) -> tuple[str | None, str]:
        """(``"limit"``/None, detail): operating limits on θ after ``a`` and on e now.

        Not cached: θ changes with parameter updates and e every cycle.
        """
        if a.kind == "parameter_update":
            limits = self.arch.modules[a.module].constraints.limits
            for p, v in (a.set or {}).items() if limits else ():
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    continue
                hi, lo = limits.get(f"max_{p}"), limits.get(f"min_{p}")
                if hi is not None and v > hi:
                    return "limit", f"θ: {a.module}.{p} = {v:g} would break max_{p} {hi:g}"
                if lo is not None and v < lo:
                    return "limit", f"θ: {a.module}.{p} = {v:g} would break min_{p} {lo:g}"
            for p, v in (a.set or {}).items():
                declared = self._declared.get((a.module, p))
                if declared is not None and (why := declared[0].outside(v)):
                    return "limit", (
                        f"θ: {a.module}.{p} = {why}, the range type '{declared[1]}' declares"
                    )
        for m, blocks in self._blocking.items():
            if m not in s.active or (a.id not in blocks if blocks != "all" else m not in target):
                continue
            bad = [v for v in s.kappa[m].violations if is_limit_violation(v)]
            if bad:
                return "limit", f"e: {m} {'; '.join(bad)} blocks {a.id}"
        return None, ""

    # ------------------------------------------------------------------ plan
    def plan(
        self, system: ManagedSystem, state: PlanState, candidates: Iterable[str]
    ) -> tuple[list[ActionEvaluation], Action | None, ActionEvaluation | None]:
        """Evaluate every action of every candidate (Algorithm 1, steps 6–8).

        Parameters
        ----------
        system : LiveSystem
            The running system (for rollouts, snapshots and linearizations; not
            modified).
        state : PlanState
            s of Eq. 17.
        candidates : iterable of str
            The candidate set C.

        Returns
        -------
        evaluations : list of ActionEvaluation
            One per action considered, with Δ, verdict, score or rejection.
        chosen : Action or None
            a* of Eq. 26, or None.
        chosen_eval : ActionEvaluation or None
            The evaluation of ``chosen``.
        """
        evaluations: list[ActionEvaluation] = []
        best: tuple[float, float, int] | None = None
        chosen: Action | None = None
        chosen_eval: ActionEvaluation | None = None
        for module in candidates:
            actions = self.by_module.get(module)
            if not actions:
                continue
            z_i = abs(float(state.z.get(module, 0.0)))
            r_i = abs(float(state.r.get(module, 0.0)))
            for order, a in (queue := list(actions)):
                ev = ActionEvaluation(a.id, module, a.kind, a.to, z=z_i, cost=a.cost)
                evaluations.append(ev)
                reason, detail, _ = self._admissible(a, state, system)
                if reason is not None:
                    ev.rejected, ev.detail = reason, detail
                    if reason == "unavailable":  # paths: evaluated next, same order
                        queue.extend((order, d) for d in self.detours.find(
                            a, state.configuration, state.kappa.unavailable(),
                            lambda c: self.dependencies(system, c)))
                    continue
                try:
                    delta = self._delta(a, module, r_i, state, system, ev)
                except Exception as exc:  # noqa: BLE001 - a failing estimate rejects the action
                    ev.rejected, ev.detail = "no improvement", f"estimate failed: {exc}"
                    continue
                if ev.rejected:  # held back (runtime.learning)
                    continue
                if not math.isfinite(delta):
                    ev.rejected, ev.detail = "no improvement", "estimate is not finite"
                    continue
                ev.delta = delta
                ev.score = z_i * delta - self.cost_weight * a.cost
                if self.utility.on and a.to is not None:  # qualities: U, μ·(U − U_target)
                    ev.utility = self.utility.of(a.to)
                    ev.score += self.utility.bonus(a.to, self.detours.origin.get(a.id, a.to))
                if ev.score <= 0:
                    ev.rejected = "no improvement"
                    gain, penalty = z_i * delta, self.cost_weight * a.cost
                    ev.detail = f"z·Δ = {gain:.3g} ≤ λ·cost = {penalty:.3g}"
                    continue
                verdict = self.stability(system, a)
                ev.stability = verdict.to_dict()
                if not verdict.ok:
                    ev.rejected, ev.detail = "unstable", verdict.reason
                    if a.id not in self.detours.origin:  # paths: a stable one with the remedy
                        queue.extend((order, d) for d in self.detours.find(a, state.configuration))
                    continue
                if self.utility.on and a.id not in self.detours.origin:  # the alternatives
                    queue.extend((order, d) for d in self.detours.find(a, state.configuration))
                key = (ev.score, -a.cost, -order)
                if best is None or key > best:
                    best, chosen, chosen_eval = key, a, ev
        return evaluations, chosen, chosen_eval

    def _delta(
        self, a: Action, module: str, r_i: float, state: PlanState, system: ManagedSystem,
        ev: ActionEvaluation,
    ) -> float:
        """Δ_k by the declared method; with ``runtime.risk`` over K draws by the rule; with
        ``runtime.learning`` times the learned factor of the context, or ``ev.rejected =
        "held back"`` after a failure there (:mod:`~archself.runtime.learning`)."""
        factor = 1.0
        if self.learning is not None:  # what this action did here before
            factor, held, ev.learned = self.learning.review(
                a.id, module, state.configuration, state.t)
            if held:
                ev.rejected, ev.detail = "held back", held
                return math.nan
        if self.risk is not None:  # K draws and the risk rule
            return factor * self.risk.estimate(a, module, r_i, system, ev)
        return factor * estimate_improvement(a, module, r_i, system)

    def check(
        self, action: Action, state: PlanState, system: ManagedSystem
    ) -> tuple[str | None, str]:
        """(rejection, detail) of one action by checks 1–4 and 6 (no score): a tactic."""
        reason, detail, _ = self._admissible(action, state, system)
        if reason is None and not (verdict := self.stability(system, action)).ok:
            reason, detail = "unstable", verdict.reason
        return reason, detail

    def stability(self, system: ManagedSystem, action: Action) -> StabilityVerdict:
        """Stability filter (Eq. 21, else Eq. 24) for one action (passes when ablated)."""
        if not self.stability_on:
            return StabilityVerdict(
                True, "off", None, None, "stability filter off (runtime.ablation)"
            )
        return check_action_stability(
            system,
            action,
            margin=self.margin,
            alpha=self.alpha,
            horizon_steps=self.horizon_steps,
            floor=self.v_floor,
            loop_steps=self.loop_steps,
            marginal=self.marginal,
        )
