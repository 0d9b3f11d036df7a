"""Strategies: the file's trees of tactics, run by the MAPE-K loop one tactic per cycle.

A strategy (:mod:`archself.model.architecture`) starts when its module is a candidate and
its first step's ``when`` holds, and no other strategy runs. While it runs it replaces
the Plan stage's scoring: each cycle :meth:`Strategies.cycle` either

- *executes* the current step's tactic — when its ``when`` holds, the learning review
  does not hold it back (``runtime.learning``: a tactic that failed in this context, as
  a single action) and the planner's own checks pass (applicable, available,
  constraints and budgets, limits, dwell, stability; ``Planner.check``) — then waits
  ``settle_s``;
- *waits* for the tactic to become admissible, at most ``timeout_s`` (default: one
  cycle), then takes the ``failure`` branch;
- after settling, checks ``post`` (r_i of the strategy's module, J_obs, the
  configuration) and takes the ``success`` or ``failure`` branch: the next step (tried
  in the same cycle), ``done``, or ``rollback`` (a switch back to the configuration
  the strategy started in, if the system left it).

Its state (strategy, step, phase, times, the configuration it started in) is kept
here, in the loop's Knowledge of the run; every cycle it acts in carries a note in the
decision log (``strategy <name>, step <step>: …``), which ``explain`` shows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from archself.contracts import ManagedSystem
from archself.model.architecture import Action, Architecture, Condition, Strategy
from archself.runtime.knowledge import ActionEvaluation

__all__ = ["Running", "Strategies", "holds"]


def holds(cond: Condition | None, configuration: str, r_i: float, j_obs: float) -> bool:
    """Whether every given part of ``cond`` holds (None: always)."""
    if cond is None:
        return True
    if cond.configuration is not None and configuration not in cond.configuration:
        return False
    if cond.residual_above is not None and not r_i > cond.residual_above:
        return False
    if cond.residual_below is not None and not r_i < cond.residual_below:
        return False
    return not (cond.objective_below is not None and not j_obs < cond.objective_below)


@dataclass
class Running:
    """The state of the strategy that runs."""

    name: str
    step: str
    phase: str  # "execute" or "settle"
    since: float  # when the step began (execute) or its tactic ran (settle)
    origin: str  # the configuration the strategy started in


class Strategies:
    """The strategies of a file and the one that runs.

    Parameters
    ----------
    arch : Architecture
        Reads ``strategies`` and ``actions``.
    planner : Planner
        Its checks admit a tactic (``Planner.check``).
    """

    def __init__(self, arch: Architecture, planner: Any) -> None:
        self.arch = arch
        self.planner = planner
        self.by_id = {a.id: a for a in arch.actions}
        self.period = arch.runtime.period_s
        self.running: Running | None = None
        self._rollbacks: dict[tuple[str, str], Action] = {}

    def wants(self, candidates: list[str], state: Any, record: Any) -> bool:
        """Whether a strategy runs, or one starts now (its module a candidate, ``when`` holds)."""
        if self.running is not None:
            return True
        for name, st in self.arch.strategies.items():
            first = st.steps.get(st.start)
            if st.module in candidates and first is not None and holds(
                first.when, state.configuration, abs(state.r.get(st.module, 0.0)), record.j_obs
            ):
                self.running = Running(name, st.start, "execute", state.t, state.configuration)
                return True
        return False

    def cycle(
        self, system: ManagedSystem, state: Any, record: Any
    ) -> tuple[list[ActionEvaluation], Action | None, ActionEvaluation | None]:
        """One cycle of the running strategy: (evaluations, tactic to execute, its evaluation)."""
        run = self.running
        assert run is not None
        st: Strategy = self.arch.strategies[run.name]
        notes: list[str] = []
        out: tuple[list[ActionEvaluation], Action | None, ActionEvaluation | None] = ([], None,
                                                                                      None)
        r_i = abs(state.r.get(st.module, 0.0))
        for _ in range(len(st.steps) + 1):  # branches within one cycle; no cycle without exit
            step = st.steps[run.step]
            where = f"strategy {run.name}, step {run.step}"
            if run.phase == "settle":
                if state.t - run.since < step.settle_s - 1e-9:
                    notes.append(f"{where}: settling ({state.t - run.since:.3g} of "
                                 f"{step.settle_s:g} s)")
                    break
                ok = holds(step.post, state.configuration, r_i, record.j_obs)
                nxt = step.success if ok else step.failure
                notes.append(f"{where}: post-check {'passed' if ok else 'FAILED'} → {nxt}")
            else:
                action = self.by_id[step.tactic]
                ev = ActionEvaluation(action.id, st.module, action.kind, action.to,
                                      z=abs(state.z.get(st.module, 0.0)), cost=action.cost)
                if not holds(step.when, state.configuration, r_i, record.j_obs):
                    ev.rejected, ev.detail = "not applicable", f"{where}: 'when' does not hold"
                elif not self._held(action, state, ev):
                    ev.rejected, ev.detail = self.planner.check(action, state, system)
                out[0].append(ev)
                if ev.rejected is None:
                    notes.append(f"{where}: executes {action.id}")
                    run.phase, run.since = "settle", state.t
                    out = (out[0], action, ev)
                    break
                limit = step.timeout_s if step.timeout_s is not None else 0.0
                if state.t - run.since < limit - 1e-9:
                    notes.append(f"{where}: waiting for {action.id} ({ev.rejected})")
                    break
                nxt = step.failure
                notes.append(f"{where}: {action.id} not admissible ({ev.rejected}) → {nxt}")
            if nxt == "done":
                self.running = None
                break
            if nxt == "rollback":
                self.running = None
                if state.configuration != run.origin:
                    back = self._rollback(st, run, state.configuration)
                    ev = ActionEvaluation(back.id, st.module, back.kind, back.to, cost=0.0)
                    out[0].append(ev)
                    out = (out[0], back, ev)
                    notes.append(f"strategy {run.name}: rollback to {run.origin}")
                break
            run.step, run.phase, run.since = nxt, "execute", state.t
        record.note = "; ".join(notes)
        return out

    def _held(self, action: Action, state: Any, ev: ActionEvaluation) -> bool:
        """The learning review of a tactic (``runtime.learning``), as of a single action.

        A tactic whose last outcome in this context (the action's module, the
        configuration: where the loop's Execute stage measures every executed action's
        outcome) failed is ``held back`` for ``hold_s``: the step waits, then takes its
        ``failure`` branch. Its learned record goes to the log.
        """
        learning = self.planner.learning
        if learning is None:
            return False
        _, held, ev.learned = learning.review(action.id, action.module, state.configuration,
                                              state.t)
        if held:
            ev.rejected, ev.detail = "held back", held
        return bool(held)

    def _rollback(self, st: Strategy, run: Running, current: str) -> Action:
        key = (run.name, run.origin)
        back = self._rollbacks.get(key)
        if back is None:
            back = self._rollbacks[key] = Action.model_validate({
                "id": f"{run.name}:rollback", "module": st.module, "kind": "substitute",
                "to": run.origin, "cost": 0.0,
                "improvement": {"method": "sensitivity", "delta_theta": 0.0},
                "description": f"strategy {run.name}: back to {run.origin}",
            })
        return back
