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
   (:class:`RiskRanking`, below); with ``runtime.learning``, Δ is scaled by what the
   action did in this context before, and an action whose last outcome here failed
   is ``held back`` (:mod:`archself.runtime.knowledge`);
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

The file holds the Plan stage whole, in this order: the planner, the candidate set,
the constraints, the detours and alternatives, the utility, the Δ estimates and their
risk; each part's rules follow.

The candidate set C of modules to adapt (paper Eq. 16 and the hysteresis of §4.2).

Three selectors, chosen by the ``runtime`` block of the architecture file:

- ``threshold: τ`` — ``C = {m_i : |z_i| ≥ τ}`` (Eq. 16), :func:`threshold_candidates`;
- ``top_k: k`` — the ``k`` modules with the largest non-zero ``|z_i|``,
  :func:`top_k_candidates`;
- ``hysteresis: {on, off}`` — a module enters C when ``|z_i| ≥ τ_on`` and leaves it
  only when ``|z_i| < τ_off`` (τ_on > τ_off), :class:`HysteresisSelector`.

With ``runtime.localization: fit`` (the default) or ``source`` the same selectors
run on the source estimate ê (:mod:`~archself.runtime.influence`) instead of z; ``symbol`` names the
quantity in :meth:`CandidateSelector.describe`.

Every selector returns the candidates ordered by decreasing ``|z_i|``, equal
magnitudes by name. ``select(z, values)`` may be given ``values``, the array of
``z``'s values in its key order: the test on ``|z_i|`` then runs on the array
(same result, far cheaper on 10^4 modules).

The constraints C(a, θ, e) ≤ 0 of Eq. 27 that a target architecture must meet.

:func:`budget_violations` (Σ resources ≤ max per budget), :func:`constraint_violations`
(the modules' ``requires``/``excludes``) and :func:`declared_ranges` (the ranges the
module types declare for the parameters an update sets). The
:class:`~archself.runtime.planner.Planner` checks them per candidate action.

Paths to a configuration: a detour when an action's target is unavailable or unstable.

A structural action ``a`` keyed to module ``m_i`` leads from the current
configuration ``M`` to its declared target ``T``. The modules it brings in,
``K = T \\ M``, are what compensates ``m_i`` (say, an adaptive controller together
with an estimator that needs a sensor). When ``T`` cannot run now — one of its
modules is down, or depends on one that is (the Plan stage's ``unavailable``,
§4.2) — the file may still declare a configuration that keeps the part of ``K`` that
*can* run: the configurations graph (configurations as nodes; the declared structural
actions and a *synthesized* switch to any declared configuration as edges, since the
executor hot swaps to any of them) has a node that compensates the fault without the
dead part.

:class:`Detours` finds them, without a hand-written action for every pair:

- ``D``: the modules of ``T`` that are unavailable or need an unavailable module
  (the target's dependency map, as the planner's availability rule);
- the *remedy*: the modules of ``K`` wired to ``m_i`` (an edge either way; all of
  ``K`` if none is), less ``D`` (nothing left: no detour);
- every declared configuration ``C ∉ {M, T}`` that holds the remedy and what ``T``
  keeps of ``M`` (less ``D``), and none of the modules of ``D`` that are not down
  themselves (those that need a dead one; a dead sensor used for monitoring only may
  stay, as the planner's rule allows) is a detour, ranked by ``|C ∩ T|`` (closest to
  the intended target) descending, then ``|C △ M|`` (smallest change) ascending, then
  declaration order.

The same search with ``D = ∅`` gives the *alternatives* of an action: the other
configurations that hold its remedy. They are evaluated when the declared target fails
the stability filter (``T`` cannot be entered safely now, another holder of the remedy
may), and, with quality attributes (``qualities``, :class:`Utility`),
for every admissible action, since the preferences may rank one above ``T``.

Each detour or alternative becomes an action ``<a.id>@<C>`` — ``a`` with ``to = C``
and no ``applies_in`` — that the planner evaluates like a declared one: availability,
constraints and budgets, limits, dwell, the same Δ estimate (the remedy of ``m_i`` is
kept), the score plus ``μ·(U(C) − U(T))`` and the stability filter. A declared action
with the same score wins the tie (it comes first). ``runtime.ablation.paths: false``
switches both off.

Weighted utility of a configuration under the file's quality preferences.

``U(C) = Σ_q w_q · u_q(value_q(C)) / Σ_q w_q`` (:mod:`archself.model.architecture`):
``value_q(C)`` is the sum of the attribute's ``resource`` over the configuration's
modules, or its declared value; ``u_q`` its utility curve; ``w_q`` the preference.

The score of a declared action is Eq. 25 as it is; a configuration the planner reaches
in its place (a detour around an unavailable target, or an alternative that keeps the
same remedy, :class:`Detours`) scores ``μ·(U(C) − U(T))`` more, T being the
declared target: the remedy's worth is the action's, the preferences say which of the
configurations holding it to land in. Without a ``qualities`` section U is 0.

The improvement Δ_k of an action (Eq. 18) by the method it declares.

``sensitivity`` (``Δ = −Δθ·|r_i|``), ``table`` (a value per module) or ``rollout``
(:func:`rollout_improvement`: mean J without minus with the action over a horizon,
on two snapshots of the running system sharing their random state).

Δ with its uncertainty: rollouts over K sampled noise draws and the risk rule.

With ``runtime.risk.draws`` K > 1, an action whose Δ is estimated by ``rollout``
(:func:`~archself.runtime.planner.rollout_improvement`) is rolled out K times:
draw 0 on the snapshots' own random state (the one-draw estimate), draws 1…K−1
with every random stream of both snapshots reseeded from the draw, the action and
the cycle (the two branches of one draw share their noise, so their difference
is still the action's effect). ``runtime.risk.rule`` turns the K values into the
one that ranks the candidates:

- ``mean``: their mean;
- ``mean_std``: mean − κ·std (risk-averse for κ > 0);
- ``cvar``: the mean of the worst ⌈α·K⌉ draws (the lower tail at level α).

Sensitivity and table estimates have no draws: their spread is 0 and the rule
is their value. The decision log records, per evaluated action, ``mean``,
``spread`` (the standard deviation of the draws), ``draws`` and ``rule``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from archself import registry
from archself.contracts import ManagedSystem, SystemSnapshot
from archself.model.architecture import Action, Architecture, Risk, Runtime
from archself.modules.base import Param
from archself.runtime.knowledge import ActionEvaluation
from archself.runtime.monitor import StatusMap, is_limit_violation
from archself.runtime.stability import (
    StabilityVerdict,
    action_target,
    apply_action,
    check_action_stability,
    rollout_copy,
)
from archself.system.live import stable_hash

__all__ = [
    "CandidateSelector",
    "Detours",
    "HysteresisSelector",
    "PlanState",
    "Planner",
    "RiskRanking",
    "ThresholdSelector",
    "TopKSelector",
    "Utility",
    "budget_violations",
    "constraint_violations",
    "declared_ranges",
    "detour_id",
    "estimate_improvement",
    "risk_value",
    "rollout_improvement",
    "sampled_rollouts",
    "selector_from_runtime",
    "threshold_candidates",
    "top_k_candidates",
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
        "held back"`` after a failure there (:mod:`~archself.runtime.knowledge`)."""
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


def _ranked(z: Mapping[str, float], names: Iterable[str]) -> list[str]:
    """Names by decreasing ``|z|``; ties (equal to 12 significant digits) by name.

    Comparing rounded magnitudes keeps the order of equal channels fixed when the
    last bits of z change with the BLAS or SuperLU build.
    """
    return sorted(names, key=lambda n: (-float(f"{abs(z[n]):.12g}"), n))


def _ranked_where(z: Mapping[str, float], mask: np.ndarray) -> list[str]:
    """:func:`_ranked` of the keys of ``z`` where the boolean array ``mask`` holds."""
    index = mask.nonzero()[0].tolist()
    if not index:  # most cycles: nothing to rank
        return []
    keys = list(z)
    return _ranked(z, [keys[i] for i in index])


def threshold_candidates(z: Mapping[str, float], tau: float) -> list[str]:
    """Modules with ``|z_i| ≥ τ`` (Eq. 16), largest first.

    Examples
    --------
    >>> threshold_candidates({"a": 0.2, "b": -0.9, "c": 0.6}, 0.55)
    ['b', 'c']
    """
    return _ranked(z, [n for n, v in z.items() if abs(v) >= tau])


def top_k_candidates(z: Mapping[str, float], k: int) -> list[str]:
    """The ``k`` modules with the largest ``|z_i|``, ignoring ``z_i = 0``.

    Examples
    --------
    >>> top_k_candidates({"a": 0.2, "b": -0.9, "c": 0.0}, 2)
    ['b', 'a']
    """
    return _ranked(z, [n for n, v in z.items() if v != 0.0])[:k]


class CandidateSelector:
    """Base class: ``select(z[, values]) -> list of module names``, largest ``|z|`` first.

    ``values``, when given, is ``numpy.array(list(z.values()))`` (computed
    already by the caller); selectors use it to test every module at once.
    ``symbol`` names the quantity selected on in :meth:`describe` (``z`` or ``ê``).
    """

    symbol = "z"

    def select(
        self, z: Mapping[str, float], values: np.ndarray | None = None
    ) -> list[str]:  # pragma: no cover - abstract
        raise NotImplementedError

    def entering(self, z: Mapping[str, float], values: np.ndarray | None = None) -> list[str]:
        """The modules that would enter C on ``z`` now, without changing the selector's state.

        A second look in the same cycle (the echo of a source whose action waits out the
        dwell time, :class:`~archself.runtime.mapek.MapeK`); stateless selectors select.
        """
        return self.select(z, values)

    def reset(self) -> None:
        """Forget any state (nothing for the stateless selectors)."""

    def describe(self) -> str:  # pragma: no cover - abstract
        raise NotImplementedError


class ThresholdSelector(CandidateSelector):
    """``|z_i| ≥ τ`` (Eq. 16)."""

    def __init__(self, tau: float, symbol: str = "z") -> None:
        self.tau = float(tau)
        self.symbol = symbol

    def select(self, z: Mapping[str, float], values: np.ndarray | None = None) -> list[str]:
        if values is None:
            return threshold_candidates(z, self.tau)
        return _ranked_where(z, np.abs(values) >= self.tau)

    def describe(self) -> str:
        return f"|{self.symbol}| >= {self.tau:g}"


class TopKSelector(CandidateSelector):
    """The ``k`` largest non-zero ``|z_i|``."""

    def __init__(self, k: int, symbol: str = "z") -> None:
        self.k = int(k)
        self.symbol = symbol

    def select(self, z: Mapping[str, float], values: np.ndarray | None = None) -> list[str]:
        if values is None:
            return top_k_candidates(z, self.k)
        return _ranked_where(z, values != 0.0)[: self.k]

    def describe(self) -> str:
        return f"top {self.k} by |{self.symbol}|"


class HysteresisSelector(CandidateSelector):
    """Candidate set with hysteresis: enter at ``|z| ≥ on``, leave at ``|z| < off``.

    Parameters
    ----------
    on, off : float
        Thresholds τ_on > τ_off ≥ 0.

    Examples
    --------
    >>> sel = HysteresisSelector(on=0.6, off=0.3)
    >>> sel.select({"a": 0.5})      # below on: not yet a candidate
    []
    >>> sel.select({"a": 0.7})      # crosses on: enters
    ['a']
    >>> sel.select({"a": 0.4})      # between off and on: stays
    ['a']
    >>> sel.select({"a": 0.2})      # below off: leaves
    []
    """

    def __init__(self, on: float, off: float, symbol: str = "z") -> None:
        self.symbol = symbol
        if not on > off:
            raise ValueError("hysteresis needs on > off")
        self.on = float(on)
        self.off = float(off)
        self.members: set[str] = set()

    def select(self, z: Mapping[str, float], values: np.ndarray | None = None) -> list[str]:
        keep = {n for n in self.members if n in z and abs(z[n]) >= self.off}
        if values is None:
            enter = {n for n, v in z.items() if abs(v) >= self.on}
        else:
            keys = list(z)
            enter = {keys[i] for i in (np.abs(values) >= self.on).nonzero()[0].tolist()}
        self.members = keep | enter
        return _ranked(z, self.members)

    def entering(self, z: Mapping[str, float], values: np.ndarray | None = None) -> list[str]:
        """``|z| ≥ on``, the members left as they are."""
        return threshold_candidates(z, self.on)

    def reset(self) -> None:
        self.members.clear()

    def describe(self) -> str:
        s = self.symbol
        return f"hysteresis on |{s}| >= {self.on:g}, off |{s}| < {self.off:g}"


def selector_from_runtime(runtime: Runtime) -> CandidateSelector:
    """The selector the ``runtime`` block declares (exactly one is given).

    It selects on z with ``localization: influence``, else on the source estimate ê.
    """
    symbol = "z" if runtime.localization == "influence" else "ê"
    if runtime.hysteresis is not None:
        return HysteresisSelector(runtime.hysteresis.on, runtime.hysteresis.off, symbol)
    if runtime.top_k is not None:
        return TopKSelector(runtime.top_k, symbol)
    assert runtime.threshold is not None
    return ThresholdSelector(runtime.threshold, symbol)


def declared_ranges(arch: Architecture) -> dict[tuple[str, str], tuple[Any, str]]:
    """``(Param, type)`` per (module, parameter) that a parameter update sets.

    The declaration of the parameter by the module's type, where it gives a range
    (``Param(min=, max=)``; :meth:`~archself.modules.base.Param.outside` judges a
    value). Types are looked up in the registry (one it does not know declares
    nothing).

    Examples
    --------
    >>> import json
    >>> from archself.model.generate import generate_architecture
    >>> from archself.model.loader import load_text
    >>> data = json.loads(generate_architecture(3, seed=0).split("\\n", 1)[1])
    >>> data["actions"] = [{"id": "quiet", "module": "m1", "kind": "parameter_update",
    ...     "set": {"noise": 0.1}, "cost": 0.1,
    ...     "improvement": {"method": "sensitivity", "delta_theta": -1}}]
    >>> spec, type_ = declared_ranges(load_text(json.dumps(data)).arch)[("m1", "noise")]
    >>> spec.outside(-1.0), type_
    ('-1 is outside [0, ∞]', 'generic.relay')
    """

    out: dict[tuple[str, str], tuple[Any, str]] = {}
    for a in arch.actions:
        mod = arch.modules.get(a.module)
        if a.kind != "parameter_update" or mod is None or not a.set:
            continue
        try:
            cls = registry.lookup(mod.type)
        except Exception:  # noqa: BLE001 - a broken plugin declares nothing here
            cls = None
        params = getattr(cls, "parameters", None) or {}
        for p in a.set:
            spec = params.get(p)
            if isinstance(spec, Param) and (spec.min is not None or spec.max is not None):
                out[(a.module, p)] = (spec, mod.type)
    return out


def budget_violations(arch: Architecture, modules: Iterable[str]) -> list[str]:
    """Budgets violated by a module set: Σ_{m} resources[resource] − max > 0 (Eq. 27).

    Returns
    -------
    list of str
        One line per violated budget (empty when C(a) ≤ 0 holds).
    """
    mods = list(modules)
    out = []
    for b in arch.constraints:
        use = sum(arch.modules[m].resources.get(b.resource, 0.0) for m in mods if m in arch.modules)
        if use > b.max + 1e-12:
            out.append(f"{b.resource} {use:g} > {b.max:g}")
    return out


def constraint_violations(
    arch: Architecture, modules: Iterable[str], constrained: Iterable[str] | None = None
) -> list[str]:
    """Module constraints k_i (``requires``/``excludes``) violated by a module set.

    ``constrained``, when given, holds every module of the file that has a
    constraint (the others cannot violate one): only those are looked at.
    """
    on = set(modules)
    out = []
    for m in sorted(on if constrained is None else on.intersection(constrained)):
        if m not in arch.modules:
            continue
        cons = arch.modules[m].constraints
        out += [f"{m} requires {x}" for x in cons.requires if x not in on]
        out += [f"{m} excludes {x}" for x in cons.excludes if x in on]
    return out


#: Separates the action's id from the detour's configuration in a synthesized id.
SEPARATOR = "@"


def detour_id(action_id: str, configuration: str) -> str:
    """The id of the detour of ``action_id`` to ``configuration`` (``a@C``)."""
    return f"{action_id}{SEPARATOR}{configuration}"


class Detours:
    """Synthesized switches to the declared configurations that keep an action's remedy.

    Parameters
    ----------
    arch : Architecture
        Reads ``configurations`` and ``runtime.ablation.paths``.
    """

    def __init__(self, arch: Architecture) -> None:
        self.on = arch.runtime.ablation.paths
        self.modules = {c: frozenset(conf.modules) for c, conf in arch.configurations.items()}
        self.order = {c: k for k, c in enumerate(arch.configurations)}
        self.wired: dict[str, set[str]] = {}
        for e in arch.edges:
            self.wired.setdefault(e.source, set()).add(e.target)
            self.wired.setdefault(e.target, set()).add(e.source)
        self._made: dict[tuple[str, str], Action] = {}
        #: synthesized action id -> the declared target it stands in for
        self.origin: dict[str, str] = {}

    def find(
        self,
        action: Action,
        current: str,
        down: Iterable[str] = (),
        dependencies: Callable[[str], Mapping[str, Iterable[str]] | None] | None = None,
    ) -> list[Action]:
        """The detours (or, with nothing down, the alternatives) of ``action``, best first.

        Parameters
        ----------
        action : Action
            A declared structural action.
        current : str
            The current configuration M.
        down : iterable of str
            The modules reported unavailable (κ); empty for the alternatives.
        dependencies : callable, optional
            configuration -> {module: modules it cannot run without}, or None
            (then only the unavailable modules themselves are excluded).

        Returns
        -------
        list of Action
            ``<action.id>@<C>`` for each C, ranked as the module docstring says.
        """
        target = action.to
        if not self.on or action.kind == "parameter_update" or target not in self.modules:
            return []
        off = set(down)
        t_mods = self.modules[target]
        deps = (dependencies(target) if dependencies is not None and off else None) or {}
        dead = {m for m in t_mods if m in off or off.intersection(deps.get(m, ()))}
        m_now = self.modules.get(current, frozenset())
        brought = t_mods - m_now
        remedy = (brought & self.wired.get(action.module, set())) or brought
        kept = remedy - dead
        if not kept:
            return []
        must = kept | ((t_mods & m_now) - dead)
        needs = dead - off  # modules that need a dead one; the dead themselves may stay
        found = [
            c
            for c, mods in self.modules.items()
            if c not in (current, target) and must <= mods and not (mods & needs)
        ]
        found.sort(key=lambda c: (-len(self.modules[c] & t_mods),
                                  len(self.modules[c] ^ m_now), self.order[c]))
        return [self._action(action, c, bool(off)) for c in found]

    def _action(self, action: Action, configuration: str, detour: bool) -> Action:
        key = (action.id, configuration)
        made = self._made.get(key)
        if made is None:
            why = ("its target {} is unavailable" if detour else "it holds the remedy of {}")
            made = self._made[key] = action.model_copy(update={
                "id": detour_id(action.id, configuration),
                "to": configuration,
                "applies_in": None,
                "description": f"in place of {action.id} ({why.format(action.to)})",
            })
            self.origin[made.id] = str(action.to)
        return made


class Utility:
    """U(C) and the attribute values behind it, cached per configuration.

    Parameters
    ----------
    arch : Architecture
        Reads ``qualities``, ``configurations`` and the modules' ``resources``.
    """

    def __init__(self, arch: Architecture) -> None:
        self.arch = arch
        self.qualities = arch.qualities
        self.weight = self.qualities.weight if self.qualities is not None else 0.0
        self._cache: dict[str, dict[str, Any]] = {}

    @property
    def on(self) -> bool:
        """Whether the file declares quality attributes."""
        return self.qualities is not None

    def of(self, configuration: str) -> dict[str, Any]:
        """``{"U": U(C), "attributes": {q: {"value", "utility"}}}`` of a configuration."""
        found = self._cache.get(configuration)
        if found is not None:
            return found
        q = self.qualities
        attrs: dict[str, dict[str, float]] = {}
        total = weights = 0.0
        conf = self.arch.configurations.get(configuration)
        if q is not None and conf is not None:
            for name, attr in q.attributes.items():
                if attr.resource is not None:
                    value = sum(
                        float(self.arch.modules[m].resources.get(attr.resource, 0.0))
                        for m in conf.modules if m in self.arch.modules
                    )
                else:
                    value = float((attr.values or {}).get(configuration, float("nan")))
                u = attr.utility_of(value) if value == value else 0.0
                attrs[name] = {"value": value, "utility": u}
                w = float(q.preferences.get(name, 0.0))
                total += w * u
                weights += w
        found = {"U": total / weights if weights > 0 else 0.0, "attributes": attrs}
        self._cache[configuration] = found
        return found

    def bonus(self, configuration: str, declared: str) -> float:
        """``μ·(U(configuration) − U(declared))`` (0 without qualities)."""
        if self.qualities is None or configuration == declared:
            return 0.0
        return self.weight * (self.of(configuration)["U"] - self.of(declared)["U"])


def mean_objective(system: SystemSnapshot, steps: int) -> float:
    """Step ``system`` ``steps`` times; the mean objective error J over them."""
    total = 0.0
    for _ in range(steps):
        system.step()
        total += float(system.objective_error())
    return total / steps


def rollout_improvement(system: ManagedSystem, action: Action, horizon_s: float) -> float:
    """Δ = mean J(no action) − mean J(action) over ``horizon_s`` on two snapshots.

    The live system is not modified. Snapshots share the RNG state, so noise is
    common to both branches and the difference isolates the action's effect. Each
    copies only the modules the objective depends on over the horizon when the
    system says which (:func:`~archself.runtime.stability.rollout_copy`).
    """
    steps = max(1, int(round(horizon_s / float(system.dt))))
    base = rollout_copy(system, system.configuration, steps)
    trial = rollout_copy(system, action_target(system, action), steps)
    apply_action(trial, action)
    return mean_objective(base, steps) - mean_objective(trial, steps)


def estimate_improvement(
    action: Action, module: str, r_i: float, system: ManagedSystem | None = None
) -> float:
    """Δ_k(m_i) of Eq. 18 by the action's declared method.

    Examples
    --------
    >>> from archself.model.architecture import Action
    >>> a = Action(id="x", module="m", kind="substitute", to="b", cost=0.1,
    ...            improvement={"method": "sensitivity", "delta_theta": -0.9})
    >>> estimate_improvement(a, "m", 2.0)
    1.8
    """
    imp = action.improvement
    if imp.method == "sensitivity":
        return float(-imp.delta_theta * abs(r_i))
    if imp.method == "table":
        return float(imp.values.get(module, imp.default))
    if system is None:
        raise ValueError("a rollout estimate needs the running system")
    return float(rollout_improvement(system, action, imp.horizon_s))


_MAX_DEPTH = 6


def risk_value(draws: np.ndarray, rule: str, kappa: float = 1.0, alpha: float = 0.25) -> float:
    """The value that ranks an action with Δ draws ``draws`` under ``rule``.

    Examples
    --------
    >>> import numpy as np
    >>> d = np.array([-1.0, 3.0, -1.0, 3.0])
    >>> risk_value(d, "mean"), risk_value(d, "mean_std", kappa=1.0)
    (1.0, -1.0)
    >>> risk_value(d, "cvar", alpha=0.5)
    -1.0
    """
    d = np.asarray(draws, dtype=float)
    if rule == "mean":
        return float(d.mean())
    if rule == "mean_std":
        return float(d.mean() - kappa * d.std())
    if rule == "cvar":
        worst = max(1, math.ceil(alpha * d.size))
        return float(np.sort(d)[:worst].mean())
    raise ValueError(f"unknown risk rule {rule!r}: mean, mean_std or cvar")


def _generators(obj: Any, path: str, seen: set[int], depth: int) -> Iterator[tuple[str, Any]]:
    """(path, numpy Generator) of every random stream reachable from ``obj``."""
    if id(obj) in seen or depth > _MAX_DEPTH or isinstance(obj, (str, bytes, int, float, type)):
        return
    seen.add(id(obj))
    if isinstance(obj, np.random.Generator):
        yield path, obj
        return
    if isinstance(obj, (Architecture, np.ndarray)):
        return
    if isinstance(obj, dict):
        items: Any = ((str(k), v) for k, v in obj.items())
    elif isinstance(obj, (list, tuple)):
        items = ((str(i), v) for i, v in enumerate(obj))
    elif hasattr(obj, "__dict__"):
        items = vars(obj).items()
    else:
        return
    for key, value in items:
        yield from _generators(value, f"{path}.{key}", seen, depth + 1)


def reseed(system: Any, base: int) -> int:
    """Reseed every random stream of ``system`` from ``base`` and its path; how many."""
    n = 0
    for path, g in _generators(system, "", set(), 0):
        seq = np.random.SeedSequence([base, stable_hash(path)])
        g.bit_generator.state = type(g.bit_generator)(seq).state
        n += 1
    return n


def sampled_rollouts(
    system: ManagedSystem, action: Action, horizon_s: float, draws: int
) -> tuple[np.ndarray, int]:
    """Δ of ``action`` over ``draws`` noise draws (draw 0: the snapshots' own state).

    Returns
    -------
    values : numpy.ndarray
        One Δ per draw.
    streams : int
        The random streams reseeded per draw (0: the system has none reachable,
        every draw is the same; the spread is then 0 and says nothing).
    """
    steps = max(1, int(round(horizon_s / float(system.dt))))
    cycle = int(round(float(system.t) / float(system.dt)))
    values = np.empty(draws)
    streams = 0
    for k in range(draws):
        base = rollout_copy(system, system.configuration, steps)
        trial = rollout_copy(system, action_target(system, action), steps)
        if k:
            seed = stable_hash(f"{action.id}:{cycle}:{k}") & 0xFFFFFFFF
            streams = reseed(base, seed)
            reseed(trial, seed)
        apply_action(trial, action)
        values[k] = mean_objective(base, steps) - mean_objective(trial, steps)
    return values, streams


class RiskRanking:
    """The planner's Δ under ``runtime.risk`` (K draws of a rollout, the rule)."""

    def __init__(self, risk: Risk) -> None:
        self.risk = risk

    def estimate(
        self, action: Action, module: str, r_i: float, system: ManagedSystem, ev: Any
    ) -> float:
        """Δ that ranks ``action``; ``ev`` (an ActionEvaluation) gets mean, spread, rule."""
        rk = self.risk
        ev.rule = rk.rule if rk.rule != "mean_std" else f"mean − {rk.kappa:g}·std"
        if rk.rule == "cvar":
            ev.rule = f"cvar at {rk.alpha:g}"
        if action.improvement.method != "rollout":
            value = estimate_improvement(action, module, r_i, system)
            ev.mean, ev.spread, ev.draws = value, 0.0, 1
            return value
        values, streams = sampled_rollouts(system, action, action.improvement.horizon_s, rk.draws)
        ev.mean, ev.spread, ev.draws = float(values.mean()), float(values.std()), rk.draws
        if streams == 0:
            ev.rule += " (no random stream to resample: the draws are one)"
        return risk_value(values, rk.rule, rk.kappa, rk.alpha)
