"""The campaign driver: plan the runs, hand them to an executor, keep the results.

A campaign is the product scenarios × sweep points × seeds, each run once with
the architecture fixed and once with the MAPE-K loop (``modes``). Replicate
``k`` gets the seed of child ``k`` of ``numpy.random.SeedSequence(root_seed)``;
the same replicate index uses the same seed in every scenario, sweep point and
mode (common random numbers: fixed and adaptive runs, and neighbouring sweep
values, see the same noise). A run's row depends only on its job, so the
table is the same whatever the number of workers or the order they finish in.

Results are written atomically to the Parquet file every few seconds and at
the end; an interrupted campaign keeps every finished run and ``resume``
continues it, skipping the runs already in the file (failed runs are retried).
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from archself.campaign.sweep import CampaignError, Sweep, apply_values, sweep_points
from archself.campaign.worker import Job, run_job, trace_name
from archself.errors import ArchselfError

__all__ = ["CampaignInterrupted", "CampaignOutcome", "plan_campaign", "run_campaign", "run_seeds"]

MODES = ("fixed", "adaptive")


class CampaignInterrupted(ArchselfError):
    """Ctrl-C: the finished runs are saved; exit code 130."""

    exit_code = 130


@dataclass
class CampaignOutcome:
    """What :func:`run_campaign` did."""

    out: Path
    planned: int
    skipped: int
    ran: int
    failed: int
    rows: int
    workers: int
    executor: str
    elapsed_s: float
    errors: list[str] = field(default_factory=list)


def run_seeds(root_seed: int, n: int) -> list[int]:
    """Seeds of replicates ``0 … n−1``: child ``k`` of ``SeedSequence(root_seed)``.

    Child ``k`` does not depend on ``n``, so adding seeds later keeps the old ones.

    Examples
    --------
    >>> run_seeds(0, 3)[:2] == run_seeds(0, 2)
    True
    """
    import numpy as np

    children = np.random.SeedSequence(int(root_seed)).spawn(int(n))
    return [int(c.generate_state(1, dtype=np.uint32)[0]) for c in children]


def _fmt(v: float) -> str:
    return f"{v:.12g}"


def run_id(
    scenario: str, sweeps: Sequence[Sweep], point: Sequence[float], replicate: int, mode: str
) -> str:
    """The stable key of a run, e.g. ``imu_drift|runtime.threshold=0.5|3|adaptive``."""
    parts = [scenario] + [f"{s.path}={_fmt(v)}" for s, v in zip(sweeps, point, strict=True)]
    return "|".join(parts + [str(replicate), mode])


def plan_campaign(
    arch_path: str | Path,
    scenarios: Sequence[str],
    seeds: int,
    sweeps: Sequence[Sweep] = (),
    *,
    modes: Sequence[str] = MODES,
    root_seed: int = 0,
    traces: str | Path | None = None,
) -> tuple[list[Job], dict[str, Any]]:
    """Validate a campaign and list its jobs (and the metadata of its results file).

    The file is loaded and checked once here, and every sweep point is applied
    and validated, so user errors are one-line errors before any run starts.

    Raises
    ------
    CampaignError, LoadError
        Unknown scenario, bad PATH or value, a file with errors.
    """
    from archself.check import check, has_errors
    from archself.loader import Loaded, SourceMap, load_text, read_text

    file = str(arch_path)
    if seeds < 1:
        raise CampaignError("--seeds must be at least 1")
    if not scenarios:
        raise CampaignError("give at least one --scenario")
    if len(set(scenarios)) != len(scenarios):
        raise CampaignError("the same --scenario is given twice")
    bad_modes = [m for m in modes if m not in MODES]
    if bad_modes or not modes:
        raise CampaignError(
            f"unknown mode {bad_modes[0] if bad_modes else ''!r}; known: " + ", ".join(MODES)
        )
    text = read_text(arch_path)
    loaded = load_text(text, file)
    _no_errors(check(loaded), has_errors, "")
    arch = loaded.arch
    missing = [s for s in scenarios if s not in arch.scenarios]
    if missing:
        known = ", ".join(arch.scenarios) or "none"
        raise CampaignError(f"{file}: unknown scenario {missing[0]!r}; known: {known}")
    points = sweep_points(sweeps)
    for point in points if sweeps else []:
        swept = apply_values(loaded.data, sweeps, point, file)
        setting = ", ".join(f"{s.path}={_fmt(v)}" for s, v in zip(sweeps, point, strict=True))
        _no_errors(check(Loaded(swept, SourceMap(file), loaded.data)), has_errors, f"{setting}: ")
    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()
    seed_list = run_seeds(root_seed, seeds)
    tdir = Path(traces) if traces is not None else None
    jobs = []
    for sc in scenarios:
        for point in points:
            for rep, seed in enumerate(seed_list):
                for mode in modes:
                    trace = None
                    if tdir is not None:
                        trace = str(tdir / trace_name(sc, tuple(point), rep, mode))
                    jobs.append(
                        Job(
                            run_id=run_id(sc, sweeps, point, rep, mode),
                            arch_text=text,
                            arch_digest=digest,
                            file=file,
                            sweeps=tuple(sweeps),
                            point=tuple(float(v) for v in point),
                            scenario=sc,
                            replicate=rep,
                            seed=seed,
                            mode=mode,
                            trace=trace,
                        )
                    )
    meta = {
        "format": 1,
        "architecture": arch.name,
        "file": Path(file).name,
        "sha256": digest,
        "root_seed": int(root_seed),
        "sweeps": [s.path for s in sweeps],
        "fault_free": sorted(name for name, s in arch.scenarios.items() if not s.faults),
        "thresholds": _threshold_paths(sweeps),
    }
    return jobs, meta


def _threshold_paths(sweeps: Sequence[Sweep]) -> list[str]:
    return [
        s.path
        for s in sweeps
        if s.keys in (("runtime", "threshold"), ("runtime", "hysteresis", "on"))
    ]


def _no_errors(findings: list[Any], has_errors: Callable[[list[Any]], bool], prefix: str) -> None:
    if has_errors(findings):
        first = next(f for f in findings if f.severity == "error")
        raise CampaignError(f"{prefix}{first}")


def _existing(out: Path, meta: dict[str, Any]) -> list[dict[str, Any]]:
    from archself.campaign.results import read_results

    table, old = read_results(out)
    for key, what in (
        ("sha256", "architecture file"),
        ("root_seed", "--root-seed"),
        ("sweeps", "sweep PATHs"),
    ):
        if old.get(key) != meta.get(key):
            raise CampaignError(
                f"{out}: was made with a different {what}; cannot resume it "
                "(write to another --out, or --force to start over)"
            )
    return [r for r in table.to_pylist() if r.get("error") is None]


def run_campaign(
    jobs: Sequence[Job],
    meta: dict[str, Any],
    out: str | Path,
    *,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
    resume: bool = False,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
    flush_s: float = 2.0,
) -> CampaignOutcome:
    """Run the jobs on an executor and write the results table to ``out``.

    Parameters
    ----------
    jobs, meta
        From :func:`plan_campaign`.
    out : path
        The Parquet file (rewritten atomically every ``flush_s`` seconds).
    executor : {"local", "dask"}
    workers : int, optional
        Local processes or LocalCluster workers (default: all cores).
    address : str, optional
        Dask scheduler address (``--executor dask`` only).
    resume : bool
        Keep the rows of an existing ``out`` and run only the missing runs.
    force : bool
        Overwrite an existing ``out``.
    progress : callable, optional
        ``progress(done, total)`` after every finished run.

    Raises
    ------
    CampaignInterrupted
        On Ctrl-C, after saving the finished runs.
    CampaignError
        ``out`` exists (without resume or force), or belongs to another campaign.
    """
    from archself.campaign.executors import make_executor
    from archself.campaign.results import write_results

    out = Path(out)
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise CampaignError(f"{out}: cannot write: folder {folder} does not exist")
    rows: list[dict[str, Any]] = []
    if out.exists() and resume:
        rows = _existing(out, meta)
    elif out.exists() and not force:
        raise CampaignError(f"{out}: exists; --resume to continue it, --force to start over")
    done_ids = {r["run_id"] for r in rows}
    # replicate-major submission: an interrupted campaign has seeds of every cell
    todo = sorted((j for j in jobs if j.run_id not in done_ids), key=lambda j: j.replicate)
    for j in todo:
        if j.trace is not None:
            Path(j.trace).parent.mkdir(parents=True, exist_ok=True)
    sweep_paths = list(meta.get("sweeps", []))
    t0 = time.perf_counter()
    ran = failed = 0
    errors: list[str] = []

    def flush() -> None:
        write_results(out, rows, sweep_paths, meta)

    if not todo:
        flush()
        return CampaignOutcome(out, len(jobs), len(jobs), 0, 0, len(rows), 0, executor, 0.0)
    ex = make_executor(
        executor, workers=workers, address=address, preload=["archself.campaign.worker"]
    )
    futures: list[Any] = []
    try:
        futures = [ex.submit(run_job, j) for j in todo]
        last = time.perf_counter()
        if progress is not None:
            progress(0, len(todo))
        for fut in ex.as_completed(futures):
            row = fut.result()
            rows.append(row)
            ran += 1
            if row.get("error"):
                failed += 1
                if len(errors) < 5:
                    errors.append(f"{row['run_id']}: {row['error']}")
            if progress is not None:
                progress(ran, len(todo))
            now = time.perf_counter()
            if now - last >= flush_s:
                flush()
                last = now
        flush()
    except KeyboardInterrupt:
        ex.cancel(futures)
        flush()
        try:
            ex.close()
        except KeyboardInterrupt:
            pass
        raise CampaignInterrupted(
            f"interrupted: {len(rows)} run{'s' * (len(rows) != 1)} saved in {out}; "
            "run the same command with --resume to continue"
        ) from None
    except BaseException:
        ex.cancel(futures)
        flush()
        ex.close()
        raise
    ex.close()
    elapsed = time.perf_counter() - t0
    return CampaignOutcome(
        out,
        len(jobs),
        len(jobs) - len(todo),
        ran,
        failed,
        len(rows),
        ex.workers,
        ex.name,
        elapsed,
        errors,
    )


def throughput(outcome: CampaignOutcome) -> float:
    """Runs per second of a campaign (NaN when nothing ran)."""
    if outcome.ran == 0 or outcome.elapsed_s <= 0:
        return math.nan
    return outcome.ran / outcome.elapsed_s
