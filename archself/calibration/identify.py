"""``archself identify``: the influence weights W of the edges, estimated from experiments.

For each configuration, the fault-free scenario runs fixed in it once per seed
unperturbed and once per seed and *experiment*: a small fault (``bias`` by
default, from t = 0) on the main output of one active module that takes it —
modules with a residual and hidden ones (sensors, actuators without a residual
block) alike. The runs are sampled like calibration runs (the Monitor's filtered
residual signals every ``runtime.period_s``, :class:`archself.calibration.runs.Recorder`),
time-averaged after the settling time, and the difference perturbed − nominal
of the same seed (common random numbers) gives Δr in the loop's units. The
weights are then fitted per target module (:mod:`~archself.calibration.identify_fit`)
and compared with the declared ones (times the loop's ρ(W) scale).

The runs go to the campaign executors (local process pool, Dask, or inline).
:func:`set_weights` writes the fitted weights into a copy of the file's text,
comments and layout kept, like :mod:`archself.calibration.edit` does for bands.
See docs/identify.md.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from archself.calibration.identify_fit import EdgeEstimate, TargetFit, delta_residuals, fit_edges
from archself.errors import ArchselfError, LoadError

__all__ = [
    "EdgeRow",
    "IdJob",
    "Identification",
    "IdentifyError",
    "identify",
    "markdown_table",
    "run_identify_job",
    "set_weights",
    "summary_text",
]

#: Flag a fitted weight as different from the declared one beyond this many SE.
FLAG_SE = 2.0
COMMENT_TAG = "# identified:"

_ARCHS: dict[str, Any] = {}  # text digest -> Architecture (parsed once per process)


class IdentifyError(ArchselfError):
    """The identification cannot be done as asked (one-line message, exit 1)."""


@dataclass(frozen=True)
class IdJob:
    """One run: (configuration, seed), unperturbed or with one perturbation.

    ``perturb`` is ``(module, kind, magnitude)`` or None for the nominal run.
    """

    arch_text: str
    arch_digest: str
    file: str
    scenario: str
    configuration: str
    replicate: int
    seed: int
    perturb: tuple[str, str, float] | None
    settle_s: float


def _architecture(job: IdJob) -> Any:
    arch = _ARCHS.get(job.arch_digest)
    if arch is None:
        from archself.loader import load_text

        arch = load_text(job.arch_text, job.file).arch
        _ARCHS.clear()
        _ARCHS[job.arch_digest] = arch
    return arch


def run_identify_job(job: IdJob) -> dict[str, Any]:
    """Run one job; never raises for a failed run.

    Returns
    -------
    dict
        ``configuration``, ``replicate``, ``seed``, ``experiment`` (the perturbed
        module or None), ``mean`` (time-averaged |s̄| per residual module after
        ``settle_s``, float64, in the file's module order), ``error``.
    """
    from archself.calibration.runs import Recorder
    from archself.model import Fault
    from archself.sim.run import simulate

    out: dict[str, Any] = {
        "configuration": job.configuration,
        "replicate": job.replicate,
        "seed": job.seed,
        "experiment": job.perturb[0] if job.perturb else None,
        "error": None,
    }
    try:
        arch = _architecture(job).model_copy(deep=True)
        if job.perturb is not None:
            module, kind, magnitude = job.perturb
            arch.scenarios[job.scenario].faults.append(
                Fault.model_validate(
                    {"module": module, "kind": kind, "onset_s": 0.0, "magnitude": magnitude}
                )
            )
        names = [m for m, spec in arch.modules.items() if spec.residual is not None]
        rec = Recorder(arch, names)
        simulate(arch, job.scenario, configuration=job.configuration, seed=job.seed, adapt=rec)
        x = np.array(rec.x, dtype=float).reshape(len(rec.x), len(names))
        t = np.array(rec.t, dtype=float)
        keep = t >= job.settle_s - 1e-9
        if not keep.any():
            raise IdentifyError(f"no sample after the settling time {job.settle_s:g} s")
        out["mean"] = x[keep].mean(axis=0)
    except Exception as exc:  # noqa: BLE001 - a failed run is reported, not fatal
        msg = str(exc).splitlines()[0] if str(exc) else ""
        out["error"] = f"{type(exc).__name__}: {msg}"[:500]
    return out


def _run_jobs(
    jobs: Sequence[IdJob],
    executor: str,
    workers: int | None,
    address: str | None,
    progress: Callable[[int, int], None] | None,
) -> list[dict[str, Any]]:
    from archself.calibration.runs import run_on_executor

    return run_on_executor(
        jobs, run_identify_job, "archself.calibration.identify",
        executor=executor, workers=workers, address=address, progress=progress,
    )


@dataclass
class EdgeRow:
    """One edge pair (source → target) of one configuration: declared vs fitted."""

    configuration: str
    source: str
    target: str
    carries: list[str]
    declared: float
    effective: float
    fitted: float
    se: float
    identifiable: bool
    reason: str

    @property
    def differs(self) -> bool | None:
        """|fitted − effective| > 2 SE (None when not identifiable or without an SE)."""
        if not self.identifiable or not math.isfinite(self.se):
            return None
        return abs(self.fitted - self.effective) > max(FLAG_SE * self.se, 1e-9)


@dataclass
class Experiment:
    """One perturbed module of one configuration and what it excited."""

    configuration: str
    module: str
    kind: str
    magnitude: float
    seeds: int
    own_delta: float  # mean Δr of the module itself (NaN when hidden)
    max_delta: float  # largest mean |Δr| over the observed modules


@dataclass
class Identification:
    """What :func:`identify` found."""

    architecture: str
    file: str
    scenario: str
    configurations: list[str]
    seeds: int
    root_seed: int
    w_scale: float
    settle_s: float
    rows: list[EdgeRow]
    fits: dict[str, dict[str, TargetFit]]
    experiments: list[Experiment]
    skipped: dict[str, list[str]]  # configuration -> active modules not perturbed (why)
    failed: list[str]
    runs: int
    elapsed_s: float
    executor: str
    text: str = ""
    meta: dict[str, Any] = field(default_factory=dict)

    def fitted_weights(self) -> dict[tuple[str, str], tuple[float, float]]:
        """(source, target) -> (weight, SE) pooled over configurations.

        Inverse-variance weighted where every estimate has an SE > 0, the mean
        otherwise.
        """
        by: dict[tuple[str, str], list[EdgeRow]] = {}
        for r in self.rows:
            if r.identifiable:
                by.setdefault((r.source, r.target), []).append(r)
        out: dict[tuple[str, str], tuple[float, float]] = {}
        for key, rows in by.items():
            se = np.array([r.se for r in rows])
            w = np.array([r.fitted for r in rows])
            if np.all(np.isfinite(se)) and np.all(se > 0):
                iv = 1.0 / se**2
                out[key] = (float(iv @ w / iv.sum()), float(1.0 / math.sqrt(iv.sum())))
            else:
                out[key] = (float(w.mean()), float(se[0]) if len(rows) == 1 else math.nan)
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON data (``--json``)."""

        def num(v: float) -> float | None:
            return float(v) if v == v and not math.isinf(v) else None

        return {
            "architecture": self.architecture,
            "file": self.file,
            "scenario": self.scenario,
            "configurations": self.configurations,
            "seeds": self.seeds,
            "root_seed": self.root_seed,
            "runs": self.runs,
            "failed": self.failed,
            "w_scale": self.w_scale,
            "settle_s": self.settle_s,
            "edges": [
                {
                    "configuration": r.configuration,
                    "source": r.source,
                    "target": r.target,
                    "carries": r.carries,
                    "declared": r.declared,
                    "effective": r.effective,
                    "fitted": num(r.fitted),
                    "se": num(r.se),
                    "identifiable": r.identifiable,
                    "reason": r.reason,
                    "differs": r.differs,
                }
                for r in self.rows
            ],
            "targets": {
                c: {
                    t: {"rows": f.rows, "r2": num(f.r2), "rms": num(f.rms), "moved": num(f.moved)}
                    for t, f in fits.items()
                }
                for c, fits in self.fits.items()
            },
            "experiments": [
                {
                    "configuration": e.configuration,
                    "module": e.module,
                    "kind": e.kind,
                    "magnitude": e.magnitude,
                    "seeds": e.seeds,
                    "own_delta": num(e.own_delta),
                    "max_delta": num(e.max_delta),
                }
                for e in self.experiments
            ],
            "not_perturbed": self.skipped,
            "executor": self.executor,
            "elapsed_s": round(self.elapsed_s, 3),
        }


# --------------------------------------------------------------------------- driver
def _prepare(path: str | Path, scenario: str | None, configurations: Sequence[str] | None):
    from archself.check import check, has_errors
    from archself.loader import load_text, read_text

    text = read_text(path)
    loaded = load_text(text, str(path))
    findings = check(loaded)
    if has_errors(findings):
        raise IdentifyError(str(next(f for f in findings if f.severity == "error")))
    arch = loaded.arch
    if not any(m.residual is not None for m in arch.modules.values()):
        raise IdentifyError(f"{path}: no module declares a residual: nothing to identify")
    if scenario is not None:
        if scenario not in arch.scenarios:
            known = ", ".join(arch.scenarios) or "none"
            raise IdentifyError(f"{path}: unknown scenario {scenario!r}; known: {known}")
        if arch.scenarios[scenario].faults:
            raise IdentifyError(
                f"{path}: scenario {scenario!r} has faults; identify needs a fault-free one"
            )
    else:
        free = [n for n, s in arch.scenarios.items() if not s.faults]
        if not free:
            raise IdentifyError(f"{path}: no fault-free scenario; declare one (no faults)")
        scenario = "nominal" if "nominal" in free else free[0]
    if configurations:
        for c in configurations:
            if c not in arch.configurations:
                known = ", ".join(arch.configurations)
                raise IdentifyError(f"{path}: unknown configuration {c!r}; known: {known}")
        confs = list(dict.fromkeys(configurations))
    else:
        confs = list(arch.configurations)
    return text, arch, scenario, confs


def _experiments(
    arch: Any,
    configuration: str,
    kind: str,
    magnitude: float,
    perturb: Mapping[str, tuple[str, float]],
) -> tuple[list[tuple[str, str, float]], list[str]]:
    """The perturbations of one configuration, and the active modules left out (with why)."""
    from archself import registry

    active = arch.configurations[configuration].modules
    chosen: list[tuple[str, str, float]] = []
    skipped: list[str] = []
    for m in active:
        k, mag = perturb.get(m, (kind, magnitude))
        cls = registry.get(arch.modules[m].type)
        if k not in cls.fault_kinds:
            skipped.append(f"{m} (takes no {k} fault)")
        elif mag == 0:
            skipped.append(f"{m} (magnitude 0)")
        else:
            chosen.append((m, k, float(mag)))
    return chosen, skipped


def identify(
    path: str | Path,
    *,
    configurations: Sequence[str] | None = None,
    scenario: str | None = None,
    seeds: int = 3,
    kind: str = "bias",
    magnitude: float = 0.1,
    perturb: Mapping[str, tuple[str, float]] | None = None,
    settle_s: float | None = None,
    min_excitation: float = 0.05,
    root_seed: int = 0,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Identification:
    """Estimate the edge weights W of an architecture file from perturbation experiments.

    Parameters
    ----------
    path : str or Path
        The architecture file.
    configurations : sequence of str, optional
        Configurations to identify in (default: all).
    scenario : str, optional
        The fault-free scenario to run (default: ``nominal``, else the first fault-free one).
    seeds : int
        Runs per experiment (and of the unperturbed run) per configuration.
    kind, magnitude : str, float
        The fault of each experiment (on the module's main output from t = 0).
    perturb : mapping, optional
        module -> (kind, magnitude) overriding ``kind``/``magnitude`` for that
        module (magnitude 0 leaves it out).
    settle_s : float, optional
        Averages start here (default: the warm-up plus five times the longest
        residual smoothing time constant).
    min_excitation : float
        A source whose |Δr| stays at or below this in every usable equation is
        not identifiable (units of r: a band's width under ``nominal`` normalization).
    root_seed : int
        Root of the seed sequence (the campaign's).
    executor, workers, address
        Where the runs go: ``local``, ``dask`` or ``inline``.
    progress : callable, optional
        ``progress(done, total)``.

    Returns
    -------
    Identification

    Raises
    ------
    IdentifyError
        A file with errors, no residual, no fault-free scenario, an unknown
        configuration, or no experiment possible.
    """
    from archself.calibration.runs import seeds_from
    from archself.runtime.knowledge import Knowledge, active_edges

    if seeds < 1:
        raise IdentifyError("--seeds must be at least 1")
    text, arch, scen, confs = _prepare(path, scenario, configurations)
    perturb = dict(perturb or {})
    for m in perturb:
        if m not in arch.modules:
            raise IdentifyError(f"{path}: --perturb names unknown module {m!r}")
    rt = arch.runtime
    residual = {m: spec.residual for m, spec in arch.modules.items() if spec.residual is not None}
    names = list(residual)
    if settle_s is None:
        longest = max(float(r.smoothing_s) for r in residual.values())
        settle_s = float(rt.warmup_time_s) + 5.0 * longest
    duration = float(arch.scenarios[scen].duration_s)
    if settle_s >= duration:
        raise IdentifyError(
            f"{path}: settling time {settle_s:g} s is not shorter than scenario {scen!r} "
            f"({duration:g} s)"
        )
    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()
    seed_list = seeds_from(root_seed, 0, seeds)
    plan: dict[str, tuple[list[tuple[str, str, float]], list[str]]] = {}
    jobs: list[IdJob] = []
    for c in confs:
        exps, skipped = _experiments(arch, c, kind, magnitude, perturb)
        plan[c] = (exps, skipped)
        for rep, sd in enumerate(seed_list):
            for p in [None, *exps]:
                jobs.append(IdJob(text, digest, str(path), scen, c, rep, int(sd), p, settle_s))
    if not any(exps for exps, _ in plan.values()):
        raise IdentifyError(
            f"{path}: no active module takes a {kind!r} fault; choose another --kind or --perturb"
        )
    t0 = time.perf_counter()
    results = _run_jobs(jobs, executor, workers, address, progress)
    elapsed = time.perf_counter() - t0

    failed = [
        f"{r['configuration']} seed {r['seed']} {r['experiment'] or 'nominal'}: {r['error']}"
        for r in results
        if r["error"] is not None
    ]
    by = {(r["configuration"], r["replicate"], r["experiment"]): r for r in results}
    knowledge = Knowledge(arch)
    rows: list[EdgeRow] = []
    fits: dict[str, dict[str, TargetFit]] = {}
    experiments: list[Experiment] = []
    sens = np.array([float(residual[m].sensitivity) for m in names])
    scale = np.array(
        [float(residual[m].nominal) if rt.normalization == "nominal" else 1.0 for m in names]
    )
    for c in confs:
        conf = arch.configurations[c]
        active = list(conf.modules)
        observed = [m for m in names if m in set(active)]
        cols = [names.index(m) for m in observed]
        keys = sorted(active_edges(arch, active, conf.disabled_edges))
        pairs = list(dict.fromkeys((s, t) for s, t, _ in keys))
        exps, _ = plan[c]
        dr_rows: list[np.ndarray] = []
        exp_of: list[str] = []
        for m, k, mag in exps:
            deltas = []
            for rep in range(seeds):
                base, pert = by.get((c, rep, None)), by.get((c, rep, m))
                if base is None or pert is None or base["error"] or pert["error"]:
                    continue
                d = delta_residuals(pert["mean"], base["mean"], sens, scale)[cols]
                dr_rows.append(d)
                exp_of.append(m)
                deltas.append(d)
            if deltas:
                mean = np.mean(deltas, axis=0)
                own = float(mean[observed.index(m)]) if m in observed else math.nan
                experiments.append(
                    Experiment(c, m, k, mag, len(deltas), own, float(np.abs(mean).max()))
                )
        dr = np.array(dr_rows, dtype=float).reshape(len(dr_rows), len(observed))
        estimates, target_fits = fit_edges(
            dr, exp_of, observed, pairs, min_excitation=min_excitation
        )
        fits[c] = target_fits
        est_of: dict[tuple[str, str], EdgeEstimate] = {(e.source, e.target): e for e in estimates}
        for s, t in pairs:
            e = est_of[(s, t)]
            carries = [cr for (a, b, cr) in keys if (a, b) == (s, t)]
            declared = sum(knowledge.arch_weight(s, t, cr) for cr in carries)
            rows.append(
                EdgeRow(
                    c,
                    s,
                    t,
                    carries,
                    declared,
                    declared * knowledge.w_scale,
                    e.weight,
                    e.se,
                    e.identifiable,
                    e.reason,
                )
            )
    runs = len(jobs)
    return Identification(
        architecture=arch.name,
        file=str(path),
        scenario=scen,
        configurations=confs,
        seeds=seeds,
        root_seed=root_seed,
        w_scale=knowledge.w_scale,
        settle_s=settle_s,
        rows=rows,
        fits=fits,
        experiments=experiments,
        skipped={c: plan[c][1] for c in confs},
        failed=failed,
        runs=runs,
        elapsed_s=elapsed,
        executor=executor,
        text=text,
    )


# --------------------------------------------------------------------------- output
def _f(v: float, digits: int = 3) -> str:
    return "—" if not (isinstance(v, float | int) and math.isfinite(v)) else f"{v:.{digits}f}"


def _flag(r: EdgeRow) -> str:
    d = r.differs
    return "" if d is None else ("DIFFERS" if d else "ok")


def summary_text(ident: Identification, *, all_edges: bool = False) -> str:
    """The terminal table: identifiable edges per configuration, then the rest counted."""
    lines = [
        f"identify {ident.file} · scenario {ident.scenario} · {ident.seeds} seed"
        f"{'s' * (ident.seeds != 1)} · {ident.runs} runs in {ident.elapsed_s:.1f} s "
        f"({ident.executor}) · averages after {ident.settle_s:g} s"
    ]
    if ident.w_scale != 1.0:
        lines.append(f"declared weights × {ident.w_scale:.4g} (the loop's ρ(W) scale) = effective")
    for c in ident.configurations:
        rows = [r for r in ident.rows if r.configuration == c]
        shown = [r for r in rows if r.identifiable or all_edges]
        lines.append("")
        lines.append(f"configuration {c}")
        width = max([len(f"{r.source} -> {r.target}") for r in shown] + [4])
        lines.append(f"  {'edge':<{width}}  {'declared':>8}  {'fitted':>8}  {'SE':>7}  flag")
        for r in shown:
            edge = f"{r.source} -> {r.target}"
            if r.identifiable:
                lines.append(
                    f"  {edge:<{width}}  {r.effective:>8.3f}  {r.fitted:>8.3f}  "
                    f"{_f(r.se):>7}  {_flag(r)}"
                )
            else:
                lines.append(
                    f"  {edge:<{width}}  {r.effective:>8.3f}  {'—':>8}  {'—':>7}  "
                    f"not identifiable: {r.reason}"
                )
        hidden = len(rows) - len(shown)
        if hidden:
            lines.append(f"  ({hidden} more edge{'s' * (hidden != 1)} not identifiable; --all)")
        fits = ident.fits.get(c, {})
        if fits:
            lines.append(
                "  fit per target: "
                + ", ".join(f"{t} R² {_f(f.r2, 2)} ({f.rows} eq.)" for t, f in fits.items())
            )
        skipped = ident.skipped.get(c) or []
        if skipped:
            lines.append(f"  not perturbed: {', '.join(skipped)}")
    if ident.failed:
        lines.append("")
        lines.append(f"{len(ident.failed)} failed run(s); first: {ident.failed[0]}")
    return "\n".join(lines) + "\n"


def markdown_table(ident: Identification) -> str:
    """The report as Markdown: the edge table, the fit per target, the experiments."""
    out = [
        f"# Identified influence weights of {ident.architecture}",
        "",
        f"File `{ident.file}`, scenario `{ident.scenario}`, {ident.seeds} seeds, "
        f"{ident.runs} runs in {ident.elapsed_s:.1f} s ({ident.executor}); averages after "
        f"{ident.settle_s:g} s. Flag: |fitted − declared| > {FLAG_SE:g} SE.",
        "",
        "| configuration | edge | declared W | fitted W | SE | flag |",
        "| --- | --- | ---: | ---: | ---: | --- |",
    ]
    for r in ident.rows:
        if r.identifiable:
            out.append(
                f"| {r.configuration} | {r.source} → {r.target} | {r.effective:.3f} | "
                f"{r.fitted:.3f} | {_f(r.se)} | {_flag(r)} |"
            )
        else:
            out.append(
                f"| {r.configuration} | {r.source} → {r.target} | {r.effective:.3f} | — | — | "
                f"not identifiable: {r.reason} |"
            )
    out += [
        "",
        "| configuration | target | equations | largest Δr | R² | RMS of the fit |",
        "| --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for c, fits in ident.fits.items():
        for t, f in fits.items():
            out.append(
                f"| {c} | {t} | {f.rows} | {_f(f.moved, 4)} | {_f(f.r2, 2)} | {_f(f.rms, 4)} |"
            )
    out += [
        "",
        "| configuration | perturbed | fault | own Δr | largest Δr |",
        "| --- | --- | --- | ---: | ---: |",
    ]
    for e in ident.experiments:
        out.append(
            f"| {e.configuration} | {e.module} | {e.kind} {e.magnitude:g} | {_f(e.own_delta)} | "
            f"{_f(e.max_delta)} |"
        )
    return "\n".join(out) + "\n"


# --------------------------------------------------------------------------- write-back
def format_weight(value: float) -> str:
    """A weight as a YAML float with 3 decimals (``0.0`` for zero).

    Examples
    --------
    >>> format_weight(0.41234), format_weight(0.0), format_weight(1.0)
    ('0.412', '0.0', '1.0')
    """
    text = f"{round(value, 3):.3f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def set_weights(text: str, file: str, values: Mapping[tuple[str, str], float], comment: str) -> str:
    """The text with the weights of the edges ``source → target`` set to ``values``.

    Parallel edges of a pair (several ``carries``) share the fitted weight in the
    proportion of their declared weights (equally when those are 0). Every
    changed line gets ``# identified: <comment>``; nothing else changes
    (:mod:`archself.calibration.edit` does the same for bands). The result is
    loaded again and checked.

    Raises
    ------
    LoadError
        An edge whose weight is not a plain scalar, or is shared through a YAML alias.
    """
    from ruamel.yaml import YAML
    from ruamel.yaml.nodes import MappingNode, ScalarNode, SequenceNode

    from archself.calibration.edit import _child, replace_scalars

    root = YAML(typ="rt").compose(text)
    seq = _child(root, "edges")
    if not isinstance(seq, SequenceNode):
        raise LoadError("no edges to write weights into", file, path="edges")
    from archself.ports import split_ref

    mods = _child(root, "modules")
    names = {k.value for k, _ in mods.value} if isinstance(mods, MappingNode) else set()
    groups: dict[tuple[str, str], list[tuple[int, Any, float]]] = {}
    for i, item in enumerate(seq.value):
        if not isinstance(item, MappingNode):
            continue
        s, t, w = _child(item, "from"), _child(item, "to"), _child(item, "weight")
        if not (isinstance(s, ScalarNode) and isinstance(t, ScalarNode)):
            continue
        key = (split_ref(s.value, names)[0], split_ref(t.value, names)[0])  # module.port ends
        if key in values:
            if not isinstance(w, ScalarNode):
                raise LoadError("edge weight is not a plain value", file, path=f"edges.{i}.weight")
            groups.setdefault(key, []).append((i, w, float(w.value)))
    edits: dict[int, tuple[int, int, str]] = {}
    expect: dict[int, float] = {}
    for key, items in groups.items():
        total = sum(d for _, _, d in items)
        for i, node, d in items:
            share = d / total if total > 0 else 1.0 / len(items)
            new = format_weight(values[key] * share)
            if id(node) in edits and edits[id(node)][2] != new:
                raise LoadError(
                    "edge weight is shared (a YAML alias) with another edge; write it out",
                    file,
                    node.start_mark.line + 1,
                    node.start_mark.column + 1,
                    f"edges.{i}.weight",
                )
            edits[id(node)] = (node.start_mark.index, node.end_mark.index, new)
            expect[i] = float(new)
    result = replace_scalars(text, list(edits.values()), comment, COMMENT_TAG)
    from archself.loader import load_text

    arch = load_text(result, file).arch
    for i, w in expect.items():
        if arch.edges[i].weight != w:  # pragma: no cover - a bug of the editor
            raise LoadError(f"writing the weight of edge {i} failed", file)
    return result


def written_copy(ident: Identification) -> str:
    """The file's text with the fitted weights (pooled over configurations) written in."""
    pooled = ident.fitted_weights()
    values = {k: w for k, (w, _) in pooled.items()}
    if not values:
        raise IdentifyError(f"{ident.file}: no edge was identifiable; nothing to write back")
    comment = (
        f"archself identify, {ident.seeds} seeds, scenario {ident.scenario}, "
        f"configurations {'/'.join(ident.configurations)}"
    )
    return set_weights(ident.text, ident.file, values, comment)
