"""The constraints C(a, θ, e) ≤ 0 of Eq. 27 that a target architecture must meet.

:func:`budget_violations` (Σ resources ≤ max per budget), :func:`constraint_violations`
(the modules' ``requires``/``excludes``) and :func:`declared_ranges` (the ranges the
module types declare for the parameters an update sets). The
:class:`~archself.runtime.planner.Planner` checks them per candidate action.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from archself.model.architecture import Architecture

__all__ = ["budget_violations", "constraint_violations", "declared_ranges"]


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
    from archself import registry
    from archself.modules.base import Param

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
