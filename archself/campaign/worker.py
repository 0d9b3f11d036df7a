"""What a campaign worker does: one simulation run → one results row.

A :class:`Job` carries everything a worker needs: the architecture's text and
its digest, the sweep point, the scenario, the seed, the mode and where to
write the trace. A worker process parses each architecture text once and keeps
the validated model of each sweep point in a small cache, so a campaign of
thousands of runs loads the file once per process, not once per run.

This module never imports matplotlib, jinja2 or pyarrow (a worker needs none of
them); python-control, which the LQR modules import, is another matter (see
docs/campaigns.md).
"""

from __future__ import annotations

import math
import re
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from archself.campaign.sweep import Sweep, apply_values

__all__ = ["Job", "RunJob", "run_error", "run_job", "run_unit", "summarize_run"]

#: How many validated sweep points a worker keeps (:meth:`RunJob.architecture`).
CACHE_SIZE = 64

_TEXTS: dict[str, Any] = {}  # arch digest -> Loaded (parsed once per process)
_ARCHS: OrderedDict[tuple[str, tuple[float, ...]], Any] = OrderedDict()


@dataclass(frozen=True)
class RunJob:
    """One run of campaign, calibrate or identify: the file, the sweep point, the seed.

    Attributes
    ----------
    arch_text, arch_digest, file : str
        The architecture file's text, its SHA-256 and its name (for messages).
    scenario : str
    replicate : int
        Index of the seed (0 … N−1).
    seed : int
        The seed passed to :func:`archself.sim.run.simulate`.
    sweeps : tuple of Sweep
    point : tuple of float
        The sweep values of this run, in the order of ``sweeps``.
    """

    arch_text: str
    arch_digest: str
    file: str
    scenario: str
    replicate: int
    seed: int
    sweeps: tuple[Sweep, ...] = ()
    point: tuple[float, ...] = ()

    def architecture(self) -> Any:
        """The validated model of the file at the job's sweep point, shared by the runs of
        this process (a worker parses each text once and keeps :data:`CACHE_SIZE` points):
        copy it before a run changes it."""
        key = (self.arch_digest, tuple(self.point))
        arch = _ARCHS.get(key)
        if arch is not None:
            _ARCHS.move_to_end(key)
            return arch
        loaded = _TEXTS.get(self.arch_digest)
        if loaded is None:
            from archself.model.loader import load_text

            loaded = load_text(self.arch_text, self.file)
            _TEXTS.clear()  # one campaign at a time
            _TEXTS[self.arch_digest] = loaded
        if self.sweeps:
            arch = apply_values(loaded.data, self.sweeps, self.point, self.file)
        else:
            arch = loaded.arch
        _ARCHS[key] = arch
        while len(_ARCHS) > CACHE_SIZE:
            _ARCHS.popitem(last=False)
        return arch


@dataclass(frozen=True, kw_only=True)
class Job(RunJob):
    """One run of a campaign (:class:`RunJob` and the following).

    Attributes
    ----------
    run_id : str
        Stable key of the run (scenario, sweep values, replicate, mode).
    mode : str
        ``"fixed"`` or ``"adaptive"``.
    trace : str or None
        Where to write the run's trace (Parquet or JSON by the suffix), if anywhere.
    """

    run_id: str
    mode: str
    trace: str | None = None


def run_job(job: Job) -> dict[str, Any]:
    """Run one job and return its results row (never raises for a failed run).

    A run that raises is a row with the ``error`` column set and NaN metrics.
    """
    row = _base_row(job)
    try:
        arch = job.architecture()
        from archself.sim.run import simulate

        adapt = None
        if job.mode == "adaptive":
            from archself.runtime import MapeK

            adapt = MapeK(arch)
        # the cached model is shared by the runs of this process: give each run its own copy
        # a row keeps J's metrics and the switches: the series only for a trace
        result = simulate(arch.model_copy(deep=True), job.scenario, seed=job.seed, adapt=adapt,
                          keep=None if job.trace is not None else ())
        updates = None
        if adapt is not None:
            updates = [(u["action"], u["t_s"]) for u in adapt.updates]
        _fill(row, job, arch, result, updates)
    except Exception as exc:  # noqa: BLE001 - a failed run is a row, not a failed campaign
        row["error"] = run_error(exc)
    return row


def _fill(row: dict[str, Any], job: Job, arch: Any, result: Any,
          updates: list[tuple[str, float]] | None) -> None:
    """Complete a run's row: its summary, its parameter updates (adaptive), its trace."""
    row.update(summarize_run(result, arch))
    if updates is not None:
        row["n_updates"] = len(updates)
        row["updates"] = ";".join(f"{a}@{t:g}" for a, t in updates)
    if job.trace is not None:
        result.write_trace(job.trace)
        row["trace"] = job.trace


def run_unit(job_fn: Any, jobs: tuple[Job, ...]) -> list[dict[str, Any]]:
    """The rows of a unit of work: one job, or runs batched as lanes.

    A unit of several jobs (runs of one file, scenario and mode, from
    :func:`archself.campaign.driver.lane_units`) runs as one lane-batched simulation
    (:func:`archself.lanes.simulate_lanes`), with the rows and traces of the per-run
    path; if the lanes cannot run together (another structure or duration at a
    sweep point) or any run fails, every job runs on its own. ``job_fn`` other than
    :func:`run_job` (tests) runs job by job.
    """
    if len(jobs) == 1 or job_fn is not run_job:
        return [job_fn(j) for j in jobs]
    try:
        from archself.lanes import simulate_lanes

        archs = [j.architecture() for j in jobs]
        adaptive = jobs[0].mode == "adaptive"
        results = simulate_lanes(
            [a.model_copy(deep=True) for a in archs], jobs[0].scenario, [j.seed for j in jobs],
            adapt=adaptive,
        )
        rows = []
        for job, arch, result in zip(jobs, archs, results, strict=True):
            updates = None
            if adaptive:
                updates = [(d.chosen["action"], d.t) for d in result.decisions
                           if d.chosen and d.chosen.get("kind") == "parameter_update"]
            row = _base_row(job)
            _fill(row, job, arch, result, updates)
            rows.append(row)
        return rows
    except Exception:  # noqa: BLE001 - the per-run path says what failed, run by run
        return [run_job(j) for j in jobs]


def run_error(exc: BaseException) -> str:
    """A failed run's error as one line: ``Type: first line of the message`` (≤ 500 chars).

    >>> run_error(ValueError("bad value" + chr(10) + "more"))
    'ValueError: bad value'
    """
    msg = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {msg}"[:500]


def _base_row(job: Job) -> dict[str, Any]:
    nan = math.nan
    return {
        "run_id": job.run_id,
        "scenario": job.scenario,
        **{s.path: float(v) for s, v in zip(job.sweeps, job.point, strict=True)},
        "replicate": job.replicate,
        "seed": job.seed,
        "mode": job.mode,
        "start_configuration": None,
        "final_configuration": None,
        "configuration_path": None,
        "switch_times_s": [],
        "n_switches": 0,
        "first_fault_onset_s": None,
        "detection_delay_s": None,
        "false_switches": 0,
        "n_updates": 0,
        "updates": "",
        "module_faults": None,
        "max_error": nan,
        "final_error": nan,
        "rms_error": nan,
        "peak_time_s": nan,
        "unit": None,
        "trace": None,
        "error": None,
    }


def summarize_run(result: Any, arch: Any) -> dict[str, Any]:
    """The per-run columns derived from a :class:`~archself.sim.run.RunResult`.

    - ``configuration_path``: start and every switch target joined by ``>``.
    - ``first_fault_onset_s``: the earliest ``onset_s`` of the scenario's faults.
    - ``detection_delay_s``: first switch at or after that onset minus the onset
      (None without faults or without such a switch).
    - ``false_switches``: every switch in a scenario without faults, or before the
      first onset in one with faults.
    - ``module_faults``: the run's :attr:`~archself.sim.result.RunResult.faults` as
      ``module: reason``, ``;``-separated (``""``: none).
    - ``max_error``, ``final_error``, ``rms_error``, ``peak_time_s``: the run's metrics;
      ``unit``: theirs (``runtime.objective.unit``).
    """
    sc = arch.scenarios[result.scenario]
    onset = min((float(f.onset_s) for f in sc.faults), default=None)
    times = [float(s["t_s"]) for s in result.switches]
    path = [result.configuration] + [str(s["to"]) for s in result.switches]
    if onset is None:
        false = len(times)
        delay = None
    else:
        false = sum(1 for t in times if t < onset)
        after = [t for t in times if t >= onset]
        delay = (after[0] - onset) if after else None
    m = result.metrics
    return {
        "start_configuration": result.configuration,
        "final_configuration": result.final_configuration,
        "configuration_path": ">".join(path),
        "switch_times_s": times,
        "n_switches": len(times),
        "first_fault_onset_s": onset,
        "detection_delay_s": delay,
        "false_switches": false,
        "module_faults": ";".join(f"{f['module']}: {f['reason']}" for f in result.faults),
        "max_error": float(m["max_error"]),
        "final_error": float(m["final_error"]),
        "rms_error": float(m["rms_error"]),
        "peak_time_s": float(m["peak_time_s"]),
        "unit": arch.runtime.objective.unit,
    }


_UNSAFE = re.compile(r"[^A-Za-z0-9_.=-]+")


def trace_name(scenario: str, point: tuple[float, ...], replicate: int, mode: str,
               suffix: str = ".json") -> str:
    """A file name for a run's trace: readable, unique per run, safe on every OS.

    ``suffix`` chooses the format (``.parquet``: :mod:`archself.io.trace`).

    Examples
    --------
    >>> trace_name("imu_drift", (0.5,), 3, "adaptive")
    'imu_drift_0.5_r0003_adaptive.json'
    >>> trace_name("imu drift", (), 0, "fixed", ".parquet")
    'imu_drift-cd60cc_r0000_fixed.parquet'
    """
    safe = _UNSAFE.sub("_", scenario).strip("._") or "scenario"
    if safe != scenario:  # keep names apart that differ only in replaced characters
        import hashlib

        safe += "-" + hashlib.sha256(scenario.encode("utf-8")).hexdigest()[:6]
    parts = [safe]
    parts += [f"{v:.6g}" for v in point]
    parts += [f"r{replicate:04d}", mode]
    return "_".join(parts) + suffix
