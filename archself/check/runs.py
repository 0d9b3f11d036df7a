"""Checks of what runs: actions, scenario faults, the work caps, the objective, stability.

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

from typing import Any

from archself.check.context import Context, closest, refers
from archself.check.modules import outside_declared, outside_space, wrong_kind
from archself.io.yaml_source import Path_
from archself.model.architecture import Architecture

__all__ = [
    "MAX_MODULE_BYTES",
    "MAX_RUN_BYTES",
    "MAX_RUN_STEPS",
    "MAX_RUN_WORK",
    "check_actions",
    "check_build",
    "check_clock",
    "check_objective",
    "check_scenarios",
    "check_stability",
    "check_work",
    "run_estimate",
]

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
    from archself.model.strategies import EXITS

    actions = {a.id for a in ctx.arch.actions}
    for name, st in ctx.arch.strategies.items():
        base = ("strategies", name)
        refers(ctx, st.module, (*base, "module"))
        steps = st.steps
        if st.start not in steps:
            close = closest(st.start, steps)
            hint = f"; did you mean '{close}'?" if close else ""
            ctx.add("error", "strategy", f"unknown step '{st.start}'{hint}", (*base, "start"))
        for sname, step in steps.items():
            at = (*base, "steps", sname)
            if step.tactic not in actions:
                close = closest(step.tactic, actions)
                hint = f"; did you mean '{close}'?" if close else ""
                ctx.add("error", "strategy", f"unknown tactic '{step.tactic}' (not an action "
                        f"id){hint}", (*at, "tactic"))
            for cond in ("when", "post"):
                c = getattr(step, cond)
                for j, conf in enumerate((c.configuration or []) if c is not None else []):
                    refers(ctx, conf, (*at, cond, "configuration", j), "configuration")
            for branch in ("success", "failure"):
                nxt = getattr(step, branch)
                if nxt not in steps and nxt not in EXITS:
                    close = closest(nxt, [*steps, *EXITS])
                    hint = f"; did you mean '{close}'?" if close else ""
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
