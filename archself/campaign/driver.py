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

A local worker that dies (killed, out of memory, a crash in C code) breaks the
pool and every run on it: the pool is started again and the unfinished runs
are submitted again. The runs that were on the workers (the first
``workers + 1`` unfinished ones: the pool is FIFO) are retried one at a time
first, so that a run that kills its worker is found: alone on the pool
:data:`MAX_ATTEMPTS` times, it becomes a failed row (``--resume`` retries
failed rows) and the campaign goes on. After :data:`MAX_POOL_RESTARTS`
restarts the campaign stops with a message naming ``--resume``; the finished
rows are saved.

The planning (validation, size, seeds, jobs) is in :mod:`archself.campaign.plan`;
:func:`plan_campaign`, :func:`run_seeds` and :class:`CampaignEstimate` are
re-exported here.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from archself.campaign.executors import make_executor
from archself.campaign.figures import plot_results
from archself.campaign.plan import (
    CampaignEstimate,
    available_memory,
    default_lanes,
    lane_units,
    plan_campaign,
    run_seeds,
)
from archself.campaign.results import outcome_html, read_results, summary_frame, write_results
from archself.campaign.sweep import CampaignError
from archself.campaign.worker import Job, _base_row, run_job, run_unit
from archself.errors import ArchselfError, OutputError, Terminated
from archself.io.files import file_ids, refuse_same_file

__all__ = [
    "RunProgress",
    "CampaignEstimate",
    "CampaignInterrupted",
    "CampaignOutcome",
    "plan_campaign",
    "run_campaign",
    "run_seeds",
]

#: A run that broke the pool this many times alone on it becomes a failed row.
MAX_ATTEMPTS = 2
#: A campaign restarts its local pool at most this many times, then stops (--resume).
MAX_POOL_RESTARTS = 10


class CampaignInterrupted(ArchselfError):
    """Ctrl-C (exit code 130) or SIGTERM (143): the finished runs are saved."""

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

    def table(self) -> Any:
        """Per scenario, sweep point and mode: runs, median errors, switches (pandas).

        :func:`archself.campaign.results.summary_frame` of :attr:`out`.
        """

        return summary_frame(self.out)

    def plot(self, metric: str = "max_error", **kwargs: Any) -> Any:
        """Fixed vs adaptive ``metric`` per scenario: a Figure (``size``, ``title``).

        :func:`archself.campaign.figures.plot_results` of :attr:`out`.
        """

        return plot_results(self.out, metric, **kwargs)

    def _repr_html_(self) -> str:
        return outcome_html(self)


def _existing(out: Path, meta: dict[str, Any]) -> list[dict[str, Any]]:
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


def _check_outputs(jobs: Sequence[Job], out: Path) -> None:
    """Refuse ``--out`` or a trace file that is an input; make and probe the traces folder."""
    import tempfile

    inputs = sorted({j.file for j in jobs})
    refuse_same_file(inputs, out, "--out")
    traces = [Path(j.trace) for j in jobs if j.trace is not None]
    names = {t.name for t in traces}
    input_ids = set().union(*(file_ids(i) for i in inputs))
    for d in sorted({t.parent for t in traces}):
        try:
            d.mkdir(parents=True, exist_ok=True)
            fd, probe = tempfile.mkstemp(prefix=".archself-probe.", dir=d)
            os.close(fd)
            os.unlink(probe)
        except OSError as exc:
            raise OutputError(
                f"{d}: error: --traces folder cannot be written: {exc.strerror or exc}"
            ) from None
        if input_ids & file_ids(d):
            continue
        for inp in inputs:
            cand = d / Path(inp).name
            if cand.name in names and file_ids(cand) & file_ids(inp):
                raise OutputError(
                    f"{cand}: error: a trace would overwrite the input file; "
                    "choose another --traces folder"
                )


def _worker_died(exc: BaseException) -> bool:
    """A worker process of the pool died (killed, out of memory, a crash in C code)."""
    from concurrent.futures.process import BrokenProcessPool

    return isinstance(exc, BrokenProcessPool) or type(exc).__name__ == "KilledWorker"


class RunProgress:
    """A progress bar of many runs (``rich.progress``): count, percent, rate, elapsed, ETA.

    ``update(done, total)`` is the ``progress`` callback of :func:`run_campaign` and of
    the calibration driver; a ``done`` lower than before (a new phase, e.g. the
    calibration's verification runs) starts a new bar; ``close()`` ends it. The rate is
    the runs done over the time since the bar started, the throughput so far: runs that
    finish together (a batch of lanes, the first runs of each worker) do not make it
    thousands per second. On a terminal the bar is redrawn in place (colours unless
    ``NO_COLOR``); in a notebook rich draws it in the cell (live with ``ipywidgets``).

    Examples
    --------
    >>> import io
    >>> now = iter([0.0, 0.0, 10.0]).__next__
    >>> bar = RunProgress("{total} runs", file=io.StringIO(), clock=now)
    >>> bar.update(0, 4); bar.update(2, 4); bar.rate()
    '0.20 runs/s'
    >>> bar.close()
    """

    def __init__(self, label: str, unit: str = "runs", *, file: Any = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.label, self.unit, self.file, self.clock = label, unit, file, clock
        self.bar: Any = None
        self.task: Any = None
        self.done = self.total = 0
        self.t0 = 0.0
        self.elapsed = 0.0

    def rate(self) -> str:
        """Runs per second since the bar started ("" before the first run)."""
        if self.done <= 0 or self.elapsed <= 0:
            return ""
        return f"{self.done / self.elapsed:.2f} {self.unit}/s"

    def _start(self, total: int) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TaskProgressColumn,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.close()
        console = Console(file=self.file if self.file is not None else sys.stderr)
        self.bar = Progress(
            TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
            TaskProgressColumn(), TextColumn("{task.fields[rate]}"), TimeElapsedColumn(),
            TextColumn("ETA"), TimeRemainingColumn(), console=console,
        )
        self.bar.start()
        self.task = self.bar.add_task(self.label.format(total=total), total=total, rate="")
        self.done, self.total, self.t0, self.elapsed = 0, total, self.clock(), 0.0

    def update(self, done: int, total: int) -> None:
        if self.bar is None or done < self.done or total != self.total:
            self._start(total)
        self.done = done
        self.elapsed = self.clock() - self.t0
        self.bar.update(self.task, completed=done, rate=self.rate())

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
            self.bar = None


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
    progress: Callable[[int, int], None] | bool | None = None,
    flush_s: float = 2.0,
    notice: Callable[[str], None] | None = None,
    job_fn: Callable[[Job], dict[str, Any]] = run_job,
    lanes: int | None = None,
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
        Overwrite an existing ``out`` (never the architecture file: refused).
    progress : callable or bool, optional
        ``progress(done, total)`` after every finished run; True: a
        :class:`RunProgress` bar (on stderr, or in a notebook's cell).
    notice : callable, optional
        Called with a one-line message when a worker died and the pool is
        restarted (default: printed to stderr).
    job_fn : callable
        What a worker runs (default :func:`~archself.campaign.worker.run_job`;
        another function for fault injection in tests).
    lanes : int, optional
        Runs of one scenario and mode are batched, up to this many per unit of work,
        and stepped together (:func:`lane_units`, :mod:`archself.lanes`); 1 turns
        batching off. Default: :func:`default_lanes` (the runs shared over the
        workers, within half the free memory, at most 256) where every module type of
        the file is batched (``meta["lane_types"]``), else 1.

    A local worker that dies: its runs are retried, as the module's docstring says.

    Raises
    ------
    CampaignInterrupted
        On Ctrl-C (exit 130) or SIGTERM (exit 143), after saving the finished runs.
    CampaignError
        ``out`` exists (without resume or force), or belongs to another campaign;
        the pool cannot start, or its workers keep dying.
    OutputError
        ``out`` or a trace is an input file; the traces folder cannot be written.
    """
    run = _plan_run(jobs, meta, Path(out), executor, resume=resume, force=force)
    if not run.todo:
        run.flush()
        return run.outcome()
    bar = RunProgress("{total:,} runs") if progress is True else None
    run.progress = bar.update if bar is not None else progress if callable(progress) else None
    run.say = notice or (lambda msg: print(msg, file=sys.stderr, flush=True))
    run.flush_s, run.unit_fn = flush_s, functools.partial(run_unit, job_fn)
    try:
        run.open(workers, address, lanes)
        run.run()
    finally:
        if bar is not None:
            bar.close()
    return run.outcome()


def _plan_run(jobs: Sequence[Job], meta: dict[str, Any], out: Path, executor: str, *,
              resume: bool, force: bool) -> _Campaign:
    """Check the outputs, keep the rows to resume from: the runs to do."""
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise CampaignError(f"{out}: cannot write: folder {folder} does not exist")
    _check_outputs(jobs, out)
    rows: list[dict[str, Any]] = []
    if out.exists() and resume:
        rows = _existing(out, meta)
    elif out.exists() and not force:
        raise CampaignError(f"{out}: exists; --resume to continue it, --force to start over")
    done_ids = {r["run_id"] for r in rows}
    # replicate-major submission: an interrupted campaign has seeds of every cell
    todo = sorted((j for j in jobs if j.run_id not in done_ids), key=lambda j: j.replicate)
    return _Campaign(jobs, meta, out, executor, rows, todo)


def _lane_width(lanes: int | None, meta: dict[str, Any], jobs: Sequence[Job],
                todo: list[Job], n_workers: int) -> int:
    """Runs per unit of work: ``lanes``, else :func:`default_lanes` where lanes pay."""
    if lanes is None and not meta.get("lane_types", True):
        return 1  # some module type would run lane by lane: lanes would not pay
    if lanes is None:
        steps = int(meta.get("steps", 0)) // max(1, len(jobs))
        return default_lanes(todo, n_workers, steps, available_memory())
    return max(1, int(lanes))


class _Campaign:
    """The runs of a campaign on one executor: submit, keep the rows, recover a dead pool.

    A worker that dies: as the module's docstring says.
    """

    def __init__(self, jobs: Sequence[Job], meta: dict[str, Any], out: Path, executor: str,
                 rows: list[dict[str, Any]], todo: list[Job]) -> None:
        self.jobs, self.meta, self.out, self.executor = jobs, meta, out, executor
        self.rows, self.todo = rows, todo
        self.pending: dict[str, Job] = {j.run_id: j for j in todo}  # in submission order
        self.suspects: set[str] = set()  # on a worker when the pool broke: one at a time
        self.attempts: dict[str, int] = {}  # pool breaks while a run was alone on it
        self.ran = self.failed = self.restarts = 0
        self.errors: list[str] = []
        self.futures: dict[Any, tuple[Job, ...]] = {}
        self.progress: Callable[[int, int], None] | None = None
        self.say: Callable[[str], None] = print
        self.flush_s = 2.0
        self.unit_fn: Callable[..., Any] = run_unit
        self.width = 1
        self.t0 = time.perf_counter()

    def flush(self) -> None:
        write_results(self.out, self.rows, list(self.meta.get("sweeps", [])), self.meta)

    def saved(self) -> str:
        n = len(self.rows)
        return (f"{n} run{'s' * (n != 1)} saved in {self.out}; "
                "run the same command with --resume to continue")

    def open(self, workers: int | None, address: str | None, lanes: int | None) -> None:
        """Start the executor; the runs per unit of work from its workers."""
        # no more local processes than runs (--workers 100000 on 2 runs starts 2)
        self.n_start = None if workers is None else max(1, min(int(workers), len(self.todo)))
        self.address = address
        self.start()
        self.n_workers = self.ex.workers
        self.width = _lane_width(lanes, self.meta, self.jobs, self.todo, self.n_workers)

    def start(self) -> None:
        """Start the executor (again after a worker died)."""

        try:
            self.ex = make_executor(self.executor, workers=self.n_start, address=self.address,
                                    preload=["archself.campaign.worker"])
        except (OSError, RuntimeError) as exc:
            raise CampaignError(f"cannot start the {self.executor} workers: {exc}") from None

    def keep(self, job: Job, row: dict[str, Any]) -> None:
        """A finished run's row: kept, counted, reported to ``progress``."""
        self.pending.pop(job.run_id, None)
        self.suspects.discard(job.run_id)
        self.rows.append(row)
        self.ran += 1
        if row.get("error"):
            self.failed += 1
            if len(self.errors) < 5:
                self.errors.append(f"{row['run_id']}: {row['error']}")
        if self.progress is not None:
            self.progress(self.ran, len(self.todo))

    def run(self) -> None:
        """Rounds of submission until no run is pending; Ctrl-C or an error saves the rows."""
        try:
            if self.progress is not None:
                self.progress(0, len(self.todo))
            self.last = time.perf_counter()
            while self.pending:
                self.round()
            self.flush()
        except KeyboardInterrupt as exc:
            _abort(self.ex, self.futures)
            self.flush()
            terminated = isinstance(exc, Terminated)
            err = CampaignInterrupted(
                f"{'terminated' if terminated else 'interrupted'}: {self.saved()}")
            err.exit_code = 143 if terminated else 130
            raise err from None
        except BaseException:
            _abort(self.ex, self.futures)
            self.flush()
            raise
        self.ex.close()

    def round(self) -> None:
        """Submit the pending runs (a suspect alone), keep the rows as they finish."""
        alone = [j for j in self.pending.values() if j.run_id in self.suspects][:1]
        units = ([tuple(alone)] if alone
                 else lane_units(list(self.pending.values()), self.width, self.n_workers))
        try:
            self.futures = {self.ex.submit(self.unit_fn, u): u for u in units}
        except Exception as exc:  # noqa: BLE001 - a pool that cannot take work
            if not _worker_died(exc) and not isinstance(exc, OSError):
                raise
            raise CampaignError(f"the {self.executor} workers could not start: {exc}") from None
        for fut in self.ex.as_completed(list(self.futures)):
            unit = self.futures[fut]
            try:
                unit_rows = fut.result()
            except Exception as exc:  # noqa: BLE001 - infrastructure, not the run
                if _worker_died(exc) and self.executor != "dask":
                    self.recover(exc, units, alone)
                    return
                unit_rows = [_failed_row(j, f"{type(exc).__name__}: {exc}") for j in unit]
            for job, row in zip(unit, unit_rows, strict=True):
                self.keep(job, row)
            now = time.perf_counter()
            if now - self.last >= self.flush_s:
                self.flush()
                self.last = now

    def recover(self, died: BaseException, units: list[tuple[Job, ...]],
                alone: list[Job]) -> None:
        """A worker died: keep what finished, find the run that was on it, restart the pool."""
        for fut, unit in self.futures.items():
            if unit[0].run_id in self.pending and fut.done() and not fut.cancelled():
                if fut.exception() is None:
                    for job, row in zip(unit, fut.result(), strict=True):
                        self.keep(job, row)
        self.flush()
        if alone:  # it was alone on the pool: it is the one
            job = alone[0]
            self.attempts[job.run_id] = self.attempts.get(job.run_id, 0) + 1
            if self.attempts[job.run_id] >= MAX_ATTEMPTS:
                self.keep(job, _failed_row(job, f"worker process died ({MAX_ATTEMPTS + 1} tries)"))
        else:  # FIFO: the first workers + 1 unfinished units were on a worker or queued
            left = [u for u in units if u[0].run_id in self.pending]
            self.suspects.update(j.run_id for u in left[: self.n_workers + 1] for j in u)
        with contextlib.suppress(Exception):  # the pool is broken already
            getattr(self.ex, "abort", self.ex.close)()
        self.restarts += 1
        if self.restarts > MAX_POOL_RESTARTS:
            self.flush()
            raise CampaignError(f"worker processes died {self.restarts} times "
                                f"({type(died).__name__}); {self.saved()}")
        self.say(
            f"a worker process died ({type(died).__name__}); pool restarted "
            f"({self.restarts}/{MAX_POOL_RESTARTS}), {len(self.pending)} runs to go"
            + (f", {len(self.suspects)} retried one at a time" if self.suspects else "")
        )
        if self.pending:
            self.start()

    def outcome(self) -> CampaignOutcome:
        """What the campaign did (nothing to run: no workers, no time)."""
        n = len(self.jobs)
        if not self.todo:
            return CampaignOutcome(self.out, n, n, 0, 0, len(self.rows), 0, self.executor, 0.0)
        return CampaignOutcome(
            self.out, n, n - len(self.todo), self.ran, self.failed, len(self.rows),
            self.n_workers, self.ex.name, time.perf_counter() - self.t0, self.errors,
        )


def _failed_row(job: Job, error: str) -> dict[str, Any]:
    return {**_base_row(job), "error": error[:500]}


def _abort(ex: Any, futures: dict[Any, tuple[Job, ...]]) -> None:
    """Stop the executor at once (Ctrl-C, SIGTERM, an error), whatever state it is in."""
    with contextlib.suppress(BaseException):  # a second Ctrl-C, a broken pool
        if hasattr(ex, "abort"):  # the local pool: end the workers, no cancel (see abort)
            ex.abort()
        else:
            ex.cancel(list(futures))
            ex.close()
