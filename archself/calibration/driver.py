"""``archself calibrate``: plan the nominal runs, run them, derive the bands.

:func:`calibrate` is the whole command without its output: it checks the file,
runs every fault-free scenario fixed in every configuration for N seeds
(:mod:`~archself.calibration.runs`, on a campaign executor), derives the bands
(:mod:`~archself.calibration.bands`) and returns a :class:`Calibration` holding
the old and new bands, the predicted and empirical false-alarm rates per
(scenario, configuration) and the calibrated text of the file
(:mod:`~archself.calibration.edit`). Optionally it measures the rate of the new
bands on fresh seeds (``verify_seeds``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from archself.calibration import runs as R
from archself.calibration.bands import (
    Cell,
    Prediction,
    channel_shape,
    critical_scales,
    influence_block,
)
from archself.calibration.edit import format_band, set_nominals
from archself.calibration.prepare import parse_envelope, prepare
from archself.calibration.result import Calibration, CalibrationError, CellResult, ModuleBand
from archself.calibration.runs import band_free_digest, load_runs
from archself.campaign.plan import BYTES_PER_RUN, past_half_memory
from archself.campaign.sweep import sweep_points

__all__ = ["Calibration", "CalibrationError", "CellResult", "ModuleBand", "calibrate"]


def _cells(arch: Any, results: list[dict[str, Any]]) -> list[Cell]:
    names = [m for m, spec in arch.modules.items() if spec.residual is not None]
    col = {m: j for j, m in enumerate(names)}
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in results:
        groups.setdefault((r["scenario"], r["configuration"]), []).append(r)
    cells = []
    for (sc, conf), rows in groups.items():
        active = set(arch.configurations[conf].modules)
        mods = [m for m in names if m in active]
        idx = [col[m] for m in mods]
        ok = [r for r in rows if r["error"] is None]
        cells.append(
            Cell(
                scenario=sc,
                configuration=conf,
                modules=mods,
                x=[np.asarray(r["x"])[:, idx] for r in ok],
                forced=np.array([bool(np.any(r["forced"])) for r in ok], dtype=bool),
                m=influence_block(arch, conf, mods),
                sens=np.array([float(arch.modules[m].residual.sensitivity) for m in mods]),
                seeds=[int(r["seed"]) for r in ok],
                failed=[f"seed {r['seed']}: {r['error']}" for r in rows if r["error"] is not None],
            )
        )
    return cells


def _check_size(
    arch: Any, file: str, per_cell: int, scenarios: Sequence[str], confs: Sequence[str]
) -> None:
    """Refuse runs whose recorded residuals would not fit in half of the memory.

    Every run's residuals (one row a cycle, a column per residual module) are kept
    until the bands are fitted: ``--seeds 100000000`` grew past 1.8 GB in 30 s
    before a single run started, and would have ended out of memory.
    """

    runs = per_cell * len(scenarios) * len(confs)
    width = sum(1 for spec in arch.modules.values() if spec.residual is not None)
    cycles = max(float(arch.scenarios[s].duration_s) for s in scenarios) / float(
        arch.runtime.period_s)
    need = runs * (BYTES_PER_RUN + 8 * (width + 2) * (cycles + 1))
    if too_much := past_half_memory(need):
        raise CalibrationError(
            f"{file}: {runs:,} runs would hold ~{need / 1024**3:,.1f} GB of residuals, "
            f"{too_much}; use fewer --seeds, --verify-seeds, configurations or --envelope "
            "points"
        )


def calibrate(
    arch_path: str | Path,
    *,
    false_switch: float = 0.01,
    seeds: int = 100,
    scenarios: Sequence[str] | None = None,
    configurations: Sequence[str] | None = None,
    root_seed: int = 0,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
    verify_seeds: int = 0,
    progress: Callable[[int, int], None] | None = None,
    save_runs: str | Path | None = None,
    from_runs: str | Path | None = None,
    envelope: Sequence[str] = (),
    weights: Mapping[str, float] | None = None,
) -> Calibration:
    """Run the nominal scenarios and derive bands for a false-alarm rate per run.

    Parameters
    ----------
    arch_path : path
        The architecture file (checked first; a file with errors is refused).
    false_switch : float
        Target p in (0, 1): the share of nominal runs (of the scenario's
        duration) with a candidate after the warm-up, in every configuration.
    seeds : int
        Runs per (scenario, configuration).
    scenarios, configurations : sequence of str, optional
        Default: every fault-free scenario; every configuration.
    root_seed : int
        Seeds are children ``0 … seeds−1`` of ``SeedSequence(root_seed)``
        (verification: the next ``verify_seeds`` children).
    executor, workers, address
        As for ``archself campaign`` (``"inline"`` runs in this process).
    verify_seeds : int
        Also measure the rate of the new (and old) bands on this many fresh seeds.
    progress : callable, optional
        ``progress(done, total)`` after every run.
    save_runs : path, optional
        Also write the runs' residuals to this ``.npz`` file.
    from_runs : path, optional
        Take the runs from a file written by ``save_runs`` instead of running them
        (its seeds, scenarios and configurations; the architecture must be the same
        but for its bands).
    envelope : sequence of str
        The operating envelope, as ``archself campaign --sweep`` specs
        (``PATH=v1,v2`` or ``PATH=START:STOP:NUM``): every point of their product
        is run with seeds of its own (children ``p·seeds …`` of the root for point
        ``p``), and the bands hold the rate in the worst of them (e.g.
        ``modules.gps.params.noise_m.value=0.2,0.3,0.4``).
    weights : mapping of str to float, optional
        A module's weight in the split of the false-alarm budget between the channels
        of a configuration (default 1 each: an equal share p/K): module j alone
        alarms in a share p·w_j/Σw of the runs. A heavier weight gives a channel a
        narrower band and the others wider ones; the total stays p.

    Raises
    ------
    CalibrationError, LoadError
        A file with errors, ``normalization: none``, ``top_k``, no fault-free
        scenario, a rate that no band can give, every run failing.
    """
    plan = _plan(
        arch_path, false_switch, seeds, scenarios, configurations, verify_seeds, root_seed,
        envelope, weights, executor, workers, check_size=from_runs is None,
    )
    if from_runs is not None:
        plan, runs = _saved(plan, from_runs)
    else:
        runs = _run(plan, address, progress, save_runs)
    return _collect(plan, runs)


@dataclass(frozen=True)
class _Plan:
    """What :func:`calibrate` knows before any run: the file, the cells, the target, the seeds."""

    text: str
    arch: Any
    file: str
    chosen: list[str]
    confs: list[str]
    tau: float
    p: float
    weights: dict[str, float]
    sweeps: tuple[Any, ...]
    n_points: int
    digest: str
    seeds: int
    verify_seeds: int
    root_seed: int
    executor: str
    workers: int | None


@dataclass(frozen=True)
class _Runs:
    """The runs' rows (:func:`archself.calibration.runs.run_jobs`) and their wall times."""

    results: list[dict[str, Any]]
    vres: list[dict[str, Any]]
    elapsed: float = 0.0
    verify_elapsed: float = 0.0


def _plan(
    arch_path: str | Path, false_switch: float, seeds: int, scenarios: Sequence[str] | None,
    configurations: Sequence[str] | None, verify_seeds: int, root_seed: int,
    envelope: Sequence[str], weights: Mapping[str, float] | None, executor: str,
    workers: int | None, *, check_size: bool,
) -> _Plan:
    """Check the options and the file, choose the cells, refuse work past half the memory.

    Raises
    ------
    CalibrationError, LoadError
        As :func:`calibrate`, before any run.
    """

    p = float(false_switch)
    if not 0.0 < p < 1.0:
        raise CalibrationError(f"--false-switch {false_switch}: expected a rate in (0, 1)")
    if seeds < 1:
        raise CalibrationError("--seeds must be at least 1")
    if verify_seeds < 0:
        raise CalibrationError("--verify-seeds must be at least 0")
    text, loaded, chosen, confs, tau = prepare(arch_path, scenarios, configurations)
    arch, file = loaded.arch, loaded.file
    weights = dict(weights or {})
    for m, w in weights.items():
        if m not in arch.modules or arch.modules[m].residual is None:
            raise CalibrationError(f"--weight {m}={w:g}: {file} has no module {m!r} "
                                   "with a residual")
        if not (w > 0 and math.isfinite(w)):
            raise CalibrationError(f"--weight {m}={w:g}: expected a weight > 0")
    sweeps = parse_envelope(loaded, envelope)
    n_points = len(sweep_points(sweeps))
    digest = band_free_digest(loaded.data)
    if sweeps:
        digest += "|" + ";".join(f"{s.path}={s.values}" for s in sweeps)
    if check_size:
        _check_size(arch, file, (seeds + verify_seeds) * n_points, chosen, confs)
    return _Plan(text, arch, file, chosen, confs, tau, p, weights, sweeps, n_points,
                 digest, seeds, verify_seeds, root_seed, executor, workers)


def _saved(plan: _Plan, from_runs: str | Path) -> tuple[_Plan, _Runs]:
    """The runs of a ``save_runs`` file, and the plan they were run with (seeds, cells).

    Raises
    ------
    CalibrationError
        Runs of another architecture (not only the bands differ), a damaged file.
    """

    arch, file = plan.arch, plan.file
    meta, saved = load_runs(from_runs)
    if meta.get("digest") != plan.digest:
        raise CalibrationError(
            f"{from_runs}: runs of another architecture (not only the bands differ from "
            f"{file}); run them again without --from-runs"
        )
    width = sum(1 for spec in arch.modules.values() if spec.residual is not None)
    for one in saved:  # the digest matched: only a damaged file gets here
        if (one["scenario"] not in arch.scenarios
                or one["configuration"] not in arch.configurations
                or (one["error"] is None and one["x"].shape[1] != width)):
            raise CalibrationError(
                f"{from_runs}: a run of {one['scenario']!r} in {one['configuration']!r} does "
                f"not fit {file} (a damaged runs file); run them again without --from-runs"
            )
    plan = replace(
        plan, seeds=int(meta["seeds"]), verify_seeds=int(meta["verify_seeds"]),
        chosen=list(meta["scenarios"]), confs=list(meta["configurations"]),
        root_seed=int(meta["root_seed"]),
        executor=f"{meta['executor']}, runs from {Path(from_runs).name}",
    )
    return plan, _Runs(
        [r for r in saved if r["phase"] == "calibration"],
        [r for r in saved if r["phase"] == "verify"],
        float(meta["elapsed_s"]), float(meta["verify_elapsed_s"]),
    )


def _run(
    plan: _Plan, address: str | None, progress: Callable[[int, int], None] | None,
    save_runs: str | Path | None,
) -> _Runs:
    """Run the calibration (and verification) replicates; write them to ``save_runs``."""

    def run(phase: str, first: int, n: int) -> tuple[list[dict[str, Any]], float]:
        """Replicates ``first … first+n−1`` (each envelope point its own seeds)."""
        t0 = time.perf_counter()
        seeds = R.seeds_from(plan.root_seed, first * plan.n_points, n * plan.n_points)
        jobs = R.plan_runs(plan.text, plan.file, plan.chosen, plan.confs, seeds,
                           first_replicate=first, phase=phase, envelope=plan.sweeps)
        got = R.run_jobs(jobs, executor=plan.executor, workers=plan.workers, address=address,
                         progress=progress)
        return got, time.perf_counter() - t0

    results, elapsed = run("calibration", 0, plan.seeds)
    vres: list[dict[str, Any]] = []
    verify_elapsed = 0.0
    if plan.verify_seeds:
        vres, verify_elapsed = run("verify", plan.seeds, plan.verify_seeds)
    if save_runs is not None:
        meta = {
            "format": 1,
            "architecture": plan.arch.name,
            "digest": plan.digest,
            "seeds": plan.seeds,
            "verify_seeds": plan.verify_seeds,
            "root_seed": plan.root_seed,
            "scenarios": plan.chosen,
            "configurations": plan.confs,
            "executor": plan.executor,
            "elapsed_s": elapsed,
            "verify_elapsed_s": verify_elapsed,
        }
        R.save_runs(save_runs, meta, results + vres)
    return _Runs(results, vres, elapsed, verify_elapsed)


@dataclass(frozen=True)
class _Bands:
    """The bands derived from the cells: per module the old and new band, the shape."""

    old: dict[str, float]
    new: dict[str, float]
    shape: dict[str, float]
    where: dict[str, list[str]]
    notes: dict[str, str]
    calibrated: list[str]
    needed: list[float]
    scale: float


def _bands(plan: _Plan, cells: list[Cell]) -> _Bands:
    """Shape (each channel alone alarms in its share of p, worst cell) and scale (every
    cell's runs at most p false alarms) of the bands.

    Raises
    ------
    CalibrationError
        No module's residual calibrated, a rate no band gives, no candidate at any band.
    """

    arch, file, p, tau = plan.arch, plan.file, plan.p, plan.tau
    old = {m: float(s.residual.nominal) for m, s in arch.modules.items() if s.residual}
    # shape: each channel alone alarms in a share p/K of the runs, worst cell
    base: dict[str, float] = {}
    where: dict[str, list[str]] = {}
    for c in cells:
        for m in c.modules:
            where.setdefault(m, [])
            if c.configuration not in where[m]:
                where[m].append(c.configuration)
            base[m] = max(base.get(m, 0.0), channel_shape(c, m, p, tau, plan.weights))
    notes: dict[str, str] = {}
    for m in old:
        sens = float(arch.modules[m].residual.sensitivity)
        if m not in where:
            notes[m] = "not active in a calibrated configuration"
        elif sens == 0:
            notes[m] = "sensitivity 0: the band has no effect"
        elif not math.isfinite(base.get(m, math.nan)) or base.get(m, 0.0) <= 0:
            notes[m] = "no nominal signal (always 0 or unusable): the band has no effect"
    calibrated = [m for m in old if m not in notes]
    if not calibrated:
        raise CalibrationError(f"{file}: no module's residual could be calibrated")
    shape = {m: (base[m] if m in calibrated else old[m]) for m in old}

    # scale: every cell's runs at most p false alarms (predicted and empirical)
    needed = [Prediction.of(c, shape, tau).quantile(p) for c in cells]
    for c, s_c in zip(cells, needed, strict=True):
        if math.isinf(s_c):
            raise CalibrationError(
                f"{file}: {int(c.forced.sum())} of {c.runs} nominal runs of {c.scenario} in "
                f"{c.configuration} have a module unavailable after the warm-up: no band gives "
                f"a false-switch rate of {p:g}"
            )
    scale = max([0.0, *needed])
    if scale <= 0:
        raise CalibrationError(f"{file}: the nominal residuals raise no candidate at any band")
    new = {m: (float(format_band(scale * shape[m])) if m in calibrated else old[m]) for m in old}
    return _Bands(old, new, shape, where, notes, calibrated, needed, scale)


def _cell_results(
    plan: _Plan, cells: list[Cell], bands: _Bands, vres: list[dict[str, Any]]
) -> list[CellResult]:
    """Predicted and empirical rates of the old and new bands per cell, and on fresh
    seeds (``vres``) where verified."""
    tau = plan.tau
    results = []
    for c, s_needed in zip(cells, bands.needed, strict=True):
        f_old, f_new = Prediction.of(c, bands.old, tau), Prediction.of(c, bands.new, tau)
        results.append(
            CellResult(
                scenario=c.scenario,
                configuration=c.configuration,
                runs=c.runs,
                failed=c.failed,
                forced=int(c.forced.sum()),
                scale_needed=s_needed,
                old_predicted=f_old.predicted(1.0),
                old_empirical=f_old.empirical(1.0),
                new_predicted=f_new.predicted(1.0),
                new_empirical=f_new.empirical(1.0),
                fit_old=f_old,
                fit_new=f_new,
            )
        )
    if vres:
        by_key = {(c.scenario, c.configuration): c for c in _cells(plan.arch, vres)}
        for r in results:
            vc = by_key.get((r.scenario, r.configuration))
            if vc is None or vc.runs == 0:
                continue
            r.verify_runs = vc.runs
            r.verify_new = float(np.mean(critical_scales(vc, bands.new, tau) >= 1.0))
            r.verify_old = float(np.mean(critical_scales(vc, bands.old, tau) >= 1.0))
    return results


def _comment(plan: _Plan, cells: list[Cell]) -> str:
    """The comment written beside each new band: the rate, the weights, the runs."""
    confs, n_points = plan.confs, plan.n_points
    cells_text = (
        f"{len(confs)} configuration{'s' * (len(confs) != 1)}"
        if len(plan.chosen) == 1
        else f"{len(cells)} (scenario, configuration)"
    )
    if plan.sweeps:
        cells_text += f" × {n_points} envelope point{'s' * (n_points != 1)}"
    weighted = "".join(f", weight {m} {w:g}" for m, w in sorted(plan.weights.items()) if w != 1)
    return (f"p = {plan.p:g}/run{weighted}, {plan.seeds} nominal runs × {cells_text} "
            "(archself calibrate)")


def _collect(plan: _Plan, runs: _Runs) -> Calibration:
    """The bands, the rates per cell and the calibrated text, from the runs.

    Raises
    ------
    CalibrationError
        Every run of a cell failed, or as :func:`_bands`.
    """

    arch = plan.arch
    cells = _cells(arch, runs.results)
    for c in cells:
        if c.runs == 0:
            raise CalibrationError(
                f"{plan.file}: every run of {c.scenario} in {c.configuration} failed: "
                f"{c.failed[0]}"
            )
    bands = _bands(plan, cells)
    results_cells = _cell_results(plan, cells, bands, runs.vres)
    comment = _comment(plan, cells)
    new_text = set_nominals(
        plan.text, plan.file, {m: bands.new[m] for m in bands.calibrated}, comment)
    modules = {
        m: ModuleBand(
            name=m, old=bands.old[m], new=bands.new[m], base=bands.shape[m],
            sensitivity=float(arch.modules[m].residual.sensitivity),
            signal=arch.modules[m].residual.signal,
            configurations=bands.where.get(m, []), calibrated=m in bands.calibrated,
            note=bands.notes.get(m, ""), weight=float(plan.weights.get(m, 1.0)),
        )
        for m in bands.old
    }
    return Calibration(
        architecture=arch.name, file=plan.file, tau=plan.tau, false_switch=plan.p,
        seeds=plan.seeds, root_seed=plan.root_seed, scenarios=plan.chosen,
        configurations=plan.confs, scale=bands.scale, modules=modules, cells=results_cells,
        data=cells, text=new_text, comment=comment, executor=plan.executor,
        workers=plan.workers, elapsed_s=runs.elapsed, runs=len(runs.results),
        verify_seeds=plan.verify_seeds, verify_elapsed_s=runs.verify_elapsed,
    )
