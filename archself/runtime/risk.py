"""Δ with its uncertainty: rollouts over K sampled noise draws and the risk rule.

With ``runtime.risk.draws`` K > 1, an action whose Δ is estimated by ``rollout``
(:func:`~archself.runtime.improvement.rollout_improvement`) is rolled out K times:
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
from collections.abc import Iterator
from typing import Any

import numpy as np

from archself.contracts import ManagedSystem
from archself.model.architecture import Action, Architecture, Risk
from archself.runtime.improvement import estimate_improvement, mean_objective
from archself.runtime.stability import action_target, apply_action, rollout_copy
from archself.system.streams import stable_hash

__all__ = ["RiskRanking", "risk_value", "sampled_rollouts"]

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
