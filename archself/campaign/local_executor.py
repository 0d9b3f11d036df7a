"""The local process pool: workers on this machine that die with the driver.

:class:`LocalExecutor` is a :class:`concurrent.futures.ProcessPoolExecutor` on all
cores (:func:`default_workers`), started with ``forkserver`` where available (fresh
processes, not copies of the caller); its workers ignore SIGINT, so Ctrl-C reaches
only the driver, and end when the driver dies (:func:`die_with_parent`: Linux's
``PR_SET_PDEATHSIG`` and a watchdog thread). Each process runs its BLAS
single-threaded (:func:`single_thread_blas`). The forkserver imports this module
first, which makes it die with the driver too.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from collections.abc import Callable, Iterable, Iterator, MutableMapping
from typing import Any

from archself.campaign.sweep import CampaignError

__all__ = [
    "BLAS_THREAD_VARIABLES",
    "LocalExecutor",
    "default_workers",
    "die_with_parent",
    "single_thread_blas",
]

#: Environment variables that set the thread count of the BLAS/OpenMP libraries.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_thread_blas(environ: MutableMapping[str, str] | None = None) -> None:
    """One BLAS thread for the processes started from now on (unless the user chose a number).

    A run multiplies 3×3 to 5×5 matrices, where a second BLAS thread gains nothing,
    but OpenBLAS's idle threads spin: one 400 s run took 0.84 s of wall time and
    1.08 s of CPU, and two runs side by side slowed each other by 16 %. With one
    thread per process, two workers run at the speed of one each (measured:
    0.841 s/run alone, 0.843 and 0.846 s/run side by side). The variables are read
    when a BLAS library loads, so this runs before a worker imports numpy: the
    local pool's forkserver inherits them (a Dask nanny sets the same by default,
    ``distributed.nanny.pre-spawn-environ``).

    Parameters
    ----------
    environ : mutable mapping, optional
        Where to set them (default ``os.environ``).
    """
    env = os.environ if environ is None else environ
    for name in BLAS_THREAD_VARIABLES:
        if not env.get(name):  # unset or empty
            env[name] = "1"


def default_workers() -> int:
    """Number of usable cores (the process's CPU affinity where the OS tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


#: Set by the driver for the processes it starts: its pid (see :func:`die_with_parent`).
DRIVER_PID_VARIABLE = "ARCHSELF_DRIVER_PID"
#: How often a worker's watchdog checks that the driver is still there (seconds).
WATCHDOG_PERIOD_S = 0.5
PR_SET_PDEATHSIG = 1


def _set_pdeathsig(sig: int) -> None:
    """Linux: the kernel sends ``sig`` to this process when its parent dies."""
    if sys.platform.startswith("linux"):
        import ctypes

        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def die_with_parent(driver_pid: int | None = None, watchdog: bool = True) -> None:
    """Make this process exit when its parent (or the campaign driver) dies.

    Two mechanisms: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` on Linux (immediate, when
    the parent process dies), and a daemon thread that checks every
    :data:`WATCHDOG_PERIOD_S` that the parent is the same and the driver
    (``driver_pid``) still exists, and ends the process otherwise (every OS).
    A pool worker's parent is the forkserver, which itself dies with the driver
    (this function, run in the forkserver when it imports this module).
    """
    parent = os.getppid()
    _set_pdeathsig(signal.SIGKILL)
    if os.getppid() != parent or parent == 1:  # the parent died before prctl
        os._exit(1)
    if not watchdog:
        return
    import threading

    def watch() -> None:
        import time

        while True:
            time.sleep(WATCHDOG_PERIOD_S)
            if os.getppid() != parent or (driver_pid is not None and not _alive(driver_pid)):
                os._exit(1)

    threading.Thread(target=watch, name="archself-parent-watchdog", daemon=True).start()


def _worker_init(driver_pid: int | None = None) -> None:
    """Initializer of a local pool worker: no SIGINT (the driver stops cleanly), dies with it."""
    import warnings

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    # a run's numeric trouble shows in its row (NaN metrics, the error column); the
    # workers' warnings would reach the terminal unlocated, between the driver's lines
    warnings.simplefilter("ignore", RuntimeWarning)
    die_with_parent(driver_pid)


# In the forkserver (it imports this module as a preload, its parent is the driver):
# die with the driver. The forkserver forks the workers, so no thread is started here.
if (
    os.environ.get(DRIVER_PID_VARIABLE) == str(os.getppid())
    and sys.argv[:1] == ["-c"]
    and "multiprocessing.forkserver" in sys.modules
):
    die_with_parent(watchdog=False)


class LocalExecutor:
    """A process pool on this machine (the default executor).

    Parameters
    ----------
    workers : int, optional
        Number of processes (default: all usable cores).
    preload : sequence of str, optional
        Modules the forkserver imports once, so every worker starts with them.
    """

    name = "local"

    def __init__(self, workers: int | None = None, preload: Iterable[str] = ()) -> None:
        import concurrent.futures
        import multiprocessing

        self.workers = int(workers or default_workers())
        if self.workers < 1:
            raise CampaignError("--workers must be at least 1")
        single_thread_blas()  # before the forkserver (and numpy in it) starts
        os.environ[DRIVER_PID_VARIABLE] = str(os.getpid())  # the forkserver dies with us
        methods = multiprocessing.get_all_start_methods()
        method = "forkserver" if "forkserver" in methods else "spawn"
        ctx = multiprocessing.get_context(method)
        if method == "forkserver":
            ctx.set_forkserver_preload([__name__, *preload])
        self._cf = concurrent.futures
        try:
            self._pool = concurrent.futures.ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=ctx,
                initializer=_worker_init,
                initargs=(os.getpid(),),
            )
        except (OSError, ValueError) as exc:
            raise CampaignError(f"cannot start the local process pool: {exc}") from None

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> Any:
        return self._pool.submit(fn, *args)

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        return self._pool.map(fn, items)

    def as_completed(self, futures: Iterable[Any]) -> Iterator[Any]:
        return self._cf.as_completed(list(futures))

    def cancel(self, futures: Iterable[Any]) -> None:
        for f in futures:
            f.cancel()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)

    def abort(self) -> None:
        """Stop at once: cancel the queue and end the workers (their runs are lost)."""
        # End the workers first, without cancelling futures: the pool's manager then
        # fails the unfinished futures itself (cancelling them first races with it:
        # InvalidStateError in its thread, Python 3.11).
        for p in list(getattr(self._pool, "_processes", None) or {}):
            with contextlib.suppress(OSError):
                os.kill(p, signal.SIGTERM)
        with contextlib.suppress(Exception):  # a broken pool is fine here
            self._pool.shutdown(wait=True, cancel_futures=False)

    def __enter__(self) -> LocalExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
