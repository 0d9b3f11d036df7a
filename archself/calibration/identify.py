"""``archself identify``: the influence weights W of the edges, estimated from experiments.

For each configuration, the fault-free scenario runs fixed in it once per seed
unperturbed and once per seed and *experiment*: a small fault (``bias`` by
default, from t = 0) on the main output of one active module that takes it —
modules with a residual and hidden ones (sensors, actuators without a residual
block) alike. The runs are sampled like calibration runs (the Monitor's filtered
residual signals every ``runtime.period_s``, :class:`archself.calibration.runs.Recorder`),
time-averaged after the settling time, and the difference perturbed − nominal
of the same seed (common random numbers) gives Δr in the loop's units. The
weights are then fitted per target module (:mod:`~archself.runtime.identify_fit`)
and compared with the declared ones (times the loop's ρ(W) scale).

The runs go to the campaign executors (local process pool, Dask, or inline).
:func:`set_weights` writes the fitted weights into a copy of the file's text,
comments and layout kept, like :mod:`archself.calibration.edit` does for bands.
See docs/identify.md. The result types and their
tables are in :mod:`~archself.calibration.identify_results`; :func:`set_weights` (in
:mod:`~archself.calibration.edit`) is re-exported here.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from archself import registry
from archself.calibration.edit import set_weights
from archself.calibration.identify_results import EdgeRow, Experiment, Identification, IdentifyError
from archself.calibration.prepare import chosen_configurations, load_checked
from archself.calibration.runs import record, run_on_executor, seeds_from
from archself.campaign.plan import BYTES_PER_RUN, past_half_memory
from archself.campaign.worker import RunJob, run_error
from archself.errors import unknown
from archself.model.architecture import Fault
from archself.runtime.identify_fit import TargetFit, delta_residuals, fit_edges
from archself.runtime.knowledge import Knowledge, active_edges

__all__ = ["Identification", "IdentifyError", "identify", "set_weights", "written_copy"]


def _prepare(path: str | Path, scenario: str | None, configurations: Sequence[str] | None):
    text, loaded = load_checked(path, IdentifyError)
    arch = loaded.arch
    if not any(m.residual is not None for m in arch.modules.values()):
        raise IdentifyError(f"{path}: no module declares a residual: nothing to identify")
    if scenario is not None:
        if scenario not in arch.scenarios:
            raise IdentifyError(f"{path}: {unknown('scenario', scenario, arch.scenarios)}")
        if arch.scenarios[scenario].faults:
            raise IdentifyError(
                f"{path}: scenario {scenario!r} has faults; identify needs a fault-free one"
            )
    else:
        free = [n for n, s in arch.scenarios.items() if not s.faults]
        if not free:
            raise IdentifyError(f"{path}: no fault-free scenario; declare one (no faults)")
        scenario = "nominal" if "nominal" in free else free[0]
    confs = chosen_configurations(arch, str(path), configurations, IdentifyError)
    return text, arch, scenario, confs


def _experiments(
    arch: Any,
    configuration: str,
    kind: str,
    magnitude: float,
    perturb: Mapping[str, tuple[str, float]],
) -> tuple[list[tuple[str, str, float]], list[str]]:
    """The perturbations of one configuration, and the active modules left out (with why)."""

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


def _fault(module: str, kind: str, magnitude: float) -> Any:
    """An experiment's fault: ``kind`` of ``magnitude`` on ``module`` from t = 0."""

    return Fault.model_validate({"module": module, "kind": kind, "onset_s": 0.0,
                                 "magnitude": magnitude})


def _check_fault(path: str | Path, module: str, kind: str, magnitude: float, own: bool) -> None:
    """Refuse a perturbation the fault model refuses, before any run (each run failed)."""
    from pydantic import ValidationError

    try:
        _fault(module, kind, magnitude)
    except ValidationError as exc:
        err = exc.errors()[0]
        opt = f"--perturb {module}={kind}:{magnitude:g}" if own else f"--magnitude {magnitude:g}"
        where = ".".join(str(x) for x in err.get("loc", ()))
        raise IdentifyError(f"{path}: {opt}: fault {where}: {err.get('msg', 'invalid')}") from None


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

    plan = _plan(path, configurations, scenario, seeds, kind, magnitude, perturb, settle_s,
                 min_excitation, root_seed)
    t0 = time.perf_counter()
    results = run_on_executor(
        plan.jobs, run_identify_job, "archself.calibration.identify",
        executor=executor, workers=workers, address=address, progress=progress,
    )
    return _collect(plan, results, time.perf_counter() - t0, executor)


@dataclass(frozen=True)
class _Plan:
    """What :func:`identify` knows before any run: the file, the experiments, the jobs."""

    path: str | Path
    text: str
    arch: Any
    scenario: str
    confs: list[str]
    seeds: int
    root_seed: int
    settle_s: float
    min_excitation: float
    #: configuration -> (its experiments (module, kind, magnitude), the modules left out)
    experiments: dict[str, tuple[list[tuple[str, str, float]], list[str]]]
    jobs: list[IdJob]


def _plan(
    path: str | Path, configurations: Sequence[str] | None, scenario: str | None, seeds: int,
    kind: str, magnitude: float, perturb: Mapping[str, tuple[str, float]] | None,
    settle_s: float | None, min_excitation: float, root_seed: int,
) -> _Plan:
    """Check the options and the file, choose the experiments, list the jobs.

    Raises
    ------
    IdentifyError
        As :func:`identify`, before any run.
    """
    if seeds < 1:
        raise IdentifyError("--seeds must be at least 1")
    if settle_s is not None and not (math.isfinite(settle_s) and settle_s >= 0):
        raise IdentifyError(f"--settle {settle_s:g}: expected a time ≥ 0 s")
    if not (math.isfinite(min_excitation) and min_excitation >= 0):
        raise IdentifyError(f"--min-excitation {min_excitation:g}: expected a number ≥ 0")
    text, arch, scen, confs = _prepare(path, scenario, configurations)
    perturb = dict(perturb or {})
    for m in perturb:
        if m not in arch.modules:
            raise IdentifyError(f"{path}: --perturb names unknown module {m!r}")
    if settle_s is None:
        longest = max(float(s.residual.smoothing_s) for s in arch.modules.values() if s.residual)
        settle_s = float(arch.runtime.warmup_time_s) + 5.0 * longest
    duration = float(arch.scenarios[scen].duration_s)
    if settle_s >= duration:
        raise IdentifyError(
            f"{path}: settling time {settle_s:g} s is not shorter than scenario {scen!r} "
            f"({duration:g} s)"
        )
    _check_size(path, arch, confs, seeds)
    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()
    seed_list = seeds_from(root_seed, 0, seeds)
    plan: dict[str, tuple[list[tuple[str, str, float]], list[str]]] = {}
    jobs: list[IdJob] = []
    for c in confs:
        exps, skipped = _experiments(arch, c, kind, magnitude, perturb)
        for m, k, mag in exps:  # what every run would refuse (a magnitude past 1e9)
            _check_fault(path, m, k, mag, m in perturb)
        plan[c] = (exps, skipped)
        for rep, sd in enumerate(seed_list):
            for p in [None, *exps]:
                jobs.append(IdJob(arch_text=text, arch_digest=digest, file=str(path), scenario=scen,
                                  replicate=rep, seed=int(sd), configuration=c, perturb=p,
                                  settle_s=settle_s))
    if not any(exps for exps, _ in plan.values()):
        raise IdentifyError(
            f"{path}: no active module takes a {kind!r} fault; choose another --kind or --perturb"
        )
    return _Plan(path, text, arch, scen, confs, seeds, root_seed, settle_s, min_excitation,
                 plan, jobs)


def _check_size(path: str | Path, arch: Any, confs: Sequence[str], seeds: int) -> None:
    """Refuse runs the driver could not hold: at most one run a seed per module and the
    unperturbed one, each held by the driver, past half the memory (``--seeds 100000000``
    grew for minutes, no run started)."""

    most = seeds * sum(1 + len(arch.configurations[c].modules) for c in confs)
    if too_much := past_half_memory(most * BYTES_PER_RUN):
        raise IdentifyError(
            f"{path}: up to {most:,} runs would need ~{most * BYTES_PER_RUN / 1024**3:,.1f} GB, "
            f"{too_much}; use fewer --seeds or configurations"
        )


# --------------------------------------------------------------------------- runs
@dataclass(frozen=True, kw_only=True)
class IdJob(RunJob):
    """One run: (configuration, seed), unperturbed or with one perturbation
    (:class:`~archself.campaign.worker.RunJob` and the following).

    ``perturb`` is ``(module, kind, magnitude)`` or None for the nominal run.
    """

    configuration: str
    perturb: tuple[str, str, float] | None
    settle_s: float


def run_identify_job(job: IdJob) -> dict[str, Any]:
    """Run one job; never raises for a failed run.

    Returns
    -------
    dict
        ``configuration``, ``replicate``, ``seed``, ``experiment`` (the perturbed
        module or None), ``mean`` (time-averaged |s̄| per residual module after
        ``settle_s``, float64, in the file's module order), ``error``.
    """

    out: dict[str, Any] = {
        "configuration": job.configuration,
        "replicate": job.replicate,
        "seed": job.seed,
        "experiment": job.perturb[0] if job.perturb else None,
        "error": None,
    }
    try:
        arch = job.architecture().model_copy(deep=True)
        if job.perturb is not None:
            arch.scenarios[job.scenario].faults.append(_fault(*job.perturb))
        got = record(arch, job)
        keep = got["t"] >= job.settle_s - 1e-9
        if not keep.any():
            raise IdentifyError(f"no sample after the settling time {job.settle_s:g} s")
        out["mean"] = got["x"][keep].mean(axis=0)
    except Exception as exc:  # noqa: BLE001 - a failed run is reported, not fatal
        out["error"] = run_error(exc)
    return out


def _collect(
    plan: _Plan, results: list[dict[str, Any]], elapsed: float, executor: str
) -> Identification:
    """The fitted weights of every configuration beside the declared ones."""

    failed = [
        f"{r['configuration']} seed {r['seed']} {r['experiment'] or 'nominal'}: {r['error']}"
        for r in results
        if r["error"] is not None
    ]
    by = {(r["configuration"], r["replicate"], r["experiment"]): r for r in results}
    knowledge = Knowledge(plan.arch)
    rows: list[EdgeRow] = []
    fits: dict[str, dict[str, TargetFit]] = {}
    experiments: list[Experiment] = []
    for c in plan.confs:
        fits[c] = _fit(plan, c, by, knowledge, rows, experiments)
    return Identification(
        architecture=plan.arch.name,
        file=str(plan.path),
        scenario=plan.scenario,
        configurations=plan.confs,
        seeds=plan.seeds,
        root_seed=plan.root_seed,
        w_scale=knowledge.w_scale,
        settle_s=plan.settle_s,
        rows=rows,
        fits=fits,
        experiments=experiments,
        skipped={c: plan.experiments[c][1] for c in plan.confs},
        failed=failed,
        runs=len(plan.jobs),
        elapsed_s=elapsed,
        executor=executor,
        text=plan.text,
    )


def _fit(
    plan: _Plan, c: str, by: Mapping[tuple[str, int, str | None], dict[str, Any]],
    knowledge: Any, rows: list[EdgeRow], experiments: list[Experiment],
) -> dict[str, TargetFit]:
    """Fit the weights into each observed module of configuration ``c``; its edges appended
    to ``rows``, its experiments' mean Δr to ``experiments``; the fits per target."""

    arch = plan.arch
    residual = {m: spec.residual for m, spec in arch.modules.items() if spec.residual is not None}
    names = list(residual)
    sens = np.array([float(residual[m].sensitivity) for m in names])
    nominal = arch.runtime.normalization == "nominal"
    scale = np.array([float(residual[m].nominal) if nominal else 1.0 for m in names])
    conf = arch.configurations[c]
    active = list(conf.modules)
    observed = [m for m in names if m in set(active)]
    cols = [names.index(m) for m in observed]
    keys = sorted(active_edges(arch, active, conf.disabled_edges))
    pairs = list(dict.fromkeys((s, t) for s, t, _ in keys))
    dr_rows: list[np.ndarray] = []
    exp_of: list[str] = []
    for m, k, mag in plan.experiments[c][0]:
        deltas = []
        for rep in range(plan.seeds):
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
            peak = float(np.abs(mean).max())
            experiments.append(Experiment(c, m, k, mag, len(deltas), own, peak))
    dr = np.array(dr_rows, dtype=float).reshape(len(dr_rows), len(observed))
    estimates, fits = fit_edges(dr, exp_of, observed, pairs, min_excitation=plan.min_excitation)
    for e in estimates:  # in the order of pairs
        s, t = e.source, e.target
        carries = [cr for (a, b, cr) in keys if (a, b) == (s, t)]
        declared = sum(knowledge.arch_weight(s, t, cr) for cr in carries)
        rows.append(EdgeRow(c, s, t, carries, declared, declared * knowledge.w_scale,
                            e.weight, e.se, e.identifiable, e.reason))
    return fits


def written_copy(ident: Identification) -> str:
    """The file's text with the fitted weights (pooled over configurations) written in."""
    values = {k: w for k, (w, _) in ident.fitted_weights().items()}
    if not values:
        raise IdentifyError(f"{ident.file}: no edge was identifiable; nothing to write back")
    comment = (
        f"archself identify, {ident.seeds} seeds, scenario {ident.scenario}, "
        f"configurations {'/'.join(ident.configurations)}"
    )
    return set_weights(ident.text, ident.file, values, comment)
