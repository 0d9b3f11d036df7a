"""Semantic checks of an architecture beyond its schema.

Each rule yields :class:`~archself.findings.Finding` objects located at the
offending node. The rules:

* ``reference``: every name used (edges, configurations, actions, faults,
  constraints, objective) refers to a declared module or configuration;
* ``unknown-type``: every module ``type`` is registered (built-in or plugin);
* ``self-loop``, ``duplicate``: edges are proper and unique, action ids unique;
* ``weight``: W_ji ≥ 0 (Eq. 13);
* ``spectral-radius``, ``singular``: ρ(W) < ``runtime.max_spectral_radius`` < 1 so
  that I − Wᵀ is nonsingular and z = (I − Wᵀ)⁻¹ r is bounded (Eq. 13–14);
* ``signal``: an edge carries a signal its source outputs;
* ``port``: named ports (``from: module.port``) exist on the types, with "did you
  mean"; an edge names a signal (:mod:`archself.ports`);
* ``incomplete``: in each configuration every active module receives its
  required inputs over active edges, the active modules are connected, and the
  modules ``runtime.objective`` reads are active; a configuration that fills
  none of the roles the initial configuration fills gets a warning;
* ``double-input``: no module receives the same signal (input port) over two active
  edges of one configuration (the executor would keep only one of them);
* ``algebraic-loop``: every cycle of active edges passes through a module
  without direct feedthrough (a plant, a delay), so the data flow can be ordered;
* ``module-constraint``: k_i ``requires``/``excludes`` hold in each configuration;
* ``budget``: each configuration satisfies C(a, θ, e) ≤ 0 (Eq. 27) — a warning;
* ``parameter``: required parameters are given, every parameter is one the type
  declares (when it declares them: ``RuntimeModule.parameters``),
  nominal values lie inside their spaces, and every number of a value (and the
  file's ``min``/``max``) lies in the range the type declares (``Param.min``/``max``);
* ``fault``: faults target modules whose type accepts that fault kind and signal,
  and that are in at least one configuration (else the fault never acts);
* ``work``: each scenario's run fits the caps: :data:`MAX_RUN_STEPS` simulation
  steps, :data:`MAX_RUN_BYTES` of recorded series, :data:`MAX_RUN_WORK`
  module-steps with the rollouts and Lyapunov tests (:func:`run_estimate`);
* ``action``: actions lead to declared configurations, their kind matches the
  change, parameter updates name parameters of the module and stay in bounds;
  the module an action addresses is active where it applies (a warning);
* ``residual``: a residual names a signal the module's type publishes;
* ``initial``: at most one configuration is marked initial;
* ``limits``: a module's ``constraints.blocks`` names declared actions (and has
  ``limits`` to be violated);
* ``stability``: with ``runtime.stability.verify`` warning or error (opt-in: it
  compiles the modules), every configuration's closed loop and every action's
  result pass Eq. 21 (:mod:`archself.verify`); judged only on a file without errors.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from archself.findings import Finding
from archself.loader import Loaded, Path_, dotted
from archself.model import Architecture, Parameter

#: Simulation steps of one run of a scenario (duration_s / step_s): about 3 h at 10^4 steps/s.
MAX_RUN_STEPS = 10**8
#: Memory of one run's recorded series (bytes; the estimate ``simulate`` shows).
MAX_RUN_BYTES = 16 * 1024**3
#: Module-steps of one run: modules × (steps + rollout and Lyapunov steps of every cycle).
MAX_RUN_WORK = 10**10


def run_estimate(arch: Architecture, scenario: str) -> tuple[int, int, int]:
    """``(steps, bytes, work)`` of one run of ``scenario``: what ``work`` checks.

    steps = ⌈duration_s / step_s⌉; bytes ≈ steps × (250 + 40 × residual modules)
    (the series a run records); work = modules of the largest configuration ×
    (steps + cycles × Σ over actions of the rollout steps of its Δ estimate and
    ``stability.horizon_steps``), with cycles = ⌈duration_s / period_s⌉.

    Examples
    --------
    >>> from archself.loader import load_architecture
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


class _Ctx:
    def __init__(self, loaded: Loaded) -> None:
        from archself import registry

        self.arch: Architecture = loaded.arch
        self.src = loaded.source
        self.out: list[Finding] = []
        by_type: dict[str, Any] = {}
        self.types: dict[str, Any] = {}
        for name, mod in self.arch.modules.items():
            if mod.type not in by_type:
                by_type[mod.type] = registry.lookup(mod.type)
            self.types[name] = by_type[mod.type]

    def add(self, sev: str, code: str, msg: str, path: Path_, *, key: bool = False) -> None:
        line, col = self.src.locate(path, key=key)
        self.out.append(Finding(sev, code, msg, dotted(path), self.src.file, line, col))  # type: ignore[arg-type]


def check(loaded: Loaded) -> list[Finding]:
    """All semantic findings of a loaded architecture, sorted by position."""
    ctx = _Ctx(loaded)
    for rule in (
        _types,
        _edges,
        _ports,
        _weights,
        _configurations,
        _parameters,
        _actions,
        _scenarios,
        _work,
        _objective,
        _limits,
        _stability,
    ):
        rule(ctx)
    ctx.out.sort(key=lambda f: (f.line or 0, f.col or 0, f.code))
    return ctx.out


def has_errors(findings: list[Finding]) -> bool:
    """True when any finding has error severity."""
    return any(f.severity == "error" for f in findings)


# --------------------------------------------------------------------------- helpers
def _close(word: str, options: Any) -> str | None:
    import difflib

    close = difflib.get_close_matches(word, list(options), n=1)
    return close[0] if close else None


def _ref(ctx: _Ctx, name: str, path: Path_, what: str = "module") -> bool:
    pool = ctx.arch.modules if what == "module" else ctx.arch.configurations
    if name in pool:
        return True
    import difflib

    close = difflib.get_close_matches(name, list(pool), n=1)
    hint = f"; did you mean '{close[0]}'?" if close else ""
    ctx.add("error", "reference", f"unknown {what} '{name}'{hint}", path)
    return False


# --------------------------------------------------------------------------- rules
def _known_types_text(key: str, known: list[str]) -> str:
    """The registered types of ``key``'s namespace (``sensor.*``), or all when it has none.

    Types of other namespaces (another plugin's) do not change the message.
    """
    space = key.partition(".")[0] + "."
    same = [k for k in known if k.startswith(space)]
    if same:
        return f"{space}* types: {', '.join(same)}"
    return f"known types: {', '.join(known)}"


def _types(ctx: _Ctx) -> None:
    from archself import registry

    known = registry.known_types()
    for name, mod in ctx.arch.modules.items():
        cls = ctx.types[name]
        if cls is None:
            import difflib

            close = difflib.get_close_matches(mod.type, known, n=1)
            hint = f"did you mean '{close[0]}'? " if close else ""
            ctx.add(
                "error", "unknown-type",
                f"unknown module type '{mod.type}'; {hint}{_known_types_text(mod.type, known)}",
                ("modules", name, "type"),
            )
            continue
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
                near = _close(pname, takes)
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
                _ref(ctx, other, ("modules", name, "constraints", dep, i))


def _numbers(value: Any) -> Iterator[float]:
    """The numbers of a parameter value: itself, or the entries of a list or matrix."""
    if isinstance(value, bool):
        return
    if isinstance(value, (int, float)):
        yield value
    elif isinstance(value, list):
        for v in value:
            yield from _numbers(v)


def _outside(spec: Any, value: Any) -> str | None:
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


def _declared_range(ctx: _Ctx, type_: str, pname: str, spec: Any, p: Parameter,
                    path: Path_) -> None:
    for key, value in (("value", p.value), ("min", p.min), ("max", p.max)):
        if value is None:
            continue
        why = _outside(spec, value)
        if why:
            ctx.add("error", "parameter",
                    f"{why}, the range type '{type_}' declares for '{pname}'", (*path, key))


def _edges(ctx: _Ctx) -> None:
    seen: dict[tuple[str, str, str, str], int] = {}
    modules = ctx.arch.modules
    ports = ctx.arch.edge_ports  # named ports: archself.ports
    for i, e in enumerate(ctx.arch.edges):
        if e.source in modules and e.target in modules:  # the common case: no call
            ok = True
        else:
            ok = (_ref(ctx, e.source, ("edges", i, "from"))
                  & _ref(ctx, e.target, ("edges", i, "to")))
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
        if ok and e.carries:  # named ports: archself.ports
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
    the eigenvalue 1 only if ρ ≥ 1; then the LU factorization the runtime would
    use (:class:`~archself.runtime.influence.InfluenceSolver`) tells whether
    ``I − Wᵀ`` is singular.

    Returns
    -------
    rho : float
        The spectral radius ρ(W).
    singular : bool
        True when W has the eigenvalue 1, i.e. I − Wᵀ is singular.

    Examples
    --------
    >>> rho, singular = spectrum_summary(
    ...     ["a", "b", "c"], [("a", "b", 0.5), ("b", "a", 0.5), ("b", "c", 2.0)])
    >>> round(rho, 12), singular
    (0.5, False)
    """
    import numpy as np
    import scipy.sparse

    from archself.runtime.influence import InfluenceSolver, spectral_radius

    index = {name: k for k, name in enumerate(names)}
    rows, cols, data = [], [], []
    for source, target, weight in edges:  # finite weights: the schema says so
        j, i = index.get(source), index.get(target)
        if j is not None and i is not None and j != i:
            rows.append(j)
            cols.append(i)
            data.append(float(weight))
    n = len(names)
    W = scipy.sparse.coo_matrix((np.asarray(data, dtype=float), (rows, cols)),
                                shape=(n, n)).tocsr()  # parallel edges add up
    rho = spectral_radius(W)
    singular = False
    if rho >= 1.0 - 1e-9:
        try:
            InfluenceSolver().set_matrix(W, key=0)
        except np.linalg.LinAlgError:
            singular = True
    return rho, singular


def _ports(ctx: _Ctx) -> None:
    from archself.ports import port_findings

    for code, msg, path in port_findings(ctx.arch, ctx.types):
        ctx.add("error", code, msg, path)


def _weights(ctx: _Ctx) -> None:
    arch = ctx.arch
    edges = [(e.source, e.target, e.weight) for e in arch.edges]
    rho, singular = spectrum_summary(list(arch.modules), edges)
    limit = arch.runtime.max_spectral_radius
    if singular:
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


def _active_edges(arch: Architecture, conf_name: str) -> list[tuple[int, Any]]:
    conf = arch.configurations[conf_name]
    active = set(conf.modules) & set(arch.modules)
    off = {tuple(p) for p in conf.disabled_edges}
    return [
        (i, e) for i, e in enumerate(arch.edges)
        if e.source in active and e.target in active and (e.source, e.target) not in off
    ]


def _configurations(ctx: _Ctx) -> None:
    import scipy.sparse
    import scipy.sparse.csgraph

    from archself.dataflow import algebraic_loop

    arch = ctx.arch
    initial = [n for n, c in arch.configurations.items() if c.initial]
    if len(initial) > 1:
        ctx.add("error", "initial",
                f"{len(initial)} configurations are marked initial ({', '.join(initial)}); "
                "mark one", ("configurations", initial[1], "initial"))
    edge_pairs = {(e.source, e.target) for e in arch.edges}
    ports = arch.edge_ports
    obj = arch.runtime.objective
    needed: dict[str, str] = {}  # module -> the objective key that reads it
    for key in ("actual", "reference"):
        mod = getattr(obj, key).partition(".")[0]
        if mod in arch.modules:
            needed.setdefault(mod, key)
    first = arch.initial_configuration()
    roles = {ctx.types[m].role for m in arch.configurations[first].modules
             if ctx.types.get(m) is not None}
    for cname, conf in arch.configurations.items():
        base: Path_ = ("configurations", cname)
        names = [m for m in conf.modules if m in arch.modules]
        if len(names) != len(conf.modules):
            for i, m in enumerate(conf.modules):
                _ref(ctx, m, (*base, "modules", i))
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
        active = set(names)
        edges = _active_edges(arch, cname)
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
            nodes = sorted(active)
            pos = {m: k for k, m in enumerate(nodes)}
            links = scipy.sparse.coo_matrix(
                ([1.0] * len(edges),
                 ([pos[e.source] for _, e in edges], [pos[e.target] for _, e in edges])),
                shape=(len(nodes), len(nodes)),
            )
            ncomp, labels = scipy.sparse.csgraph.connected_components(links, directed=False)
            if ncomp > 1:
                parts: dict[int, list[str]] = {}  # in the order of their first module
                for m, label in zip(nodes, labels.tolist(), strict=True):
                    parts.setdefault(label, []).append(m)
                lonely = min(parts.values(), key=len)
                ctx.add("error", "incomplete",
                        f"configuration '{cname}' is not connected: {', '.join(lonely)} "
                        "has no active edge to the rest", (*base, "modules"))
        for b in arch.constraints:
            use = sum(arch.modules[m].resources.get(b.resource, 0.0) for m in active)
            if use > b.max:
                ctx.add("warning", "budget",
                        f"configuration '{cname}' uses {use:g} {b.resource} > budget {b.max:g} "
                        "(Eq. 27); the runtime will never choose it", base, key=True)


def _in_space(p: Parameter, value: Any) -> str | None:
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


def _parameters(ctx: _Ctx) -> None:
    for name, mod in ctx.arch.modules.items():
        for pname, p in mod.params.items():
            path = ("modules", name, "params", pname)
            if p.min is not None and p.max is not None and p.min > p.max:
                ctx.add("error", "parameter", f"min {p.min:g} > max {p.max:g}", (*path, "min"))
                continue
            why = _in_space(p, p.value)
            if why:
                ctx.add("error", "parameter",
                        f"nominal value {p.value!r} is outside the parameter space: {why}",
                        (*path, "value"))


def _actions(ctx: _Ctx) -> None:
    arch = ctx.arch
    seen: dict[str, int] = {}
    for i, a in enumerate(arch.actions):
        base: Path_ = ("actions", i)
        if a.id in seen:
            ctx.add("error", "duplicate",
                    f"action id '{a.id}' already used by actions[{seen[a.id]}]",
                    (*base, "id"))
        seen.setdefault(a.id, i)
        known = _ref(ctx, a.module, (*base, "module"))
        for j, c in enumerate(a.applies_in or []):
            if (_ref(ctx, c, (*base, "applies_in", j), "configuration") and known
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
                    elif why := _in_space(params[pname], value):
                        ctx.add("error", "action", f"new value {value!r} is {why}",
                                (*base, "set", pname))
                    elif (cls := ctx.types.get(a.module)) is not None and (
                            why := _outside((cls.parameters or {}).get(pname), value)):
                        ctx.add("error", "action",
                                f"new value: {why}, the range type "
                                f"'{arch.modules[a.module].type}' declares for '{pname}'",
                                (*base, "set", pname))
            continue
        assert a.to is not None
        if not _ref(ctx, a.to, (*base, "to"), "configuration"):
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


def _fault_targets(arch: Architecture) -> Iterator[tuple[Path_, Any]]:
    for sname, sc in arch.scenarios.items():
        for i, f in enumerate(sc.faults):
            yield ("scenarios", sname, "faults", i), f


def _scenarios(ctx: _Ctx) -> None:
    arch = ctx.arch
    placed: set[str] = set()
    for conf in arch.configurations.values():
        placed.update(conf.modules)
    for path, f in _fault_targets(arch):
        if not _ref(ctx, f.module, (*path, "module")):
            continue
        if f.module not in placed:
            ctx.add("error", "fault",
                    f"'{f.module}' is in no configuration, so the fault would never act; aim it "
                    "at a module of a configuration (or add the module to one)",
                    (*path, "module"))
            continue
        cls = ctx.types.get(f.module)
        if cls is None:
            continue
        if f.kind not in cls.fault_kinds:
            can = ", ".join(sorted(cls.fault_kinds)) or "no faults"
            ctx.add("error", "fault",
                    f"'{f.module}' ({arch.modules[f.module].type}) cannot take fault kind "
                    f"'{f.kind}' "
                    f"(it takes: {can})", (*path, "kind"))
        if f.signal is not None and cls.outputs and f.signal not in cls.outputs:
            ctx.add("error", "fault",
                    f"'{f.module}' has no output '{f.signal}' "
                    f"(it outputs: {', '.join(cls.outputs)})",
                    (*path, "signal"))
        duration = arch.scenarios[path[1]].duration_s  # type: ignore[index]
        if f.onset_s >= duration:
            ctx.add("warning", "fault",
                    f"onset {f.onset_s:g} s is after the end of the scenario ({duration:g} s)",
                    (*path, "onset_s"))


def _work(ctx: _Ctx) -> None:
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


def _objective(ctx: _Ctx) -> None:
    obj = ctx.arch.runtime.objective
    for key in ("actual", "reference"):
        ref = getattr(obj, key)
        path = ("runtime", "objective", key)
        mod, dot, sig = ref.partition(".")
        if not dot:
            ctx.add("error", "reference", f"expected 'module.signal', got '{ref}'", path)
            continue
        if _ref(ctx, mod, path):
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


def _stability(ctx: _Ctx) -> None:
    mode = ctx.arch.runtime.stability.verify
    if mode == "off" or any(f.severity == "error" for f in ctx.out):
        return
    from archself.verify import verify_stability  # compiles modules: only when asked

    for u in verify_stability(ctx.arch):
        ctx.add(mode, "stability", u.message, u.path, key=len(u.path) == 2)


def _limits(ctx: _Ctx) -> None:
    ids = [a.id for a in ctx.arch.actions]
    for name, mod in ctx.arch.modules.items():
        cons = mod.constraints
        path: Path_ = ("modules", name, "constraints", "blocks")
        if cons.blocks and not cons.limits:
            ctx.add("warning", "limits", "'blocks' has no effect without 'limits'", path)
        if cons.blocks == "all":
            continue
        for j, aid in enumerate(cons.blocks):
            if aid not in ids:
                close = _close(aid, ids)
                hint = f" (did you mean '{close}'?)" if close else ""
                ctx.add("error", "reference", f"unknown action '{aid}'{hint}", (*path, j))
