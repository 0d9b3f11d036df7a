"""Checks of the graph: edges, ports, the influence matrix W and every configuration.

Rules ``self-loop``, ``duplicate``, ``weight``, ``signal`` (edges), ``port``
(:mod:`archself.model.ports`), ``spectral-radius`` and ``singular`` (ρ(W), by
:func:`spectrum_summary`), and per configuration ``initial``, ``reference``,
``incomplete`` (inputs delivered, connected, the objective's modules, roles),
``double-input``, ``module-constraint``, ``algebraic-loop``
(:func:`archself.system.dataflow.algebraic_loop`) and ``budget``.
"""

from __future__ import annotations

from typing import Any

from archself.check.context import Context, closest, refers
from archself.io.yaml_source import Path_
from archself.model.architecture import Architecture

__all__ = [
    "active_edges",
    "check_configurations",
    "check_edges",
    "check_ports",
    "check_subsystems",
    "check_weights",
    "spectrum_summary",
]


def check_edges(ctx: Context) -> None:
    seen: dict[tuple[str, str, str, str], int] = {}
    modules = ctx.arch.modules
    ports = ctx.arch.edge_ports  # named ports: archself.model.ports
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
        if e.weight < 0:
            ctx.add("error", "weight",
                    f"negative weight {e.weight}: influence weights must be ≥ 0 (Eq. 13)",
                    ("edges", i, "weight"))
        if ok and e.carries:  # named ports: archself.model.ports
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
    from archself.model.ports import port_findings

    for code, msg, path in port_findings(ctx.arch, ctx.types):
        ctx.add("error", code, msg, path)


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
            close = closest(word, pool)
            hint = f"; did you mean '{close}'?" if close else ""
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
    from archself.system.dataflow import algebraic_loop

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
