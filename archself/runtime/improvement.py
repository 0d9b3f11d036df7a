"""The improvement Δ_k of an action (Eq. 18) by the method it declares.

``sensitivity`` (``Δ = −Δθ·|r_i|``), ``table`` (a value per module) or ``rollout``
(:func:`rollout_improvement`: mean J without minus with the action over a horizon,
on two snapshots of the running system sharing their random state).
"""

from __future__ import annotations

from archself.contracts import ManagedSystem, SystemSnapshot
from archself.model.architecture import Action
from archself.runtime.stability import action_target, apply_action, rollout_copy

__all__ = ["estimate_improvement", "rollout_improvement"]


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
