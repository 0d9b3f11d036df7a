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
from pathlib import Path
from typing import Any

import numpy as np

from archself.calibration.bands import (
    Cell,
    Prediction,
    channel_shape,
    critical_scales,
    influence_block,
)
from archself.calibration.prepare import parse_envelope, prepare
from archself.calibration.result import Calibration, CalibrationError, CellResult, ModuleBand

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
    from archself.campaign.plan import BYTES_PER_RUN, past_half_memory

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
    from archself.calibration import runs as R
    from archself.calibration.edit import format_band, set_nominals
    from archself.calibration.saved_runs import band_free_digest, load_runs
    from archself.calibration.saved_runs import save_runs as write_runs
    from archself.campaign.sweep import sweep_points

    p = float(false_switch)
    if not 0.0 < p < 1.0:
        raise CalibrationError(f"--false-switch {false_switch}: expected a rate in (0, 1)")
    if seeds < 1:
        raise CalibrationError("--seeds must be at least 1")
    if verify_seeds < 0:
        raise CalibrationError("--verify-seeds must be at least 0")
    text, loaded, chosen, confs, tau = prepare(arch_path, scenarios, configurations)
    arch = loaded.arch
    file = loaded.file
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
    elapsed = verify_elapsed = 0.0
    if from_runs is None:
        _check_size(arch, file, (seeds + verify_seeds) * n_points, chosen, confs)
    if from_runs is not None:
        meta, saved = load_runs(from_runs)
        if meta.get("digest") != digest:
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
        seeds, verify_seeds = int(meta["seeds"]), int(meta["verify_seeds"])
        chosen, confs = list(meta["scenarios"]), list(meta["configurations"])
        root_seed = int(meta["root_seed"])
        elapsed, verify_elapsed = float(meta["elapsed_s"]), float(meta["verify_elapsed_s"])
        results = [r for r in saved if r["phase"] == "calibration"]
        vres = [r for r in saved if r["phase"] == "verify"]
        executor = f"{meta['executor']}, runs from {Path(from_runs).name}"
    else:
        def run(phase: str, first: int, n: int) -> tuple[list[dict[str, Any]], float]:
            """Replicates ``first … first+n−1`` (each envelope point its own seeds)."""
            t0 = time.perf_counter()
            jobs = R.plan_runs(
                text, file, chosen, confs, R.seeds_from(root_seed, first * n_points, n * n_points),
                first_replicate=first, phase=phase, envelope=sweeps,
            )
            got = R.run_jobs(
                jobs, executor=executor, workers=workers, address=address, progress=progress
            )
            return got, time.perf_counter() - t0

        results, elapsed = run("calibration", 0, seeds)
        vres = []
        if verify_seeds:
            vres, verify_elapsed = run("verify", seeds, verify_seeds)
        if save_runs is not None:
            meta = {
                "format": 1,
                "architecture": arch.name,
                "digest": digest,
                "seeds": seeds,
                "verify_seeds": verify_seeds,
                "root_seed": root_seed,
                "scenarios": chosen,
                "configurations": confs,
                "executor": executor,
                "elapsed_s": elapsed,
                "verify_elapsed_s": verify_elapsed,
            }
            write_runs(save_runs, meta, results + vres)
    cells = _cells(arch, results)
    for c in cells:
        if c.runs == 0:
            raise CalibrationError(
                f"{file}: every run of {c.scenario} in {c.configuration} failed: {c.failed[0]}"
            )

    old = {m: float(s.residual.nominal) for m, s in arch.modules.items() if s.residual}
    # shape: each channel alone alarms in a share p/K of the runs, worst cell
    base: dict[str, float] = {}
    where: dict[str, list[str]] = {}
    for c in cells:
        for m in c.modules:
            where.setdefault(m, [])
            if c.configuration not in where[m]:
                where[m].append(c.configuration)
            base[m] = max(base.get(m, 0.0), channel_shape(c, m, p, tau, weights))
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
    results_cells = []
    for c, s_needed in zip(cells, needed, strict=True):
        f_old, f_new = Prediction.of(c, old, tau), Prediction.of(c, new, tau)
        results_cells.append(
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

    verify_cells: list[Cell] = []
    if vres:
        verify_cells = _cells(arch, vres)
        by_key = {(c.scenario, c.configuration): c for c in verify_cells}
        for r in results_cells:
            vc = by_key.get((r.scenario, r.configuration))
            if vc is None or vc.runs == 0:
                continue
            r.verify_runs = vc.runs
            r.verify_new = float(np.mean(critical_scales(vc, new, tau) >= 1.0))
            r.verify_old = float(np.mean(critical_scales(vc, old, tau) >= 1.0))

    cells_text = (
        f"{len(confs)} configuration{'s' * (len(confs) != 1)}"
        if len(chosen) == 1
        else f"{len(cells)} (scenario, configuration)"
    )
    if sweeps:
        cells_text += f" × {n_points} envelope point{'s' * (n_points != 1)}"
    weighted = "".join(f", weight {m} {w:g}" for m, w in sorted(weights.items()) if w != 1)
    comment = f"p = {p:g}/run{weighted}, {seeds} nominal runs × {cells_text} (archself calibrate)"
    new_text = set_nominals(text, file, {m: new[m] for m in calibrated}, comment)
    modules = {
        m: ModuleBand(
            name=m,
            old=old[m],
            new=new[m],
            base=shape[m],
            sensitivity=float(arch.modules[m].residual.sensitivity),
            signal=arch.modules[m].residual.signal,
            configurations=where.get(m, []),
            calibrated=m in calibrated,
            note=notes.get(m, ""),
            weight=float(weights.get(m, 1.0)),
        )
        for m in old
    }
    return Calibration(
        architecture=arch.name,
        file=file,
        tau=tau,
        false_switch=p,
        seeds=seeds,
        root_seed=root_seed,
        scenarios=chosen,
        configurations=confs,
        scale=scale,
        modules=modules,
        cells=results_cells,
        data=cells,
        text=new_text,
        comment=comment,
        executor=executor,
        workers=workers,
        elapsed_s=elapsed,
        runs=len(results),
        verify_seeds=verify_seeds,
        verify_elapsed_s=verify_elapsed,
        verify_data=verify_cells,
    )
