"""Checks of the modules: registered types, their parameters and ranges, residuals, limits.

Rules ``unknown-type``, ``parameter`` (required, declared, inside the declared range
and the file's own space), ``residual``, the ``requires``/``excludes`` names of a
module's constraints, and ``limits`` (``constraints.blocks``). The range helpers
:func:`outside_declared` and :func:`outside_space` serve the action rules too.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from archself.check.context import Context, closest, refers
from archself.io.yaml_source import Path_
from archself.model.architecture import Parameter

__all__ = [
    "check_limits",
    "check_parameters",
    "check_types",
    "outside_declared",
    "outside_space",
    "wrong_kind",
]


def _known_types_text(key: str, known: list[str]) -> str:
    """The registered types of ``key``'s namespace (``sensor.*``), or all when it has none.

    Types of other namespaces (another plugin's) do not change the message.
    """
    space = key.partition(".")[0] + "."
    same = [k for k in known if k.startswith(space)]
    if same:
        return f"{space}* types: {', '.join(same)}"
    return f"known types: {', '.join(known)}"


def check_types(ctx: Context) -> None:
    from archself import registry

    known = registry.known_types()
    legacy: set[str] = set()
    for name, mod in ctx.arch.modules.items():
        cls = ctx.types[name]
        if cls is None:
            close = closest(mod.type, known)
            hint = f"did you mean '{close}'? " if close else ""
            ctx.add(
                "error", "unknown-type",
                f"unknown module type '{mod.type}'; {hint}{_known_types_text(mod.type, known)}",
                ("modules", name, "type"),
            )
            continue
        if registry.LEGACY.get(mod.type) and mod.type not in legacy:
            legacy.add(mod.type)  # once per type: the old plugin API, converted
            ctx.add("warning", "plugin-api", registry.LEGACY[mod.type], ("modules", name, "type"))
        values = {k: p.value for k, p in mod.params.items()}
        for pname, why in cls.param_warnings(values, mod.residual and mod.residual.signal):
            ctx.add("warning", "parameter", why, ("modules", name, "params", pname))
        declared = cls.parameters
        if declared is not None:
            for pname, spec in declared.items():
                if spec.required and pname not in mod.params:
                    ctx.add("error", "parameter",
                            f"type '{mod.type}' needs parameter '{pname}'", ("modules", name),
                            key=True)
            takes = tuple(declared)
            for pname in mod.params:
                if pname in takes:
                    _declared_range(ctx, mod.type, pname, declared[pname], mod.params[pname],
                                    ("modules", name, "params", pname))
                    continue
                near = closest(pname, takes)
                hint = (f"did you mean '{near}'?" if near
                        else f"it takes: {', '.join(takes) or 'none'}")
                ctx.add("error", "parameter",
                        f"type '{mod.type}' has no parameter '{pname}'; {hint}",
                        ("modules", name, "params", pname), key=True)
        if mod.residual is not None and mod.residual.signal not in cls.residual_signals:
            offered = ", ".join(cls.residual_signals) or "none"
            ctx.add(
                "error", "residual",
                f"type '{mod.type}' publishes no residual signal '{mod.residual.signal}' "
                f"(it offers: {offered})",
                ("modules", name, "residual", "signal"),
            )
        for dep in ("requires", "excludes"):
            for i, other in enumerate(getattr(mod.constraints, dep)):
                refers(ctx, other, ("modules", name, "constraints", dep, i))


def _numbers(value: Any) -> Iterator[float]:
    """The numbers of a parameter value: itself, or the entries of a list or matrix."""
    if isinstance(value, bool):
        return
    if isinstance(value, (int, float)):
        yield value
    elif isinstance(value, list):
        for v in value:
            yield from _numbers(v)


def outside_declared(spec: Any, value: Any) -> str | None:
    """Why a number of ``value`` is outside the range ``spec`` (a ``Param``) declares."""
    lo, hi = getattr(spec, "min", None), getattr(spec, "max", None)
    if lo is None and hi is None:
        return None
    for x in _numbers(value):
        if (lo is not None and x < lo) or (hi is not None and x > hi):
            unit = f" {spec.unit}" if getattr(spec, "unit", "") else ""
            rng = f"[{'-∞' if lo is None else f'{lo:g}'}, {'∞' if hi is None else f'{hi:g}'}]"
            return f"{x:g} is outside {rng}{unit}"
    return None


def wrong_kind(spec: Any, value: Any) -> str | None:
    """Why ``value`` cannot be the parameter ``spec`` (a ``Param``) declares, or None.

    The kind is the default's: a number's takes numbers (or lists of them), a text's a
    text, a flag's a flag (or a number); a parameter without a default is not checked.
    (A string for a number validated and failed only when the module was built.)

    Examples
    --------
    >>> from archself.modules.base import Param
    >>> wrong_kind(Param(1.0), "abc")
    'expected a number (or a list of numbers), got string "abc"'
    >>> wrong_kind(Param(1.0), [1.0, 2.0]) is None
    True
    """
    from archself.io.yaml_source import describe
    from archself.modules.base import REQUIRED

    default = getattr(spec, "default", None)
    if default is None or default is REQUIRED:
        return None
    if isinstance(default, bool):
        ok, want = isinstance(value, (bool, int, float)), "true or false"
    elif isinstance(default, (int, float)):
        ok, want = not isinstance(value, (bool, str)), "a number (or a list of numbers)"
    elif isinstance(default, str):
        ok, want = isinstance(value, str), "a string"
    else:
        return None
    return None if ok else f"expected {want}, got {describe(value)}"


def _declared_range(ctx: Context, type_: str, pname: str, spec: Any, p: Parameter,
                    path: Path_) -> None:
    if why := wrong_kind(spec, p.value):
        ctx.add("error", "parameter", f"{why} (type '{type_}', parameter '{pname}')",
                (*path, "value"))
        return
    for key, value in (("value", p.value), ("min", p.min), ("max", p.max)):
        if value is None:
            continue
        why = outside_declared(spec, value)
        if why:
            ctx.add("error", "parameter",
                    f"{why}, the range type '{type_}' declares for '{pname}'", (*path, key))


def outside_space(p: Parameter, value: Any) -> str | None:
    """Why ``value`` is outside the space of ``p``, or None."""
    if p.choices is not None:
        return None if value in p.choices else f"not one of {p.choices}"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    if p.min is not None and value < p.min:
        return f"below min {p.min:g}"
    if p.max is not None and value > p.max:
        return f"above max {p.max:g}"
    return None


def check_parameters(ctx: Context) -> None:
    for name, mod in ctx.arch.modules.items():
        for pname, p in mod.params.items():
            path = ("modules", name, "params", pname)
            if p.min is not None and p.max is not None and p.min > p.max:
                ctx.add("error", "parameter", f"min {p.min:g} > max {p.max:g}", (*path, "min"))
                continue
            why = outside_space(p, p.value)
            if why:
                ctx.add("error", "parameter",
                        f"nominal value {p.value!r} is outside the parameter space: {why}",
                        (*path, "value"))


def check_limits(ctx: Context) -> None:
    ids = [a.id for a in ctx.arch.actions]
    for name, mod in ctx.arch.modules.items():
        cons = mod.constraints
        path: Path_ = ("modules", name, "constraints", "blocks")
        if cons.blocks and not cons.limits:
            ctx.add("warning", "limits", "'blocks' has no effect without 'limits'", path)
        for key in cons.limits:  # anything else was never judged, silently
            if not key.startswith(("max_", "min_")) or key in ("max_", "min_"):
                ctx.add("error", "limits", f"expected a limit named max_<x> or min_<x> (x a "
                        f"parameter or a signal of '{name}'), got '{key}'",
                        ("modules", name, "constraints", "limits", key), key=True)
        if cons.blocks == "all":
            continue
        for j, aid in enumerate(cons.blocks):
            if aid not in ids:
                close = closest(aid, ids)
                hint = f" (did you mean '{close}'?)" if close else ""
                ctx.add("error", "reference", f"unknown action '{aid}'{hint}", (*path, j))
