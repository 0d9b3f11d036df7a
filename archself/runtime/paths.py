"""Paths to a configuration: a detour when an action's target is unavailable or unstable.

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
may), and, with quality attributes (``qualities``, :mod:`archself.runtime.utility`),
for every admissible action, since the preferences may rank one above ``T``.

Each detour or alternative becomes an action ``<a.id>@<C>`` — ``a`` with ``to = C``
and no ``applies_in`` — that the planner evaluates like a declared one: availability,
constraints and budgets, limits, dwell, the same Δ estimate (the remedy of ``m_i`` is
kept), the score plus ``μ·(U(C) − U(T))`` and the stability filter. A declared action
with the same score wins the tie (it comes first). ``runtime.ablation.paths: false``
switches both off.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

from archself.model.architecture import Action, Architecture

__all__ = ["Detours", "detour_id"]

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
