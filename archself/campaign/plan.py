"""Planning a campaign: the file and every sweep point validated, its size, its jobs.

:func:`plan_campaign` checks the architecture once and each sweep point's copy,
refuses a campaign past the caps (:func:`estimate_campaign`: :data:`MAX_RUNS`,
:data:`MAX_STEPS` unless ``--yes``; half the memory always) and lists the jobs:
scenarios × sweep points × replicates × modes, replicate ``k`` seeded by child ``k``
of ``SeedSequence(root_seed)`` (:func:`run_seeds`), each with a stable
:func:`run_id`; :func:`lane_units` groups fixed runs into lane batches.
:mod:`archself.campaign.driver` runs them.
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from archself.campaign.sweep import CampaignError, Sweep, apply_values, sweep_points
from archself.campaign.worker import Job, trace_name
from archself.check import check
from archself.errors import unknown
from archself.model.loader import Loaded, load_text, read_text

__all__ = [
    "BYTES_PER_RUN",
    "CampaignEstimate",
    "LANE_BYTES_PER_STEP",
    "MAX_LANES",
    "MAX_RUNS",
    "MAX_STEPS",
    "MIN_LANES",
    "MODES",
    "available_memory",
    "default_lanes",
    "estimate_campaign",
    "lane_units",
    "plan_campaign",
    "run_id",
    "run_seeds",
    "run_steps",
]

MODES = ("fixed", "adaptive")


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
    yes: bool = False,
    trace_format: str = "json",
) -> tuple[list[Job], dict[str, Any]]:
    """Validate a campaign and list its jobs (and the metadata of its results file).

    The file is loaded and checked once here, and every sweep point is applied
    and validated, so user errors are one-line errors before any run starts.
    The size (:func:`estimate_campaign`) is checked against :data:`MAX_RUNS` and
    :data:`MAX_STEPS` (lifted by ``yes``) and against the memory (never lifted)
    before anything is built. With ``traces`` each run's trace goes into that folder,
    as ``trace_format`` (``json`` or ``parquet``).

    Raises
    ------
    CampaignError, LoadError
        Unknown scenario, bad PATH or value, a file with errors.
    """

    _check_options(scenarios, seeds, modes, root_seed, trace_format)
    file = str(arch_path)
    text = read_text(arch_path)
    loaded = load_text(text, file)
    _no_errors(check(loaded), "")
    arch = loaded.arch
    missing = [s for s in scenarios if s not in arch.scenarios]
    if missing:
        raise CampaignError(f"{file}: {unknown('scenario', missing[0], arch.scenarios)}")
    est = estimate_campaign(arch, scenarios, sweeps, seeds, modes)
    est.check(yes)
    for point in sweep_points(sweeps) if sweeps else []:
        swept = apply_values(loaded.data, sweeps, point, file, loaded.source)
        setting = ", ".join(f"{s.path}={_fmt(v)}" for s, v in zip(sweeps, point, strict=True))
        _no_errors(check(Loaded(swept, loaded.source, loaded.data)), f"{setting}: ")
    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()
    jobs = _jobs(text, digest, file, scenarios, seeds, sweeps, modes, root_seed, traces,
                 trace_format)
    return jobs, _meta(arch, file, digest, root_seed, sweeps, est)


def _check_options(
    scenarios: Sequence[str], seeds: int, modes: Sequence[str], root_seed: int, trace_format: str
) -> None:
    """Refuse options no campaign can take, before the file is read."""
    if trace_format not in ("json", "parquet"):
        raise CampaignError(f"unknown trace format {trace_format!r}; known: json, parquet")
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
    if root_seed < 0:
        raise CampaignError(f"--root-seed must be at least 0, not {root_seed}")


def _jobs(
    text: str, digest: str, file: str, scenarios: Sequence[str], seeds: int,
    sweeps: Sequence[Sweep], modes: Sequence[str], root_seed: int,
    traces: str | Path | None, trace_format: str,
) -> list[Job]:
    """Every run: scenarios × sweep points × replicates × modes, in that order."""
    seed_list = run_seeds(root_seed, seeds)
    tdir = Path(traces) if traces is not None else None
    suffix = f".{trace_format}"
    jobs = []
    for sc in scenarios:
        for point in sweep_points(sweeps):
            for rep, seed in enumerate(seed_list):
                for mode in modes:
                    trace = None
                    if tdir is not None:
                        trace = str(tdir / trace_name(sc, tuple(point), rep, mode, suffix))
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
    return jobs


def _meta(
    arch: Any, file: str, digest: str, root_seed: int, sweeps: Sequence[Sweep],
    est: CampaignEstimate,
) -> dict[str, Any]:
    """The campaign's metadata in its results file (docs/json.md)."""
    from archself.lanes.batching import batched_types

    return {
        "format": 1,
        "architecture": arch.name,
        "file": Path(file).name,
        "sha256": digest,
        "root_seed": int(root_seed),
        "sweeps": [s.path for s in sweeps],
        "fault_free": sorted(name for name, s in arch.scenarios.items() if not s.faults),
        "thresholds": _threshold_paths(sweeps),
        "steps": est.steps,
        # every module type batched: runs go in lanes by default (archself.lanes)
        "lane_types": batched_types(arch),
    }


#: Caps of a campaign without ``--yes`` (runs, simulated steps) and in any case (memory).
MAX_RUNS = 100_000
MAX_STEPS = 1_000_000_000
#: Bytes the driver holds per run (the job, its row, the futures) — measured ≈ 1.2 KB.
BYTES_PER_RUN = 2048


@dataclass(frozen=True)
class CampaignEstimate:
    """The size of a campaign, known before any run starts."""

    runs: int
    steps: int
    memory_bytes: int

    def text(self) -> str:
        """``1,200 runs × 8,000 steps ≈ 9.6e+06 steps, ~2 MB``."""
        per = self.steps // max(self.runs, 1)
        return (
            f"{self.runs:,} runs × {per:,} steps = {self.steps:.3g} steps, "
            f"~{self.memory_bytes / 1024**2:,.0f} MB"
        )

    def check(self, yes: bool) -> None:
        """Refuse past the caps: runs and steps unless ``yes``; memory always."""
        if too_much := past_half_memory(self.memory_bytes):
            raise CampaignError(f"the campaign is {self.text()}: {too_much}; use fewer "
                                "--seeds or sweep values, or split it")
        if yes:
            return
        if self.runs > MAX_RUNS or self.steps > MAX_STEPS:
            raise CampaignError(
                f"the campaign is {self.text()}: more than the cap ({MAX_RUNS:,} runs, "
                f"{MAX_STEPS:.0e} steps); pass --yes to run it anyway"
            )


def estimate_campaign(
    arch: Any, scenarios: Sequence[str], sweeps: Sequence[Sweep], seeds: int, modes: Sequence[str]
) -> CampaignEstimate:
    """Runs, simulated steps and driver memory of a campaign, without building it."""
    n_points = math.prod(len(s.values) for s in sweeps)
    per_cell = n_points * int(seeds) * len(modes)
    dt = float(arch.runtime.step_s)
    durations = {name: float(arch.scenarios[name].duration_s) for name in scenarios}
    for s in sweeps:  # a swept step or duration: the estimate takes its most expensive value
        name = str(s.keys[1]) if len(s.keys) == 3 else ""
        if s.keys == ("runtime", "step_s") and min(s.values) > 0:
            dt = min(dt, min(s.values))
        elif s.keys == ("scenarios", name, "duration_s") and name in durations:
            durations[name] = max(durations[name], max(s.values))
    steps = sum(per_cell * round(d / dt) for d in durations.values())
    runs = per_cell * len(scenarios)
    return CampaignEstimate(runs, steps, runs * BYTES_PER_RUN)


def _threshold_paths(sweeps: Sequence[Sweep]) -> list[str]:
    return [
        s.path
        for s in sweeps
        if s.keys in (("runtime", "threshold"), ("runtime", "hysteresis", "on"))
    ]


def _no_errors(findings: list[Any], prefix: str) -> None:
    first = next((f for f in findings if f.severity == "error"), None)
    if first is not None:
        raise CampaignError(f"{prefix}{first}")


#: Most lanes in one unit of work (a batch of runs stepped together).
MAX_LANES = 256
#: Bytes a lane holds per simulated step (its recorded series and their per-run copies;
#: the diff-drive robot: ~650 B, bench/floor_diffdrive.py).
LANE_BYTES_PER_STEP = 1024


def _memory_bytes(pages: str) -> int | None:
    """``os.sysconf(pages)`` pages in bytes (None where the system does not say)."""
    try:
        return int(os.sysconf(pages)) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return None


def past_half_memory(need: float) -> str | None:
    """``"more than half of this machine's memory (N GB)"`` when ``need`` bytes are, else
    None (also where the system does not say): campaign, calibrate and identify refuse
    such work before any run starts."""
    avail = _memory_bytes("SC_PHYS_PAGES")
    if avail and need > avail // 2:
        return f"more than half of this machine's memory ({avail / 1024**3:.1f} GB)"
    return None


def available_memory() -> int | None:
    """Bytes of physical memory free now (None where the system does not say)."""
    return _memory_bytes("SC_AVPHYS_PAGES")


def default_lanes(
    jobs: Sequence[Job], workers: int, steps_per_run: int = 0, memory: int | None = None
) -> int:
    """Lanes per unit: the runs shared evenly over the workers, within memory and :data:`MAX_LANES`.

    Every worker gets work (2 workers and 10 runs: units of 5), and the units of all
    workers together hold at most half of ``memory`` (``steps_per_run`` ×
    :data:`LANE_BYTES_PER_STEP` per lane).

    Examples
    --------
    >>> default_lanes(range(1000), 2)
    256
    >>> default_lanes(range(1000), 2, steps_per_run=8000, memory=2 * 2**30)
    65
    """
    width = min(MAX_LANES, math.ceil(len(jobs) / max(1, workers)))
    if steps_per_run > 0 and memory:
        width = min(width, memory // (2 * max(1, workers) * steps_per_run * LANE_BYTES_PER_STEP))
    return max(1, width)


def run_steps(job: Job) -> int:
    """The simulated steps of a job's run: its scenario's duration over the step, at its
    sweep point (the estimated cost :func:`lane_units` balances)."""
    arch = job.architecture()
    return max(1, round(float(arch.scenarios[job.scenario].duration_s)
                        / float(arch.runtime.step_s)))


#: Fewest runs in a unit the balancing makes (a lane's step costs more in small units).
MIN_LANES = 8


def lane_units(
    jobs: Sequence[Job], width: int, workers: int = 0,
    cost: Callable[[Job], float] | None = None,
) -> list[tuple[Job, ...]]:
    """Units of work: runs of one file, scenario and mode in batches of at most ``width``.

    Without ``workers`` the order of the jobs is kept: a unit stands where its first job
    stood. With ``workers`` the units are balanced for that many workers, each taking the
    next unit when it is free (guided self-scheduling): a unit holds about
    1/(2·``workers``) of the estimated cost not yet handed out (``cost(job)``, default
    :func:`run_steps`), at least :data:`MIN_LANES` runs, from the (file, scenario,
    mode) with the most cost left. So the units come largest first, interleaved across
    scenarios, and the last ones are small: the workers finish within about one small
    unit of each other, whatever the real costs of the scenarios.

    Examples
    --------
    >>> from archself.campaign.worker import Job
    >>> def job(i, mode, sc="s"):
    ...     return Job(arch_text="", arch_digest="d", file="f", scenario=sc, replicate=i, seed=i,
    ...                run_id=str(i), mode=mode)
    >>> jobs = [job(0, "fixed"), job(1, "adaptive"), job(2, "fixed"), job(3, "fixed", "t"),
    ...         job(4, "fixed"), job(5, "adaptive")]
    >>> [[j.run_id for j in u] for u in lane_units(jobs, 2)]
    [['0', '2'], ['1', '5'], ['3'], ['4']]
    >>> many = [job(i, "adaptive", "st"[i % 2]) for i in range(200)]
    >>> [(len(u), u[0].scenario) for u in lane_units(many, 256, 2, cost=lambda j: 1.0)]
    ... # doctest: +NORMALIZE_WHITESPACE
    [(50, 's'), (38, 't'), (28, 't'), (21, 's'), (16, 't'), (12, 's'), (9, 't'), (9, 's'),
     (9, 't'), (8, 's')]
    """
    if width <= 1:
        return [(j,) for j in jobs]
    groups: dict[tuple[str, str, str], list[Job]] = {}
    for j in jobs:
        groups.setdefault((j.arch_digest, j.scenario, j.mode), []).append(j)
    if workers <= 0:
        order = {id(j): k for k, j in enumerate(jobs)}
        units = [g[k:k + width] for g in groups.values() for k in range(0, len(g), width)]
        return [tuple(u) for u in sorted(units, key=lambda u: order[id(u[0])])]
    return _guided_units(groups, width, workers, cost or _cached_steps())


def _cached_steps() -> Callable[[Job], float]:
    """:func:`run_steps`, computed once per (file, sweep point, scenario)."""
    known: dict[tuple[Any, ...], float] = {}

    def steps(job: Job) -> float:
        key = (job.arch_digest, tuple(job.point), job.scenario)
        if key not in known:
            known[key] = float(run_steps(job))
        return known[key]

    return steps


def _guided_units(
    groups: dict[tuple[str, str, str], list[Job]], width: int, workers: int,
    cost: Callable[[Job], float],
) -> list[tuple[Job, ...]]:
    """:func:`lane_units` for ``workers``: the next unit from the group with most cost
    left, about 1/(2·workers) of all the cost left (``MIN_LANES`` … ``width`` runs)."""
    costs = {k: [cost(j) for j in g] for k, g in groups.items()}
    left = {k: math.fsum(c) for k, c in costs.items()}
    done = dict.fromkeys(groups, 0)
    units: list[tuple[tuple[Job, ...], float]] = []
    while any(done[k] < len(g) for k, g in groups.items()):
        key = max((k for k in groups if done[k] < len(groups[k])), key=lambda k: left[k])
        g, at = groups[key], done[key]
        per = max(left[key] / (len(g) - at), 1e-12)
        target = math.fsum(left.values()) / (2 * workers)
        n = min(width, len(g) - at, max(MIN_LANES, round(target / per)))
        if len(g) - at - n < MIN_LANES:  # no remnant smaller than a unit
            n = min(width, len(g) - at)
        units.append((tuple(g[at:at + n]), math.fsum(costs[key][at:at + n])))
        done[key] = at + n
        left[key] = math.fsum(costs[key][at + n:])
    return [u for u, _ in sorted(units, key=lambda uc: -uc[1])]  # largest first
