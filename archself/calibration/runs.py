"""The calibration runs: nominal scenarios, fixed in each configuration, residuals recorded.

One :class:`CalJob` is one run of one fault-free scenario, started (and kept,
no adaptation) in one configuration, with one seed. The worker steps the
system with :func:`archself.sim.run.simulate` and, every ``runtime.period_s``
exactly where the MAPE-K loop would run, samples it with the runtime's own
:class:`~archself.runtime.monitor.Monitor`. It keeps, for each cycle after the
warm-up, the magnitude of every module's *filtered* residual signal |s̄_i|
(before the division by ``residual.nominal``; 0 where the sample was unusable,
which is what gives r_i = 0 at run time) and whether an active module was
unavailable for a reason of its own (a saturated residual, a candidate whatever
the bands). Raw residuals do not depend on the bands, so the bands can be chosen
afterwards, offline (:mod:`archself.calibration.bands`).

Jobs run on the campaign executors (:mod:`archself.campaign.executors`): a local
process pool or Dask, like ``archself campaign``, in lane batches of one scenario
and configuration (:func:`run_calibration_unit`, :mod:`archself.lanes`). A worker
parses the architecture text once per process (:meth:`RunJob.architecture
<archself.campaign.worker.RunJob.architecture>`).

``--save-runs``/``--from-runs``: :func:`save_runs` writes the recorded residuals of
every run with the metadata that ties them to the file (an ``.npz``, no pickles);
:func:`load_runs` reads them back; :func:`band_free_digest` is the file's identity
without its bands, which ``--from-runs`` checks.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from archself.campaign.driver import run_seeds
from archself.campaign.executors import default_workers, make_executor
from archself.campaign.sweep import sweep_points
from archself.campaign.worker import RunJob, run_error
from archself.errors import LoadError
from archself.io.files import write_bytes
from archself.io.jsondata import JsonLimitError, SavedRunsMeta, document, loads, problem

__all__ = [
    "CalJob",
    "Recorder",
    "band_free_digest",
    "load_runs",
    "plan_runs",
    "record",
    "run_calibration_job",
    "run_jobs",
    "run_calibration_unit",
    "run_on_executor",
    "save_runs",
    "seeds_from",
]

@dataclass(frozen=True, kw_only=True)
class CalJob(RunJob):
    """One calibration run: (scenario, configuration, seed), architecture fixed
    (:class:`~archself.campaign.worker.RunJob` and the following)."""

    configuration: str
    phase: str = "calibration"


def seeds_from(root_seed: int, start: int, n: int) -> list[int]:
    """Seeds of replicates ``start … start+n−1``: children of ``SeedSequence(root_seed)``.

    The campaign's seeds (:func:`archself.campaign.driver.run_seeds`): child ``k``
    does not depend on how many are drawn, so a verification with replicates
    ``N … N+V−1`` uses seeds disjoint from the calibration's ``0 … N−1``.

    Examples
    --------
    >>> from archself.campaign.driver import run_seeds
    >>> seeds_from(0, 0, 3) == run_seeds(0, 3)
    True
    >>> seeds_from(0, 2, 1) == run_seeds(0, 3)[2:]
    True
    """

    return run_seeds(root_seed, start + n)[start:]


def plan_runs(
    text: str,
    file: str,
    scenarios: Sequence[str],
    configurations: Sequence[str],
    seeds: Sequence[int],
    first_replicate: int = 0,
    phase: str = "calibration",
    envelope: Sequence[Any] = (),
) -> list[CalJob]:
    """Every (envelope point, scenario, configuration, seed) job, replicate-major.

    ``envelope`` holds :class:`~archself.campaign.sweep.Sweep` objects: each point of
    their product is one operating condition of the file (a noise level, say). The
    points split ``seeds`` evenly, in order (point p takes the p-th share): a band is
    a tail quantile of the runs pooled over the points, so each run must be a fresh
    draw — with one set of seeds for every point, a statistic that does not depend on
    the noise level (the robot's drift test) gave the same maximum at all 8 points,
    800 runs holding the information of 100. Configurations and scenarios share the
    seeds (each is a cell of its own).
    """

    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()
    sweeps = tuple(envelope)
    points = sweep_points(sweeps)
    per, left = divmod(len(seeds), len(points))
    if left:
        raise ValueError(f"{len(seeds)} seeds do not split over {len(points)} envelope points")
    return [
        CalJob(
            arch_text=text, arch_digest=digest, file=file, scenario=sc, configuration=conf,
            replicate=first_replicate + k, seed=int(seeds[p * per + k]), phase=phase,
            sweeps=sweeps, point=point,
        )
        for k in range(per)
        for p, point in enumerate(points)
        for sc in scenarios
        for conf in configurations
    ]


class Recorder:
    """An ``adapt`` callable for :func:`~archself.sim.run.simulate` that only observes.

    Called every ``runtime.period_s`` like :class:`~archself.runtime.MapeK`, it
    runs the Monitor stage (the same filters, gains and sampling instants) and
    never acts.

    Parameters
    ----------
    arch : Architecture
    residual_modules : list of str, optional
        Column order of :attr:`x` (default: the modules with a ``residual`` block).

    Attributes
    ----------
    x : list of list of float
        Per cycle after the warm-up: |s̄_i| of each module of ``residual_modules``
        (0 when inactive, the sample was unusable or the filter not yet trusted:
        ``runtime.min_confidence``, or from the first sample with
        ``runtime.trust_at_start``, as the loop counts it).
    forced : list of bool
        Per cycle after the warm-up: an active module was unavailable for a
        reason of its own (the Monitor gives it the saturated residual).
    t : list of float
        Time of each recorded cycle.
    """

    def __init__(self, arch: Any, residual_modules: list[str] | None = None) -> None:
        from archself.runtime.monitor import Monitor

        if residual_modules is None:
            residual_modules = [m for m, s in arch.modules.items() if s.residual is not None]
        self.monitor = Monitor(arch, list(arch.modules))
        self.warmup_s = arch.runtime.warmup_time_s
        self.t_start: float | None = None
        self.trust = float(arch.runtime.min_confidence)
        # runtime.trust_at_start: a filter running since the first cycle counts at once
        mon = self.monitor
        self._slot = {mon.names[k]: j for j, k in enumerate(mon.res_pos.tolist())}
        self.column = {m: j for j, m in enumerate(residual_modules)}
        self.width = len(residual_modules)
        self.x: list[list[float]] = []
        self.forced: list[bool] = []
        self.t: list[float] = []

    def __call__(self, system: Any, observation: Any = None) -> list[dict[str, Any]]:
        from archself.runtime.monitor import is_own_failure

        obs = observation if observation is not None else self.monitor.observe(
            system, frozenset(system.active)
        )
        if self.t_start is None:
            self.t_start = obs.t
        if obs.t - self.t_start >= self.warmup_s - 1e-9:
            row = [0.0] * self.width
            for name, value, ok in zip(
                obs.signal_names, obs.signal_values.tolist(), obs.signal_ok.tolist(), strict=True
            ):
                if ok and value == value and (
                    obs.kappa[name].confidence >= self.trust
                    or self.monitor.from_start[self._slot[name]]
                ):
                    row[self.column[name]] = abs(value)
            self.x.append(row)
            self.forced.append(
                any(
                    not k.available and k.reason is not None and is_own_failure(k.reason)
                    for _, k in obs.kappa.findings()
                )
            )
            self.t.append(float(obs.t))
        return []

    def arrays(self) -> dict[str, Any]:
        """``x`` (cycles × modules, float64), ``forced`` (bool) and ``t`` as arrays."""
        import numpy as np

        return {
            "x": np.array(self.x, dtype=float).reshape(len(self.x), self.width),
            "forced": np.array(self.forced, dtype=bool),
            "t": np.array(self.t, dtype=float),
        }


def _row(job: CalJob) -> dict[str, Any]:
    return {
        "scenario": job.scenario,
        "configuration": job.configuration,
        "replicate": job.replicate,
        "seed": job.seed,
        "error": None,
        "phase": job.phase,
    }


def run_calibration_job(job: CalJob) -> dict[str, Any]:
    """Run one job; a dict of small arrays (never raises for a failed run).

    Returns
    -------
    dict
        ``scenario``, ``configuration``, ``replicate``, ``seed``, ``x`` (cycles ×
        residual modules, float64), ``forced`` (bool per cycle), ``t`` and
        ``error`` (None, or why the run failed).
    """
    out = _row(job)
    try:
        out.update(record(job.architecture().model_copy(deep=True), job))
    except Exception as exc:  # noqa: BLE001 - a failed run is reported, not fatal
        out["error"] = run_error(exc)
    return out


def record(arch: Any, job: Any) -> dict[str, Any]:
    """:meth:`Recorder.arrays` of ``job``'s scenario run fixed in its configuration with its
    seed on ``arch`` (stepped: pass a copy); the runs of calibrate and identify."""
    from archself.sim.run import simulate

    rec = Recorder(arch)
    simulate(arch, job.scenario, configuration=job.configuration, seed=job.seed, adapt=rec)
    return rec.arrays()


def run_calibration_unit(jobs: tuple[CalJob, ...]) -> list[dict[str, Any]]:
    """Jobs of one file, scenario and configuration as lanes: :func:`run_calibration_job`'s
    results, with one lane-batched simulation (:func:`archself.lanes.simulate_lanes`)
    and a :class:`Recorder` per lane; if the lanes cannot run together, job by job."""
    if len(jobs) == 1:
        return [run_calibration_job(jobs[0])]
    try:
        from archself.lanes import simulate_lanes

        archs = [j.architecture() for j in jobs]
        recorders: list[Recorder] = []

        def recorder(arch: Any) -> Recorder:
            recorders.append(Recorder(arch))
            return recorders[-1]

        simulate_lanes(
            [a.model_copy(deep=True) for a in archs], jobs[0].scenario,
            [j.seed for j in jobs], configuration=jobs[0].configuration, adapt=recorder,
        )
    except Exception:  # noqa: BLE001 - the per-run path says what failed, run by run
        return [run_calibration_job(j) for j in jobs]
    return [{**_row(job), **rec.arrays()} for job, rec in zip(jobs, recorders, strict=True)]


def calibration_units(jobs: Sequence[CalJob], workers: int) -> list[tuple[CalJob, ...]]:
    """The jobs in lane batches of one file, scenario and configuration (sweep points and
    seeds mixed), shared evenly over ``workers``, at most 256 lanes each."""
    import math

    groups: dict[tuple[str, str, str], list[CalJob]] = {}
    for j in jobs:
        groups.setdefault((j.arch_digest, j.scenario, j.configuration), []).append(j)
    width = max(1, min(256, math.ceil(len(jobs) / max(1, workers))))
    return [tuple(g[k : k + width]) for g in groups.values() for k in range(0, len(g), width)]


def run_jobs(
    jobs: Sequence[CalJob],
    *,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[dict[str, Any]]:
    """Run the jobs on a campaign executor; results sorted by (scenario, configuration, replicate).

    ``executor`` is ``"local"``, ``"dask"`` or ``"inline"`` (in this process; tests).
    Ctrl-C cancels the queued runs and propagates.
    """
    from archself.lanes.batching import batched_types

    if jobs and batched_types(jobs[0].architecture()):
        units = calibration_units(jobs, workers or default_workers())
    else:  # some module type would run lane by lane: lanes would not pay
        units = [(j,) for j in jobs]
    results = run_on_executor(
        units, run_calibration_unit, "archself.calibration.runs",
        executor=executor, workers=workers, address=address, progress=progress,
    )
    results.sort(key=lambda r: (r["scenario"], r["configuration"], r["replicate"]))
    return results


def run_on_executor(
    jobs: Sequence[Any],
    fn: Callable[[Any], Any],
    preload: str,
    *,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[dict[str, Any]]:
    """``fn(job)`` for every job on a campaign executor, in completion order.

    A job may be a tuple of jobs (a unit of lanes) for which ``fn`` returns a list:
    its items are the results, and ``progress`` counts them. ``preload`` is the module
    the workers import first (where ``fn`` lives). Ctrl-C cancels the queued runs and
    propagates. Used by calibrate and identify.
    """

    if not jobs:
        return []
    ex = make_executor(executor, workers=workers, address=address, preload=[preload])
    results: list[dict[str, Any]] = []
    futures: list[Any] = []
    try:
        total = sum(len(j) if isinstance(j, tuple) else 1 for j in jobs)
        futures = [ex.submit(fn, j) for j in jobs]
        if progress is not None:
            progress(0, total)
        for fut in ex.as_completed(futures):
            got = fut.result()
            if isinstance(got, list):
                results.extend(got)
            else:
                results.append(got)
            if progress is not None:
                progress(len(results), total)
    except BaseException:
        ex.cancel(futures)
        raise
    finally:
        ex.close()
    return results


def band_free_digest(data: dict[str, Any]) -> str:
    """SHA-256 of the architecture's data without its bands (``modules.*.residual.nominal``).

    The nominal runs are fixed, so their residuals do not depend on the bands: runs
    saved from a file stay valid for the same file with other bands (e.g. its
    calibrated copy), and for nothing else.
    """
    import copy
    import json

    d = copy.deepcopy(data)
    for spec in (d.get("modules") or {}).values():
        if isinstance(spec, dict) and isinstance(spec.get("residual"), dict):
            spec["residual"].pop("nominal", None)
    text = json.dumps(d, sort_keys=True, default=str, ensure_ascii=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def save_runs(path: str | Path, meta: dict[str, Any], results: Sequence[dict[str, Any]]) -> None:
    """Write runs (``run_calibration_job`` results) and ``meta`` to an ``.npz`` file, atomically.

    Arrays ``x<k>``/``forced<k>``/``t<k>`` per run, ``meta`` as a JSON string, a
    :class:`~archself.io.jsondata.SavedRunsMeta` (no pickles: the file is safe to load).
    """
    import io
    import json

    import numpy as np

    arrays: dict[str, Any] = {}
    rows = []
    for k, r in enumerate(results):
        rows.append(
            {
                key: r[key]
                for key in ("scenario", "configuration", "replicate", "seed", "error", "phase")
            }
        )
        if r["error"] is None:
            arrays.update({f"{name}{k}": r[name] for name in ("x", "forced", "t")})
    doc = document(SavedRunsMeta, {**meta, "runs": rows})
    arrays["meta"] = np.array(json.dumps(doc, ensure_ascii=False))
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    write_bytes(path, buf.getvalue())


def load_runs(path: str | Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """``(meta, results)`` of a file written by :func:`save_runs`.

    Raises
    ------
    LoadError
        When the file is missing or not such a file.
    """
    import zipfile

    import numpy as np

    try:
        with np.load(path, allow_pickle=False) as z:
            meta = loads(str(z["meta"]))  # JsonLimitError: a ValueError
            why = problem(SavedRunsMeta, meta, "meta")
            if why:
                raise LoadError(f"not a runs file of archself calibrate ({why})", str(path))
            results = []
            for k, row in enumerate(meta.pop("runs")):
                r = dict(row)
                if r["error"] is None:
                    r["x"], r["forced"], r["t"] = z[f"x{k}"], z[f"forced{k}"], z[f"t{k}"]
                    x, forced, t = r["x"], r["forced"], r["t"]
                    if (x.ndim != 2 or x.dtype.kind not in "fiu" or forced.ndim != 1
                            or t.ndim != 1 or not len(x) == len(forced) == len(t)):
                        raise LoadError(f"not a runs file of archself calibrate (the arrays "
                                        f"of run {k} have the wrong shape or type)", str(path))
                results.append(r)
    except FileNotFoundError:
        raise LoadError("no such file", str(path)) from None
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
        why = str(exc) if isinstance(exc, JsonLimitError) else type(exc).__name__
        raise LoadError(f"not a runs file of archself calibrate ({why})", str(path)) from None
    return meta, results
