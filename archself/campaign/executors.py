"""Where campaign runs execute: one small interface, a local process pool, Dask or inline.

:class:`Executor` is all the campaign driver uses: ``submit`` a function and its
arguments, ``map`` a function over items, iterate futures ``as_completed``,
``cancel`` what has not started and ``close``. Three implementations:

- :class:`LocalExecutor` — :class:`concurrent.futures.ProcessPoolExecutor` on
  all cores (:func:`default_workers`; the embedded default, no server), started with
  ``forkserver`` where available (fresh processes, not copies of the caller). Its
  workers ignore SIGINT, so Ctrl-C reaches only the driver, which then stops cleanly,
  and end when the driver dies (:func:`die_with_parent`: Linux's ``PR_SET_PDEATHSIG``
  and a watchdog thread). Each process runs its BLAS single-threaded
  (:func:`archself.resources.single_thread_blas`). The forkserver imports this module
  first, which makes it die with the driver too.
- :class:`DaskExecutor` — a :class:`distributed.Client` on an existing scheduler
  (``tcp://HOST:PORT``) or on a :class:`distributed.LocalCluster` it starts and
  stops itself. Needs the optional extra ``pip install 'archself[dask]'``; without
  it, or without a reachable scheduler, it is a one-line
  :class:`~archself.campaign.sweep.CampaignError`.
- :class:`InlineExecutor` — every job in the calling process, when its result is
  asked for: for debugging (a breakpoint in a module works) and for tests; not
  offered by the command line.

All return futures with ``result()``, ``done()`` and ``cancel()``.

Examples
--------
>>> with make_executor("local", workers=1) as ex:     # doctest: +SKIP
...     list(ex.map(abs, [-1, -2]))
[1, 2]
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future
from typing import Any, Protocol, Self

from archself.campaign.sweep import CampaignError
from archself.resources import single_thread_blas

__all__ = [
    "DaskExecutor",
    "Executor",
    "InlineExecutor",
    "LocalExecutor",
    "default_workers",
    "die_with_parent",
    "make_executor",
]


class Executor(Protocol):
    """What the campaign driver needs from a pool of workers."""

    #: Number of worker processes (for the progress label and the report).
    workers: int
    #: ``"local"`` or ``"dask"``.
    name: str

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> Any:
        """Run ``fn(*args)`` in a worker; a future."""

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        """``fn(item)`` for every item, results in the order of ``items``."""

    def as_completed(self, futures: Iterable[Any]) -> Iterator[Any]:
        """The futures in the order they finish."""

    def cancel(self, futures: Iterable[Any]) -> None:
        """Cancel the futures that have not started."""

    def close(self) -> None:
        """Stop the workers (and a cluster started by this executor)."""

    def __enter__(self) -> Executor: ...

    def __exit__(self, *exc: object) -> None: ...


class _Closing:
    """What the executors share: ``with`` closes them; ``cancel`` cancels each future."""

    def cancel(self, futures: Iterable[Any]) -> None:
        for f in futures:
            f.cancel()

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def make_executor(
    kind: str = "local",
    *,
    workers: int | None = None,
    address: str | None = None,
    preload: Iterable[str] = (),
) -> Executor:
    """The executor named ``kind``: ``"local"``, ``"dask"`` (or ``"inline"``, for tests).

    Raises
    ------
    CampaignError
        On an unknown kind, or an address given to the local executor.
    """
    if kind == "local":
        if address is not None:
            raise CampaignError("--address needs --executor dask")
        return LocalExecutor(workers, preload=preload)
    if kind == "dask":
        return DaskExecutor(address, workers)
    if kind == "inline":
        return InlineExecutor()
    raise CampaignError(f"unknown executor {kind!r}; known: local, dask")


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


class LocalExecutor(_Closing):
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


#: How long the client waits for the scheduler (seconds).
TIMEOUT_S = 30.0


class DaskExecutor(_Closing):
    """A dask.distributed client: on a scheduler at ``address`` or on a LocalCluster.

    Parameters
    ----------
    address : str, optional
        Scheduler address, e.g. ``tcp://10.0.0.5:8786``. None starts a
        :class:`distributed.LocalCluster` of ``workers`` single-threaded
        processes, closed again by :meth:`close`.
    workers : int, optional
        Workers of the LocalCluster (default: all usable cores); ignored with an
        address (the cluster has what it has).

    Raises
    ------
    CampaignError
        If dask.distributed is not installed or the scheduler cannot be reached.
    """

    name = "dask"

    def __init__(self, address: str | None = None, workers: int | None = None) -> None:
        try:
            import distributed
        except ImportError:
            raise CampaignError(
                "--executor dask needs dask.distributed: pip install 'archself[dask]'"
            ) from None
        self._distributed = distributed
        self._cluster: Any = None
        self._client: Any = None
        try:
            if address is None:
                n = int(workers or default_workers())
                if n < 1:
                    raise CampaignError("--workers must be at least 1")
                self._cluster = distributed.LocalCluster(
                    n_workers=n,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    silence_logs=50,
                )
                self._client = distributed.Client(self._cluster, timeout=TIMEOUT_S)
            else:
                self._client = distributed.Client(address, timeout=TIMEOUT_S)
        except (OSError, TimeoutError) as exc:
            self.close()
            where = address or "a LocalCluster"
            raise CampaignError(f"cannot connect to the Dask scheduler at {where}: {exc}") from None
        except (ValueError, TypeError) as exc:  # e.g. "missing port number in address"
            self.close()
            raise CampaignError(
                f"--address {address!r}: not a Dask scheduler address (tcp://HOST:PORT): {exc}"
            ) from None
        info = self._client.scheduler_info()
        threads = sum(int(w.get("nthreads", 1)) for w in info.get("workers", {}).values())
        self.workers = max(1, threads)
        self.address = self._client.scheduler.address

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> Any:
        return self._client.submit(fn, *args, pure=False)

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        futures = self._client.map(fn, list(items), pure=False)
        return (f.result() for f in futures)

    def as_completed(self, futures: Iterable[Any]) -> Iterator[Any]:
        return iter(self._distributed.as_completed(list(futures)))

    def cancel(self, futures: Iterable[Any]) -> None:
        fs = [f for f in futures if not f.done()]
        if fs:
            self._client.cancel(fs)

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None


class _Deferred(Future):
    """A future of :class:`InlineExecutor`: computed when first asked for."""

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        super().__init__()
        self._call = fn, args

    def _run(self) -> None:
        if not self.done() and self.set_running_or_notify_cancel():
            fn, args = self._call
            try:
                self.set_result(fn(*args))
            except Exception as exc:  # noqa: BLE001 - kept for result(), like a real future
                self.set_exception(exc)

    def result(self, timeout: float | None = None) -> Any:
        self._run()
        return super().result(timeout)


class InlineExecutor(_Closing):
    """Runs every job in the calling process, one after the other, when its result is asked for.

    For debugging (a breakpoint in a module works) and for tests; not offered by
    the command line.
    """

    name = "inline"
    workers = 1

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> Any:
        return _Deferred(fn, args)

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        return (fn(x) for x in items)

    def as_completed(self, futures: Iterable[Any]) -> Iterator[Any]:
        for f in list(futures):
            if not f.cancelled():
                f._run()
                yield f

    def close(self) -> None:
        pass
