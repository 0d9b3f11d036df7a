"""Stability-aware action filtering (paper Eq. 19–24).

An action ``a_k`` is admissible only if the closed loop it leads to is stable:

- **Eigenvalue margin** (Eq. 21), when a model is available: the system gives
  the closed-loop matrix ``A_k`` of the target configuration
  (``system.linearization(configuration)``; for a parameter update, of the
  current configuration on a snapshot to which the update was applied), and the
  test is ``max Re λ(A_k) ≤ −ε`` with ``ε = runtime.stability.margin``
  (:func:`eigenvalue_margin`).
- **Lyapunov decrease** (Eq. 22–24), otherwise: on a snapshot of the running
  system the action is applied and the system stepped
  ``runtime.stability.horizon_steps`` times, recording
  ``V_t = ‖x_t − x_ref‖²`` from ``system.state_error()``. The mean one-step
  change ``E[ΔV | a_k]`` is estimated from *every* step of the rollout, as the
  least-squares slope of ``V_t`` over ``t = 0 … H``, and must satisfy
  ``E[ΔV | a_k] ≤ −α‖x_0 − x_ref‖² = −α V_0`` (:func:`lyapunov_decrease`).
  Two conditions on the second half of the rollout make the test sound against
  trajectories that a two-point estimate ``(V_H − V_0)/H`` lets through: V must
  not rise above ``V_0`` there (a diverging oscillation that happens to pass
  near zero at step H), and V must not grow there (slope ≤ ``α V_0``; a
  trajectory that turns back up late).

  *Near the reference* the condition cannot hold: with ``V_0 ≈ 0`` noise alone
  makes ΔV positive as often as negative, so a literal test would reject every
  action whenever the system tracks well. We therefore also accept an action
  whose trajectory stays inside a small floor, ``max_t V_t ≤ V_floor``: a system
  that stays within the acceptable error is not being destabilized. The floor is
  ``J_ref²`` (``runtime.objective.acceptable`` squared) when that is positive,
  else ``1e-6``.

  The snapshot holds only the modules whose outputs reach the objective within
  the horizon (:func:`rollout_copy`, when the system gives ``rollout_scope``): V
  is the same step by step, and a rollout in a 10^5-module graph copies and
  steps the few hundred modules upstream of the objective, not the whole graph.

Every failure of the test itself (no snapshot, an exception in the rollout,
NaN) rejects the action: the filter fails closed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from archself.contracts import LoopSystem, ManagedSystem, SystemSnapshot
from archself.runtime.influence import is_sparse

__all__ = [
    "StabilityVerdict",
    "action_target",
    "apply_action",
    "check_action_stability",
    "eigenvalue_margin",
    "lyapunov_decrease",
    "rollout_copy",
    "whole_loop_check",
]


@dataclass
class StabilityVerdict:
    """Outcome of the stability filter for one action (logged in the decision record).

    Attributes
    ----------
    ok : bool
        The action preserves stability.
    method : str
        ``"eigenvalue"`` (Eq. 21), ``"lyapunov"`` (Eq. 24), ``"whole-loop"`` (the
        numerical linearization of every module's state), ``"lyapunov-floor"``
        (accepted because V stayed below the floor), ``"error"`` or ``"off"``
        (the filter is switched off by ``runtime.ablation``).
    value : float or None
        ``max Re λ(A_k)`` or ``E[ΔV|a_k]``.
    bound : float or None
        ``−ε`` or ``−α V_0``.
    reason : str
        One sentence for the decision log.
    """

    ok: bool
    method: str
    value: float | None
    bound: float | None
    reason: str

    def to_dict(self) -> dict[str, Any]:
        def f(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "ok": bool(self.ok),
            "method": self.method,
            "value": f(self.value),
            "bound": f(self.bound),
            "reason": self.reason,
        }


def eigenvalue_margin(A: Any, margin: float) -> StabilityVerdict:
    """Eq. 21: ``max Re λ(A) ≤ −ε`` (``A`` dense, or ``scipy.sparse`` for a large loop).

    Examples
    --------
    >>> eigenvalue_margin([[-1.0, 0.0], [0.0, -2.0]], 0.01).ok
    True
    >>> eigenvalue_margin([[0.5, 0.0], [0.0, -2.0]], 0.01).ok
    False
    """
    from archself.linear.wiring import eigenvalues

    if is_sparse(A):  # a large closed loop (archself.linear.wiring.eigenvalues)
        finite = bool(np.all(np.isfinite(A.data)))
    else:
        A = np.atleast_2d(np.asarray(A, dtype=float))
        finite = bool(np.all(np.isfinite(A)))
    if A.shape[0] != A.shape[1] or not finite:
        why = "linearization is not a finite square matrix"
        return StabilityVerdict(False, "error", None, -margin, why)
    if A.shape[0] == 0:
        return StabilityVerdict(True, "eigenvalue", None, -margin, "empty linearization")
    worst = float(np.max(eigenvalues(A).real))
    ok = worst <= -margin
    rel = "≤" if ok else ">"
    return StabilityVerdict(
        ok, "eigenvalue", worst, -margin, f"max Re λ(A_k) = {worst:.4g} {rel} −ε = {-margin:.4g}"
    )


def _slope(v: np.ndarray) -> float:
    """Least-squares slope of ``v`` against its index (mean ΔV per step)."""
    t = np.arange(v.size, dtype=float)
    t -= t.mean()
    return float(t @ (v - v.mean()) / (t @ t))


def lyapunov_decrease(v: Any, alpha: float, floor: float) -> StabilityVerdict:
    """Eq. 22–24 on a sampled ``V_0 … V_H``, over the whole horizon.

    Accepted when ``max V ≤ floor`` (near the reference), or when all of these hold:
    the least-squares slope of V over the rollout is ``≤ −α V_0`` (Eq. 24 with
    every step counted); V stays ``≤ V_0`` over the second half; and V does not
    grow over the second half (its slope there ``≤ α V_0``).

    Parameters
    ----------
    v : array_like
        ``V_t = ‖x_t − x_ref‖²`` at the start (``v[0]``) and after each step.
    alpha : float
        α of Eq. 24.
    floor : float
        Below this V the system is considered at the reference (see module docs).

    Examples
    --------
    >>> lyapunov_decrease([1.0, 0.8, 0.6], alpha=0.01, floor=1e-6).ok
    True
    >>> lyapunov_decrease([1.0, 1.2, 1.5], alpha=0.01, floor=1e-6).ok
    False
    >>> lyapunov_decrease([1e-4, 2e-4, 1e-4], alpha=0.01, floor=0.25).method
    'lyapunov-floor'

    A diverging period-2 oscillation that is back at zero on the last step
    (the two-point estimate ``(V_H − V_0)/H`` would be ``−0.5``):

    >>> lyapunov_decrease([4, 3, 2, 1, 0, 3, 0, 5, 0], alpha=0.01, floor=1e-6).reason
    'V rises to 5 > V_0 = 4 in the second half of the rollout'
    """
    v = np.asarray(v, dtype=float).ravel()
    if v.size < 2 or not np.all(np.isfinite(v)):
        return StabilityVerdict(False, "error", None, None, "Lyapunov rollout gave no finite V")
    v0 = float(v[0])
    mean_dv = _slope(v)
    bound = -alpha * v0
    vmax = float(v.max())
    if vmax <= floor:
        return StabilityVerdict(
            True,
            "lyapunov-floor",
            mean_dv,
            bound,
            f"V stays ≤ {floor:.4g} (near the reference; max V = {vmax:.4g})",
        )
    tail = v[v.size // 2:]
    tail_max = float(tail.max())
    tail_slope = _slope(tail) if tail.size >= 2 else 0.0
    if mean_dv > bound:
        why = f"E[ΔV|a_k] = {mean_dv:.4g} > −α‖x‖² = {bound:.4g}"
    elif tail_max > v0:
        why = f"V rises to {tail_max:.4g} > V_0 = {v0:.4g} in the second half of the rollout"
    elif tail_slope > alpha * v0:
        why = f"V grows in the second half of the rollout (slope {tail_slope:.4g} per step)"
    else:
        return StabilityVerdict(
            True, "lyapunov", mean_dv, bound, f"E[ΔV|a_k] = {mean_dv:.4g} ≤ −α‖x‖² = {bound:.4g}"
        )
    return StabilityVerdict(False, "lyapunov", mean_dv, bound, why)


def rollout_copy(
    system: ManagedSystem, configuration: str | None, steps: int
) -> SystemSnapshot:
    """A snapshot of ``system`` for a rollout of ``steps`` steps in ``configuration``.

    When the system can say which modules such a rollout needs for the objective
    (``rollout_scope``, docs/develop.md), a copy of those alone — the objective's
    error is the same step by step, and a large graph is not copied and stepped
    whole; otherwise ``system.snapshot()``.
    """
    scope = getattr(system, "rollout_scope", None)
    if scope is None:
        return system.snapshot()
    return system.snapshot(only=scope(configuration, steps))


def apply_action(system: SystemSnapshot, action: Any) -> None:
    """Apply ``action`` to ``system`` (a parameter update or a configuration change)."""
    if action.kind == "parameter_update":
        system.set_params(action.module, dict(action.set or {}))
    else:
        system.apply_configuration(action.to)


def action_target(system: SystemSnapshot, action: Any) -> str:
    """The configuration ``system`` is in after ``action``."""
    return system.configuration if action.kind == "parameter_update" else action.to


def _v(system: SystemSnapshot) -> float:
    x = np.asarray(system.state_error(), dtype=float).ravel()
    return float(x @ x)


def check_action_stability(
    system: ManagedSystem,
    action: Any,
    *,
    margin: float,
    alpha: float,
    horizon_steps: int,
    floor: float,
    loop_steps: int = 1,
    marginal: str = "warning",
) -> StabilityVerdict:
    """Stability filter of Algorithm 1 step 7b for one action on the live system.

    Tries Eq. 21 with the target configuration's linearization; if the system has
    none, runs the Lyapunov test on a snapshot. An action that passes is then
    checked over the whole loop (:func:`whole_loop_check`): the target's
    numerical linearization at the current operating point, every module's state.
    The live ``system`` is never modified.

    Parameters
    ----------
    system : LiveSystem
        The running system (see docs/develop.md).
    action : archself.model.architecture.Action
        The candidate action.
    margin, alpha : float
        ε and α (``runtime.stability``).
    horizon_steps : int
        Steps of the Lyapunov rollout.
    floor : float
        V floor of the Lyapunov test.
    """
    try:
        if action.kind == "parameter_update":
            snap = system.snapshot()
            apply_action(snap, action)
            A = snap.linearization(snap.configuration)
        else:
            snap = None
            A = system.linearization(action.to)
    except Exception as exc:  # noqa: BLE001 - fail closed
        return StabilityVerdict(False, "error", None, -margin, f"linearization failed: {exc}")
    if A is not None:
        verdict = eigenvalue_margin(A, margin)
        return whole_loop_check(system, action, verdict, loop_steps, marginal, horizon_steps)
    try:
        if snap is None:
            snap = rollout_copy(system, action_target(system, action), horizon_steps)
            apply_action(snap, action)
        v = [_v(snap)]
        for _ in range(horizon_steps):
            snap.step()
            v.append(_v(snap))
    except Exception as exc:  # noqa: BLE001 - fail closed
        return StabilityVerdict(False, "error", None, None, f"Lyapunov rollout failed: {exc}")
    verdict = lyapunov_decrease(v, alpha, floor)
    return whole_loop_check(system, action, verdict, loop_steps, marginal, horizon_steps)


def whole_loop_check(
    system: ManagedSystem,
    action: Any,
    passed: StabilityVerdict,
    steps: int = 1,
    marginal: str = "warning",
    horizon: int = 20,
) -> StabilityVerdict:
    """``passed`` (the declared models' or the rollout's verdict) unless the whole loop objects.

    The loop ``action`` leads to is linearized numerically around the current
    state on a snapshot (``system.whole_loop``: every active module's state, over
    ``steps`` steps; a parameter update on a copy with the values set). A mode
    with |λ| > 1 + 1e-4 per step rejects the action, naming the modules it lives
    in; a marginal mode rejects it when ``marginal`` is ``"error"``. When the loop
    cannot be linearized here (a system without ``whole_loop``, a discontinuity,
    a step that raised) the Lyapunov test runs on the loop's state instead
    (:func:`loop_divergence`).
    """
    if not passed.ok or not hasattr(system, "whole_loop"):
        return passed
    from archself.linear.closed_loop import MARGINAL_TOL

    system = cast(LoopSystem, system)

    try:
        if action.kind == "parameter_update":
            snap = system.snapshot()
            apply_action(snap, action)
            loop = snap.whole_loop(None, steps)
        else:
            loop = system.whole_loop(action.to, steps)
        if loop.problems:
            return loop_divergence(system, action, horizon, passed, loop.problems[0])
        worst, flat, growing = loop.modes(MARGINAL_TOL)
    except Exception:  # noqa: BLE001 - no whole-loop verdict: the other one stands
        return passed
    if growing:
        mode = growing[0]
        return StabilityVerdict(
            False, "whole-loop", worst, 1.0,
            f"max |λ| = {worst:.6g} per step > 1 over the whole loop; the mode lives in "
            f"{mode.where()}")
    if flat and marginal == "error":
        return StabilityVerdict(
            False, "whole-loop", worst, 1.0,
            f"a marginal mode (|λ| = {flat[0].magnitude:.6f} per step) lives in "
            f"{flat[0].where()} (runtime.stability.marginal: error)")
    return passed


#: Relative size of the loop-state offset of :func:`loop_divergence`.
OFFSET = 1e-3


def _loop_state(system: LoopSystem) -> np.ndarray:
    """Every active module's :meth:`~archself.modules.base.RuntimeModule.state`, stacked."""
    mods = system.modules.values()
    parts = [type(m).state(m) for m in mods]
    return np.concatenate(parts) if parts else np.zeros(0)


def loop_divergence(
    system: LoopSystem, action: Any, horizon: int, passed: StabilityVerdict, why: str
) -> StabilityVerdict:
    """The Lyapunov test on the loop's whole state, where the loop cannot be linearized.

    Two rollouts of ``horizon`` steps after ``action`` on snapshots (the same noise):
    one from the current state, one with every module's state offset by
    1e-3·max(1, |x|). ``V_t = ‖x'_t − x_t‖²``, the squared distance of the two loop
    states (every module's state, not only the objective's error), must not grow
    over the horizon: a mode the objective does not watch diverges here too. V
    staying level (a marginal mode) passes; growth past ``V_0`` with a positive
    slope over the second half rejects the action. ``passed`` stands otherwise.
    """
    try:
        runs = []
        for shift in (False, True):
            snap = system.snapshot()
            apply_action(snap, action)
            if shift:
                for m in snap.modules.values():
                    x = type(m).state(m)
                    if x.size:
                        type(m).set_state(m, x + OFFSET * np.maximum(1.0, np.abs(x)))
            states = [_loop_state(snap)]
            for _ in range(horizon):
                snap.step()
                states.append(_loop_state(snap))
            runs.append(np.array(states))
        v = np.sum((runs[1] - runs[0]) ** 2, axis=1)
    except Exception:  # noqa: BLE001 - sizes changed, a step raised: the other verdict stands
        return passed
    if not np.all(np.isfinite(v)):
        return StabilityVerdict(False, "whole-loop", None, None,
                                f"the loop's state is not finite in the rollout ({why})")
    tail = v[v.size // 2:]
    if v[-1] > v[0] and _slope(tail) > 0:
        return StabilityVerdict(
            False, "whole-loop", float(v[-1] / v[0]) if v[0] else None, 1.0,
            f"the loop's state diverges from its neighbour: ‖Δx‖² grows {v[-1] / v[0]:.4g}-fold "
            f"in {horizon} steps (not linearizable here: {why})")
    return passed
