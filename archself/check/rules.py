"""The semantic rules of ``archself validate`` (listed in :mod:`archself.check`) and :func:`check`.

The context of the checks: the loaded file, the types of its modules, the findings.
Every rule of :mod:`archself.check` takes a :class:`Context` and adds its findings
with :meth:`Context.add`, which locates them in the source (file, line, column).
:func:`refers` reports an unknown module or configuration name with "did you mean";
:func:`did_you_mean` is that hint.

Checks of the modules: registered types, their parameters and ranges, residuals, limits.

Rules ``unknown-type``, ``parameter`` (required, declared, inside the declared range
and the file's own space), ``residual``, the ``requires``/``excludes`` names of a
module's constraints, and ``limits`` (``constraints.blocks``). The range helpers
:func:`outside_declared` and :func:`outside_space` serve the action rules too.

Checks of the graph: edges, ports, the influence matrix W and every configuration.

Rules ``self-loop``, ``duplicate``, ``weight``, ``signal`` (edges), ``port``
(:mod:`archself.model.architecture`), ``spectral-radius`` and ``singular`` (ρ(W), by
:func:`spectrum_summary`), and per configuration ``initial``, ``reference``,
``incomplete`` (inputs delivered, connected, the objective's modules, roles),
``double-input``, ``module-constraint``, ``algebraic-loop``
(:func:`archself.system.dataflow.algebraic_loop`) and ``budget``.

Checks of what runs: actions, scenario faults, the work caps, the objective, stability.

Rules ``action`` (targets, kinds against the change, parameter updates in bounds),
``fault`` (targets and kinds a type accepts), ``work`` (a run's steps, recorded
bytes and module-steps under :data:`MAX_RUN_STEPS`, :data:`MAX_RUN_BYTES`,
:data:`MAX_RUN_WORK`; :func:`run_estimate`), ``clock`` (a scenario's duration, the
MAPE-K period and every period parameter at least one step), ``reference``/``objective``
(the objective's signals and components), ``build`` (each module's memory under
:data:`MAX_MODULE_BYTES` by its type's ``memory_estimate``, then its type's
``check_params``, for the nominal values and every parameter update; only on a file
without errors) and the opt-in ``stability`` (:mod:`archself.check.stability`, only on a file
without errors).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from archself import registry
from archself.findings import Finding
from archself.io.yaml_source import Path_, describe, dotted
from archself.model.architecture import EXITS, Architecture, Parameter
from archself.model.loader import Loaded, gc_paused
from archself.system.dataflow import algebraic_loop

__all__ = [
    "Context", "MAX_MODULE_BYTES", "MAX_RUN_BYTES", "MAX_RUN_STEPS", "MAX_RUN_WORK",
    "active_edges", "check", "check_actions", "check_build", "check_clock",
    "check_configurations", "check_edges", "check_limits", "check_objective",
    "check_parameters", "check_ports", "check_scenarios", "check_stability",
    "check_subsystems", "check_types", "check_weights", "check_work", "did_you_mean",
    "has_errors", "outside_declared", "outside_space", "refers", "run_estimate",
    "spectrum_summary", "wrong_kind"
]


class Context:
    """A loaded architecture under check: ``arch``, ``src``, ``types`` (name → class), ``out``."""

    def __init__(self, loaded: Loaded) -> None:
        self.arch: Architecture = loaded.arch
        self.src = loaded.source
        self.out: list[Finding] = []
        modules = self.arch.modules
        by_type = {t: registry.lookup(t) for t in dict.fromkeys(m.type for m in modules.values())}
        self.types: dict[str, Any] = {name: by_type[mod.type] for name, mod in modules.items()}

    def add(self, sev: str, code: str, msg: str, path: Path_, *, key: bool = False) -> None:
        line, col = self.src.locate(path, key=key)
        self.out.append(Finding(sev, code, msg, dotted(path), self.src.file, line, col))  # type: ignore[arg-type]


def did_you_mean(word: str, options: Any, form: str = "did you mean '{}'?") -> str:
    """``form`` filled with the option closest to ``word`` (difflib), or ``""``.

    Examples
    --------
    >>> did_you_mean("gsp", ["gps", "imu"], "; did you mean '{}'?"), did_you_mean("x", ["gps"])
    ("; did you mean 'gps'?", '')
    """
    import difflib

    close = difflib.get_close_matches(word, list(options), n=1)
    return form.format(close[0]) if close else ""


def refers(ctx: Context, name: str, path: Path_, what: str = "module") -> bool:
    """Whether ``name`` is a declared module (or configuration); else an error finding."""
    pool = ctx.arch.modules if what == "module" else ctx.arch.configurations
    if name in pool:
        return True
    hint = did_you_mean(name, pool, "; did you mean '{}'?")
    ctx.add("error", "reference", f"unknown {what} '{name}'{hint}", path)
    return False


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
    known = registry.known_types()
    legacy: set[str] = set()
    for name, mod in ctx.arch.modules.items():
        cls = ctx.types[name]
        if cls is None:
            hint = did_you_mean(mod.type, known, "did you mean '{}'? ")
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
                hint = did_you_mean(pname, takes) or f"it takes: {', '.join(takes) or 'none'}"
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
                hint = did_you_mean(aid, ids, " (did you mean '{}'?)")
                ctx.add("error", "reference", f"unknown action '{aid}'{hint}", (*path, j))


def check_edges(ctx: Context) -> None:
    seen: dict[tuple[str, str, str, str], int] = {}
    modules = ctx.arch.modules
    ports = ctx.arch.edge_ports  # named ports: archself.model.architecture
    for i, e in enumerate(ctx.arch.edges):
        if e.source in modules and e.target in modules:  # the common case: no call
            ok = True
        else:
            ok = (refers(ctx, e.source, ("edges", i, "from"))
                  & refers(ctx, e.target, ("edges", i, "to")))
        if e.source == e.target:
            ctx.add("error", "self-loop", f"edge from '{e.source}' to itself", ("edges", i))
        key = (e.source, e.target, e.carries, ports.into(i))
        if key in seen:
            ctx.add("error", "duplicate",
                    f"duplicate edge {e.source} -> {e.target} carrying '{e.carries}' "
                    f"(first at edges[{seen[key]}])", ("edges", i))
        seen.setdefault(key, i)
        if ok and e.carries:  # named ports: archself.model.architecture
            src = ctx.types.get(e.source)
            if (src is not None and src.outputs and e.carries not in src.outputs
                    and ports.from_port[i] is None):
                ctx.add("error", "signal",
                        f"'{e.source}' ({ctx.arch.modules[e.source].type}) does not output "
                        f"'{e.carries}'; it outputs: {', '.join(src.outputs)}",
                        ("edges", i, "carries"))
            dst = ctx.types.get(e.target)
            if (dst is not None and (dst.inputs or dst.optional_inputs)
                    and ports.to_port[i] is None
                    and e.carries not in dst.inputs + dst.optional_inputs):
                ctx.add("warning", "signal",
                        f"'{e.target}' ({ctx.arch.modules[e.target].type}) does not use "
                        f"'{e.carries}'; it takes: {', '.join(dst.inputs + dst.optional_inputs)}",
                        ("edges", i, "carries"))


def spectrum_summary(
    names: list[str], edges: list[tuple[str, str, float]]
) -> tuple[float, bool]:
    """ρ(W) of a weighted digraph, and whether ``I − Wᵀ`` is singular.

    ρ is :func:`archself.runtime.influence.spectral_radius` (the runtime's: dense
    eigenvalues up to 400 modules, per strongly connected component and ARPACK
    beyond). Self-loops are left out (the ``self-loop`` rule reports them). W has
    the eigenvalue 1 only if ρ ≥ 1, but the LU factorization the runtime uses
    (:class:`~archself.runtime.influence.InfluenceSolver`) also refuses an ``I − Wᵀ``
    that is singular in floating point (weights like 1e9 beside 0.1: condition ~1e18,
    which validated and then stopped the run with exit 3): it is tried whatever ρ,
    by the runtime's rule (:func:`~archself.runtime.influence.is_singular`). Up to
    :data:`~archself.runtime.influence.DENSE_MAX` modules W is a dense numpy array and
    neither needs scipy; above, W is sparse and scipy is imported.

    Returns
    -------
    rho : float
        The spectral radius ρ(W).
    singular : bool
        True when I − Wᵀ is singular (W has the eigenvalue 1) or numerically so.

    Examples
    --------
    >>> rho, singular = spectrum_summary(
    ...     ["a", "b", "c"], [("a", "b", 0.5), ("b", "a", 0.5), ("b", "c", 2.0)])
    >>> round(rho, 12), singular
    (0.5, False)
    """
    import numpy as np

    from archself.runtime.influence import DENSE_MAX, is_singular, spectral_radius

    index = {name: k for k, name in enumerate(names)}
    rows, cols, data = [], [], []
    for source, target, weight in edges:  # finite weights: the schema says so
        j, i = index.get(source), index.get(target)
        if j is not None and i is not None and j != i:
            rows.append(j)
            cols.append(i)
            data.append(float(weight))
    n = len(names)
    values = np.asarray(data, dtype=float)
    if n <= DENSE_MAX:
        W: Any = np.zeros((n, n))
        np.add.at(W, (rows, cols), values)  # parallel edges add up
    else:
        import scipy.sparse

        W = scipy.sparse.coo_matrix((values, (rows, cols)), shape=(n, n)).tocsr()
    return spectral_radius(W), is_singular(W)


def check_ports(ctx: Context) -> None:
    """Named ports (:class:`~archself.model.architecture.EdgePorts`): an edge names a signal,
    ``carries`` agrees with the port in ``from``, the ports exist on the types. (Ports driven
    twice and undriven required inputs are the ``double-input`` and ``incomplete`` rules.)"""
    arch, ports = ctx.arch, ctx.arch.edge_ports
    for i, (e, from_port, to_port) in enumerate(zip(arch.edges, ports.from_port, ports.to_port,
                                                          strict=True)):
        if not e.carries:
            ctx.add("error", "port", "the edge names no signal: give 'carries', or the ports as "
                    "'from: module.port' / 'to: module.port'", ("edges", i))
            continue
        if from_port is None and to_port is None:  # the common case: nothing more to check
            continue
        if from_port is not None and e.carries != from_port:
            ctx.add("error", "port", f"'carries: {e.carries}' contradicts the port in 'from' "
                    f"('{e.source}.{from_port}'); give one of them", ("edges", i, "carries"))
        src, dst = ctx.types.get(e.source), ctx.types.get(e.target)
        for end, name, port, have in (
                ("from", e.source, from_port, src.outputs if src else ()),
                ("to", e.target, to_port, dst.inputs + dst.optional_inputs if dst else ())):
            if port is not None and have and port not in have:
                hint = did_you_mean(port, have) or f"it has: {', '.join(have)}"
                side = "output" if end == "from" else "input"
                ctx.add("error", "port", f"'{name}' ({arch.modules[name].type}) has no {side} "
                        f"port '{port}'; {hint}", ("edges", i, end))


def check_weights(ctx: Context) -> None:
    arch = ctx.arch
    edges = [(e.source, e.target, e.weight) for e in arch.edges]
    rho, singular = spectrum_summary(list(arch.modules), edges)
    limit = arch.runtime.max_spectral_radius
    if singular and rho < 1.0 - 1e-9:
        top = max((abs(float(e.weight)) for e in arch.edges), default=0.0)
        ctx.add("error", "singular",
                "I − Wᵀ is singular in floating point (the weights span too many orders of "
                f"magnitude, the largest {top:g}): z = (I − Wᵀ)⁻¹ r cannot be computed "
                "(Eq. 14); lower the largest weights", ("edges",), key=True)
    elif singular:
        ctx.add("error", "singular",
                "I − Wᵀ is singular (W has the eigenvalue 1): z = (I − Wᵀ)⁻¹ r is undefined "
                "(Eq. 14); lower the weights on the cycles", ("edges",), key=True)
    elif rho >= 1.0:
        ctx.add("error", "spectral-radius",
                f"spectral radius ρ(W) = {rho:.4g} ≥ 1: influence z = (I − Wᵀ)⁻¹ r is unbounded "
                "or I − Wᵀ is singular (Eq. 13–14); lower the weights on the cycles",
                ("edges",), key=True)
    elif rho >= limit:
        ctx.add("error", "spectral-radius",
                f"spectral radius ρ(W) = {rho:.4g} exceeds runtime.max_spectral_radius = {limit}",
                ("edges",), key=True)


def active_edges(arch: Architecture, conf_name: str) -> list[tuple[int, Any]]:
    """``(index, edge)`` of the edges active in configuration ``conf_name``."""
    conf = arch.configurations[conf_name]
    active = set(conf.modules) & set(arch.modules)
    off = {tuple(p) for p in conf.disabled_edges}
    return [
        (i, e) for i, e in enumerate(arch.edges)
        if e.source in active and e.target in active and (e.source, e.target) not in off
    ]


def check_subsystems(ctx: Context) -> None:
    """Subsystem modes name known modules, a module in one mode of one subsystem; a
    composed configuration names known subsystems and modes, and lists no subsystem's
    module among its own."""
    arch = ctx.arch
    owner: dict[str, tuple[str, str]] = {}  # module -> (subsystem, mode)
    for sname, sub in arch.subsystems.items():
        if sname in arch.modules or sname == arch.name:
            ctx.add("error", "subsystem", f"subsystem '{sname}' has the name of a "
                    f"{'module' if sname in arch.modules else 'system'} (one ROS 2 part "
                    "each)", ("subsystems", sname), key=True)
        for mode, mods in sub.modes.items():
            for i, m in enumerate(mods):
                at: Path_ = ("subsystems", sname, "modes", mode, i)
                if not refers(ctx, m, at):
                    continue
                s0, m0 = owner.setdefault(m, (sname, mode))
                if (s0, m0) != (sname, mode):
                    where = f"mode '{m0}'" if s0 == sname else f"subsystem '{s0}'"
                    ctx.add("error", "subsystem", f"'{m}' is already in {where}: a module "
                            "belongs to one mode of one subsystem", at)
    for cname, conf in arch.configurations.items():
        base: Path_ = ("configurations", cname)
        for sname, mode in (conf.modes or {}).items():
            known = arch.subsystems.get(sname)
            pool = arch.subsystems if known is None else known.modes
            if known is not None and mode in pool:
                continue
            word = sname if known is None else mode
            hint = did_you_mean(word, pool, "; did you mean '{}'?")
            what = (f"unknown subsystem '{sname}'" if known is None
                    else f"subsystem '{sname}' has no mode '{mode}' (modes: "
                    f"{', '.join(pool)})")
            ctx.add("error", "subsystem", f"{what}{hint}", (*base, "modes", sname),
                    key=known is None)
        for i, m in enumerate(conf.own_modules if conf.modes is not None else []):
            if m in owner:
                ctx.add("error", "subsystem", f"'{m}' is in subsystem '{owner[m][0]}': a "
                        "composed configuration picks it by its mode", (*base, "modules", i))


def check_configurations(ctx: Context) -> None:
    """Rules on every configuration: one initial, its modules, their inputs, the data flow."""
    arch = ctx.arch
    initial = [n for n, c in arch.configurations.items() if c.initial]
    if len(initial) > 1:
        ctx.add("error", "initial",
                f"{len(initial)} configurations are marked initial ({', '.join(initial)}); "
                "mark one", ("configurations", initial[1], "initial"))
    obj = arch.runtime.objective
    needed: dict[str, str] = {}  # module -> the objective key that reads it
    for key in ("actual", "reference"):
        mod = getattr(obj, key).partition(".")[0]
        if mod in arch.modules:
            needed.setdefault(mod, key)
    first = arch.initial_configuration()
    roles = {ctx.types[m].role for m in arch.configurations[first].modules
             if ctx.types.get(m) is not None}
    for cname in arch.configurations:
        names = _members(ctx, cname, needed, first, roles)
        edges = active_edges(arch, cname)
        _inputs(ctx, cname, names, edges)
        _flow(ctx, cname, names, edges)


def _members(
    ctx: Context, cname: str, needed: dict[str, str], first: str, roles: set[str]
) -> list[str]:
    """A configuration's modules: known, the objective's, the initial one's roles, once
    each, its disabled edges; the known ones."""
    arch = ctx.arch
    conf = arch.configurations[cname]
    obj = arch.runtime.objective
    base: Path_ = ("configurations", cname)
    edge_pairs = {(e.source, e.target) for e in arch.edges}
    names = [m for m in conf.modules if m in arch.modules]
    if len(names) != len(conf.modules):
        for i, m in enumerate(conf.modules):
            refers(ctx, m, (*base, "modules", i))
    for mod, key in needed.items():
        if mod not in conf.modules:
            ctx.add("error", "incomplete",
                    f"configuration '{cname}' lacks '{mod}', which runtime.objective.{key} "
                    f"reads ('{getattr(obj, key)}')", (*base, "modules"))
    if cname != first:
        have = {ctx.types[m].role for m in names if ctx.types.get(m) is not None}
        if roles - have:
            ctx.add("warning", "incomplete",
                    f"configuration '{cname}' has no module of role "
                    f"{', '.join(map(repr, sorted(roles - have)))}, which the initial "
                    f"configuration '{first}' has", (*base, "modules"))
    if len(set(conf.modules)) != len(conf.modules):
        ctx.add("error", "duplicate", "a module is listed twice", (*base, "modules"))
    for i, (s, t) in enumerate(conf.disabled_edges):
        if (s, t) not in edge_pairs:
            ctx.add("error", "reference", f"no edge {s} -> {t} to disable",
                    (*base, "disabled_edges", i))
    return names


def _inputs(ctx: Context, cname: str, names: list[str], edges: list[tuple[int, Any]]) -> None:
    """Every input of an active module delivered once (or to a multi-input port), and the
    modules' ``requires``/``excludes``."""
    arch = ctx.arch
    conf = arch.configurations[cname]
    base: Path_ = ("configurations", cname)
    ports = arch.edge_ports
    active = set(names)
    delivered: dict[str, dict[str, int]] = {m: {} for m in active}
    for i, e in edges:
        into = ports.into(i)  # the target's port
        first_edge = delivered[e.target].setdefault(into, i)
        target_cls = ctx.types.get(e.target)
        many = target_cls is not None and into in target_cls.multi_inputs
        if first_edge != i and not many:
            other = arch.edges[first_edge].source
            ctx.add("error", "double-input",
                    f"configuration '{cname}': '{e.target}' receives '{into}' from both "
                    f"'{other}' and '{e.source}'; one would overwrite the other (split the "
                    "configuration, or disable one edge with disabled_edges)", ("edges", i))
    for m in names:
        cls = ctx.types.get(m)
        if cls is None:
            continue
        missing = [s for s in cls.inputs if s not in delivered[m]]
        if missing:
            ctx.add("error", "incomplete",
                    f"configuration '{cname}': '{m}' needs {', '.join(map(repr, missing))} "
                    "but no active edge delivers it", (*base, "modules", conf.modules.index(m)))
        k = arch.modules[m].constraints
        for r in k.requires:
            if r in arch.modules and r not in active:
                ctx.add("error", "module-constraint",
                        f"configuration '{cname}': '{m}' requires '{r}', which is not active",
                        (*base, "modules"))
        for x in k.excludes:
            if x in active:
                ctx.add("error", "module-constraint",
                        f"configuration '{cname}': '{m}' excludes '{x}', which is active",
                        (*base, "modules"))


def _flow(ctx: Context, cname: str, names: list[str], edges: list[tuple[int, Any]]) -> None:
    """The data flow of a configuration: no algebraic loop, connected, within the budgets."""

    arch = ctx.arch
    base: Path_ = ("configurations", cname)
    active = set(names)
    flow = [
        (e.source, e.target) for _, e in edges
        if (cls := ctx.types.get(e.target)) is not None and cls.direct_feedthrough
        and e.source != e.target
    ]
    loop = algebraic_loop(flow)
    if loop:
        path = " -> ".join([*loop, loop[0]])
        ctx.add("error", "algebraic-loop",
                f"configuration '{cname}' has an algebraic loop {path}: a cycle needs a "
                "module whose outputs depend on its state only (direct_feedthrough = False)",
                (*base, "modules"))
    if len(active) > 1:
        parts = _components(sorted(active), [(e.source, e.target) for _, e in edges])
        if len(parts) > 1:
            lonely = min(parts, key=len)
            ctx.add("error", "incomplete",
                    f"configuration '{cname}' is not connected: {', '.join(lonely)} "
                    "has no active edge to the rest", (*base, "modules"))
    for b in arch.constraints:
        use = sum(arch.modules[m].resources.get(b.resource, 0.0) for m in active)
        if use > b.max:
            ctx.add("warning", "budget",
                    f"configuration '{cname}' uses {use:g} {b.resource} > budget {b.max:g} "
                    "(Eq. 27); the runtime will never choose it", base, key=True)


def _components(nodes: list[str], links: list[tuple[str, str]]) -> list[list[str]]:
    """The connected components of an undirected graph, each in the order of ``nodes``,
    the components in the order of their first node.

    Examples
    --------
    >>> _components(["a", "b", "c", "d"], [("d", "b")])
    [['a'], ['b', 'd'], ['c']]
    """
    near: dict[str, list[str]] = {m: [] for m in nodes}
    for s, t in links:
        near[s].append(t)
        near[t].append(s)
    label: dict[str, int] = {}
    parts: list[list[str]] = []
    for m in nodes:
        if m in label:
            continue
        label[m] = len(parts)
        todo = [m]
        while todo:
            for t in near[todo.pop()]:
                if t not in label:
                    label[t] = len(parts)
                    todo.append(t)
        parts.append([])
    for m in nodes:
        parts[label[m]].append(m)
    return parts


#: Simulation steps of one run of a scenario (duration_s / step_s): about 3 h at 10^4 steps/s.
MAX_RUN_STEPS = 10**8
#: Memory of one run's recorded series (bytes; the estimate ``simulate`` shows).
MAX_RUN_BYTES = 16 * 1024**3
#: Module-steps of one run: modules × (steps + rollout and Lyapunov steps of every cycle).
MAX_RUN_WORK = 10**10
#: Memory of one built module (bytes; its type's ``RuntimeModule.memory_estimate``): a
#: waypoint at 1e6 m made a 9.5 GB spline table before numpy gave up.
MAX_MODULE_BYTES = 2 * 1024**3


def run_estimate(arch: Architecture, scenario: str) -> tuple[int, int, int]:
    """``(steps, bytes, work)`` of one run of ``scenario``: what ``work`` checks.

    steps = ⌈duration_s / step_s⌉; bytes ≈ steps × (250 + 40 × residual modules)
    (the series a run records); work = modules of the largest configuration ×
    (steps + cycles × Σ over actions of the rollout steps of its Δ estimate and
    ``stability.horizon_steps``), with cycles = ⌈duration_s / period_s⌉.

    Examples
    --------
    >>> from archself.model.loader import load_architecture
    >>> from archself.resources import data_dir
    >>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
    >>> steps, size, work = run_estimate(arch, "nominal")
    >>> steps, size < 100 * 2**20
    (8000, True)
    """
    import math

    rt = arch.runtime
    duration = float(arch.scenarios[scenario].duration_s)
    steps = math.ceil(duration / float(rt.step_s) - 1e-9)
    n_res = sum(1 for m in arch.modules.values() if m.residual is not None)
    size = steps * (250 + 40 * n_res)
    cycles = math.ceil(duration / float(rt.period_s) - 1e-9)
    per_cycle = 0
    for a in arch.actions:
        horizon = getattr(a.improvement, "horizon_s", None)
        if horizon is not None:
            per_cycle += math.ceil(float(horizon) / float(rt.step_s))
        per_cycle += rt.stability.horizon_steps
    width = max(len(c.modules) for c in arch.configurations.values())
    return steps, size, width * (steps + cycles * per_cycle)


def check_actions(ctx: Context) -> None:
    arch = ctx.arch
    seen: dict[str, int] = {}
    for i, a in enumerate(arch.actions):
        base: Path_ = ("actions", i)
        if a.id in seen:
            ctx.add("error", "duplicate",
                    f"action id '{a.id}' already used by actions[{seen[a.id]}]",
                    (*base, "id"))
        seen.setdefault(a.id, i)
        known = refers(ctx, a.module, (*base, "module"))
        for j, c in enumerate(a.applies_in or []):
            if (refers(ctx, c, (*base, "applies_in", j), "configuration") and known
                    and a.module not in arch.configurations[c].modules):
                ctx.add("warning", "action",
                        f"'{a.module}' is not active in configuration '{c}', so the action "
                        "never applies there", (*base, "applies_in", j))
        if a.kind == "parameter_update":
            if a.module in arch.modules:
                params = arch.modules[a.module].params
                for pname, value in (a.set or {}).items():
                    if pname not in params:
                        ctx.add("error", "action",
                                f"'{a.module}' has no parameter '{pname}' "
                                f"(it has: {', '.join(params) or 'none'})", (*base, "set", pname))
                    elif (cls := ctx.types.get(a.module)) is not None and (
                            why := wrong_kind((cls.parameters or {}).get(pname), value)):
                        ctx.add("error", "action", f"new value: {why}", (*base, "set", pname))
                    elif why := outside_space(params[pname], value):
                        ctx.add("error", "action", f"new value {value!r} is {why}",
                                (*base, "set", pname))
                    elif (cls := ctx.types.get(a.module)) is not None and (
                            why := outside_declared((cls.parameters or {}).get(pname), value)):
                        ctx.add("error", "action",
                                f"new value: {why}, the range type "
                                f"'{arch.modules[a.module].type}' declares for '{pname}'",
                                (*base, "set", pname))
            continue
        assert a.to is not None
        if not refers(ctx, a.to, (*base, "to"), "configuration"):
            continue
        target = arch.configurations[a.to]
        for src_name in a.applies_in or []:
            if src_name not in arch.configurations:
                continue
            src = arch.configurations[src_name]
            added = set(target.modules) - set(src.modules)
            removed = set(src.modules) - set(target.modules)
            off_src = {tuple(p) for p in src.disabled_edges}
            rewired = {tuple(p) for p in target.disabled_edges} != off_src
            expect = {
                "substitute": bool(added) and bool(removed),
                "activate": bool(added) and not removed,
                "deactivate": bool(removed) and not added,
                "rewire": not added and not removed and rewired,
            }[a.kind]
            if not expect:
                ctx.add("error", "action",
                        f"a {a.kind} from '{src_name}' to '{a.to}' does not match the change "
                        f"(adds {sorted(added) or 'nothing'}, "
                        f"removes {sorted(removed) or 'nothing'})",
                        (*base, "kind"))

    _check_risk(ctx)
    _check_online(ctx)


def _check_online(ctx: Context) -> None:
    """``runtime.online`` that cannot update: bands without a threshold τ (``top_k``), W
    without an edge the online fit takes (both ends with a residual, off every cycle of
    a configuration)."""
    arch, online = ctx.arch, ctx.arch.runtime.online
    if online.bands.enabled and arch.runtime.threshold is None and arch.runtime.hysteresis is None:
        ctx.add("warning", "online",
                "runtime.top_k has no threshold τ to set bands against: the bands are never "
                "updated online", ("runtime", "online", "bands", "enabled"))
    if not online.weights.enabled:
        return
    from archself.runtime.knowledge import on_cycles

    observed = {n for n, m in arch.modules.items() if m.residual is not None}
    for conf in arch.configurations.values():
        on = set(conf.modules)
        off = {tuple(p) for p in conf.disabled_edges}
        pairs = {(e.source, e.target) for e in arch.edges
                 if {e.source, e.target} <= on and (e.source, e.target) not in off}
        if any({a, b} <= observed for a, b in pairs - on_cycles(pairs)):
            return
    ctx.add("warning", "online",
            "no edge can be refitted online: in every configuration each edge between two "
            "modules with a residual is on a cycle (a control loop) or none joins two such "
            "modules; W stays as declared (docs/learning.md)",
            ("runtime", "online", "weights", "enabled"))


def _check_risk(ctx: Context) -> None:
    """``runtime.risk`` that cannot change a decision: K draws when no action's Δ is a
    rollout (sensitivity and table estimates have one value), or a rule other than the
    mean over one draw (its spread is 0: the rule is the mean)."""
    risk = ctx.arch.runtime.risk
    if risk.draws > 1 and not any(a.improvement.method == "rollout" for a in ctx.arch.actions):
        ctx.add("warning", "action",
                f"draws {risk.draws}: no action estimates its improvement by rollout, so "
                "every estimate has one value and the draws change nothing",
                ("runtime", "risk", "draws"))
    elif risk.draws == 1 and risk.rule != "mean":
        ctx.add("warning", "action",
                f"rule {risk.rule} over one draw: the spread is 0, so it ranks as the mean; "
                "set runtime.risk.draws > 1", ("runtime", "risk", "rule"))


def check_qualities(ctx: Context) -> None:
    """Quality attributes: declared values name configurations, and cover every one."""
    q = ctx.arch.qualities
    if q is None:
        return
    for name, attr in q.attributes.items():
        base = ("qualities", "attributes", name)
        if attr.values is not None:
            for c in attr.values:
                refers(ctx, c, (*base, "values", c), "configuration")
            missing = [c for c in ctx.arch.configurations if c not in attr.values]
            if missing:
                ctx.add("error", "quality",
                        f"no value for configuration(s) {', '.join(missing)}: U(C) needs "
                        f"every attribute of every configuration", (*base, "values"))
        elif attr.resource is not None and not any(
            attr.resource in m.resources for m in ctx.arch.modules.values()
        ):
            ctx.add("warning", "quality",
                    f"no module declares resource '{attr.resource}': the attribute is 0 "
                    f"everywhere", (*base, "resource"))


def check_strategies(ctx: Context) -> None:
    """Strategies: known module, tactics, configurations and steps; no step without exit.

    A step must be reachable from ``start``; from every step an exit (``done`` or
    ``rollback``) must be reachable, else the branches form a cycle without exit.
    """
    actions = {a.id for a in ctx.arch.actions}
    for name, st in ctx.arch.strategies.items():
        base = ("strategies", name)
        refers(ctx, st.module, (*base, "module"))
        steps = st.steps
        if st.start not in steps:
            hint = did_you_mean(st.start, steps, "; did you mean '{}'?")
            ctx.add("error", "strategy", f"unknown step '{st.start}'{hint}", (*base, "start"))
        for sname, step in steps.items():
            at = (*base, "steps", sname)
            if step.tactic not in actions:
                hint = did_you_mean(step.tactic, actions, "; did you mean '{}'?")
                ctx.add("error", "strategy", f"unknown tactic '{step.tactic}' (not an action "
                        f"id){hint}", (*at, "tactic"))
            for cond in ("when", "post"):
                c = getattr(step, cond)
                for j, conf in enumerate((c.configuration or []) if c is not None else []):
                    refers(ctx, conf, (*at, cond, "configuration", j), "configuration")
            for branch in ("success", "failure"):
                nxt = getattr(step, branch)
                if nxt not in steps and nxt not in EXITS:
                    hint = did_you_mean(nxt, [*steps, *EXITS], "; did you mean '{}'?")
                    ctx.add("error", "strategy", f"unknown step '{nxt}' (a step, 'done' or "
                            f"'rollback'){hint}", (*at, branch))
        seen, todo = set(), [st.start] if st.start in steps else []
        while todo:
            s_ = todo.pop()
            if s_ in seen or s_ not in steps:
                continue
            seen.add(s_)
            todo += [steps[s_].success, steps[s_].failure]
        for sname in steps:
            if sname not in seen and st.start in steps:
                ctx.add("error", "strategy", f"step '{sname}' is unreachable from start "
                        f"'{st.start}'", (*base, "steps", sname))
        exits = set(EXITS)
        grew = True
        while grew:  # the steps from which an exit is reachable
            grew = False
            for sname, step in steps.items():
                if sname not in exits and (step.success in exits or step.failure in exits):
                    exits.add(sname)
                    grew = True
        for sname in steps:
            if sname not in exits:
                ctx.add("error", "strategy", f"step '{sname}' is on a cycle without exit: no "
                        f"branch leads to 'done' or 'rollback'", (*base, "steps", sname))


def check_scenarios(ctx: Context) -> None:
    arch = ctx.arch
    placed = {m for conf in arch.configurations.values() for m in conf.modules}
    for sname, sc in arch.scenarios.items():
        for i, f in enumerate(sc.faults):
            path: Path_ = ("scenarios", sname, "faults", i)
            if not refers(ctx, f.module, (*path, "module")):
                continue
            if f.module not in placed:
                ctx.add("error", "fault",
                        f"'{f.module}' is in no configuration, so the fault would never act; "
                        "aim it at a module of a configuration (or add the module to one)",
                        (*path, "module"))
                continue
            cls = ctx.types.get(f.module)
            if cls is None:
                continue
            if f.kind not in cls.fault_kinds:
                can = ", ".join(sorted(cls.fault_kinds)) or "no faults"
                ctx.add("error", "fault",
                        f"'{f.module}' ({arch.modules[f.module].type}) cannot take fault kind "
                        f"'{f.kind}' (it takes: {can})", (*path, "kind"))
            if f.signal is not None and cls.outputs and f.signal not in cls.outputs:
                ctx.add("error", "fault",
                        f"'{f.module}' has no output '{f.signal}' "
                        f"(it outputs: {', '.join(cls.outputs)})", (*path, "signal"))
            if f.onset_s >= sc.duration_s:
                ctx.add("warning", "fault",
                        f"onset {f.onset_s:g} s is after the end of the scenario "
                        f"({sc.duration_s:g} s)", (*path, "onset_s"))


def check_work(ctx: Context) -> None:
    arch = ctx.arch
    rt = arch.runtime
    for name in arch.scenarios:
        steps, size, work = run_estimate(arch, name)
        path: Path_ = ("scenarios", name, "duration_s")
        sc = arch.scenarios[name]
        if steps > MAX_RUN_STEPS:
            ctx.add("error", "work",
                    f"a run of '{name}' is {steps:,} steps (duration_s {sc.duration_s:g} s / "
                    f"runtime.step_s {rt.step_s:g} s), more than the cap of {MAX_RUN_STEPS:,}; "
                    "shorten duration_s or raise runtime.step_s", path)
        elif size > MAX_RUN_BYTES:
            ctx.add("error", "work",
                    f"a run of '{name}' would record about {size / 2**30:,.1f} GiB of series "
                    f"({steps:,} steps), more than the cap of {MAX_RUN_BYTES // 2**30} GiB; "
                    "shorten duration_s or raise runtime.step_s", path)
        elif work > MAX_RUN_WORK:
            ctx.add("error", "work",
                    f"a run of '{name}' is about {work:.3g} module-steps with the rollouts and "
                    f"Lyapunov tests of {len(arch.actions)} actions every "
                    f"{rt.period_s:g} s, more than the cap of {MAX_RUN_WORK:.0e}; shorten "
                    "duration_s, the rollout horizons or runtime.stability.horizon_steps, or "
                    "raise runtime.period_s", path)
    # an edge's latency is a line of latency_s / step_s values, copied with the snapshot
    # of every action evaluated every cycle (latency_s: 1e7 hung simulate)
    import math

    longest = max((float(s.duration_s) for s in arch.scenarios.values()), default=0.0)
    snapshots = 1 + math.ceil(longest / float(rt.period_s) - 1e-9) * len(arch.actions)
    for i, e in enumerate(arch.edges):
        delay = round(float(e.latency_s) / float(rt.step_s))
        if delay > MAX_RUN_STEPS or delay * snapshots > MAX_RUN_WORK:
            what = (f"more than the cap of {MAX_RUN_STEPS:,}" if delay > MAX_RUN_STEPS else
                    f"a line of values copied by each of about {snapshots:,} snapshots of a "
                    f"run, more than the cap of {MAX_RUN_WORK:.0e} in all")
            ctx.add("error", "work",
                    f"a latency of {delay:,} steps (latency_s {e.latency_s:g} s / runtime.step_s "
                    f"{rt.step_s:g} s), {what}; shorten latency_s or raise runtime.step_s",
                    ("edges", i, "latency_s"))


def check_objective(ctx: Context) -> None:
    obj = ctx.arch.runtime.objective
    if not obj.components:  # J would be 0 at every step: no error ever measured
        ctx.add("error", "objective", "expected at least one component index (e.g. [0]), "
                "got an empty list", ("runtime", "objective", "components"))
    for key in ("actual", "reference"):
        ref = getattr(obj, key)
        path = ("runtime", "objective", key)
        mod, dot, sig = ref.partition(".")
        if not dot:
            ctx.add("error", "reference", f"expected 'module.signal', got '{ref}'", path)
            continue
        if refers(ctx, mod, path):
            cls = ctx.types.get(mod)
            if cls is not None and cls.outputs and sig not in cls.outputs:
                ctx.add("error", "reference",
                        f"'{mod}' has no output '{sig}' (it outputs: {', '.join(cls.outputs)})",
                        path)
                continue
            size = cls.output_sizes.get(sig) if cls is not None else None
            for j, c in enumerate(obj.components):
                if c < 0 and key == "actual":
                    ctx.add("error", "objective", f"component {c} is negative; indices start at 0",
                            ("runtime", "objective", "components", j))
                elif size is not None and c >= size:
                    ctx.add("error", "objective",
                            f"component {c} is out of range: '{ref}' has {size} component(s) "
                            f"(indices 0..{size - 1})", ("runtime", "objective", "components", j))


def check_stability(ctx: Context, verify: str | None = None) -> None:
    """The whole-loop check at the file's ``verify`` (``verify`` when that is off).

    With both off the check is not run (it compiles modules) and that is said: one
    ``info`` finding at ``runtime.stability.verify``, never a silent pass.
    """
    mode: str = ctx.arch.runtime.stability.verify
    if mode == "off":
        mode = verify or "off"
    if any(f.severity == "error" for f in ctx.out):
        return
    if mode == "off":
        ctx.add("info", "stability", NOT_CHECKED, ("runtime", "stability", "verify"), key=True)
        return
    from archself.check.stability import verify_stability  # compiles modules: only when asked

    for u in verify_stability(ctx.arch, mode):
        ctx.add(u.severity or mode, "stability", u.message, u.path, key=len(u.path) == 2)


#: The finding of a file whose whole-loop stability was not checked (verify off).
NOT_CHECKED = ("whole-loop stability not checked (verify: off); `archself validate "
               "--stability` checks it (docs/stability.md)")


def check_clock(ctx: Context) -> None:
    """A scenario shorter than one step, a MAPE-K period or a module's period (``Param(
    period=True)``; a rate in Hz as its inverse) shorter than ``runtime.step_s``."""
    arch = ctx.arch
    step = float(arch.runtime.step_s)
    short = step * (1 - 1e-9)
    for name, sc in arch.scenarios.items():
        if float(sc.duration_s) < short:
            ctx.add("error", "clock",
                    f"duration_s {sc.duration_s:g} s is shorter than one step (runtime.step_s "
                    f"{step:g} s): the run would have no step and no metric",
                    ("scenarios", name, "duration_s"))
    if float(arch.runtime.period_s) < short:
        ctx.add("error", "clock",
                f"period_s {arch.runtime.period_s:g} s is shorter than runtime.step_s {step:g} s: "
                "a MAPE-K cycle runs at most once a step; raise period_s to a multiple of step_s",
                ("runtime", "period_s"))
    for name, mod in arch.modules.items():
        declared = getattr(ctx.types.get(name), "parameters", None) or {}
        values: list[tuple[str, Any, Path_]] = [
            (pname, p.value, ("modules", name, "params", pname, "value"))
            for pname, p in mod.params.items()]
        values += [(pname, v, ("actions", i, "set", pname))
                   for i, a in enumerate(arch.actions) if a.module == name
                   for pname, v in (a.set or {}).items()]
        for pname, value, path in values:
            spec = declared.get(pname)
            if (spec is None or not getattr(spec, "period", False) or isinstance(value, bool)
                    or not isinstance(value, (int, float)) or value <= 0):
                continue
            hz = spec.unit == "Hz"
            period = 1.0 / value if hz else float(value)
            if period < short:
                what = (f"a rate of {value:g} Hz (one event every {period:g} s)" if hz
                        else f"a period of {value:g} s")
                ctx.add("error", "clock",
                        f"{what} is shorter than runtime.step_s {step:g} s: the events cannot "
                        "happen that often in a run", path)


def _named_param(message: str, names: list[str]) -> str | None:
    """The parameter of ``names`` that ``message`` names first (as a word), else None.

    Examples
    --------
    >>> _named_param("C has 3 columns, expected 2 (the states of A 2×2)", ["A", "B", "C"])
    'C'
    >>> _named_param("singular matrix", ["A", "B"]) is None
    True
    """
    import re

    found = [(m.start(), n) for n in names
             if (m := re.search(rf"(?<![\w.]){re.escape(n)}(?!\w)", message))]
    return min(found)[1] if found else None


def check_build(ctx: Context) -> None:
    """Each module's memory by its type's estimate, then its type's parameter check
    (by default one module built): for the nominal values and every parameter update.

    Only on a file without errors (a build of a wrong file would repeat its errors).
    A module over :data:`MAX_MODULE_BYTES` is not built.
    """
    if any(f.severity == "error" for f in ctx.out):
        return
    arch = ctx.arch
    dt = float(arch.runtime.step_s)
    passed: set[tuple[Any, str]] = set()  # (type, values) that built: 10^4 alike modules
    for name, mod in arch.modules.items():
        cls = ctx.types.get(name)
        if cls is None:
            continue
        nominal = {k: p.value for k, p in mod.params.items()}
        trials: list[tuple[dict, Path_, str]] = [(nominal, ("modules", name, "params"), "")]
        trials += [({**nominal, **a.set}, ("actions", i, "set"), f" after action '{a.id}'")
                   for i, a in enumerate(arch.actions)
                   if a.kind == "parameter_update" and a.module == name and a.set]
        for values, path, after in trials:
            seen = (cls, repr(sorted(values.items())))
            if seen in passed:
                continue
            where = "value" if path[0] == "modules" else None
            try:
                need = int(cls.memory_estimate({**cls.default_params(), **values}, dt))
            except Exception:  # the parameters are wrong: check_params says how
                need = 0
            if need > MAX_MODULE_BYTES:
                ctx.add("error", "build",
                        f"'{name}' ({mod.type}) would take about {need / 2**30:,.1f} GiB when "
                        f"built{after} (its type's estimate), more than the cap of "
                        f"{MAX_MODULE_BYTES // 2**30} GiB", path, key=path[0] == "modules")
                continue
            why = cls.check_params(name, values, dt)
            if not why:
                passed.add(seen)
            else:
                pname = _named_param(why, list(values))
                at = path if pname is None else (*path, pname, *([where] if where else []))
                ctx.add("error", "build", f"'{name}' ({mod.type}) cannot be built{after}: {why}",
                        at, key=pname is None and path[0] == "modules")


def check(loaded: Loaded, stability: str | None = None) -> list[Finding]:
    """All semantic findings of a loaded architecture, sorted by position.

    ``stability`` (``warning`` or ``error``) runs the whole-loop stability check at
    that severity when the file's ``runtime.stability.verify`` is off
    (``archself validate --stability``); with it off too, one ``info`` finding says
    the check did not run.
    """
    # the collector paused, as in the loader (for the imports of the packs and scipy too)
    with gc_paused():
        ctx = Context(loaded)
        for rule in (
            check_types,
            check_edges,
            check_ports,
            check_weights,
            check_subsystems,
            check_configurations,
            check_parameters,
            check_actions,
            check_qualities,
            check_strategies,
            check_scenarios,
            check_work,
            check_clock,
            check_objective,
            check_limits,
            check_build,
        ):
            rule(ctx)
    check_stability(ctx, stability)  # --verify compiles systems: the collector runs there
    ctx.out.sort(key=lambda f: (f.line or 0, f.col or 0, f.code))
    return ctx.out


def has_errors(findings: list[Finding]) -> bool:
    """True when any finding has error severity."""
    return any(f.severity == "error" for f in findings)
