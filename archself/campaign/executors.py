"""Where campaign runs execute: one small interface, a local process pool or Dask.

:class:`Executor` is all the campaign driver uses: ``submit`` a function and its
arguments, ``map`` a function over items, iterate futures ``as_completed``,
``cancel`` what has not started and ``close``. Two implementations:

- :class:`LocalExecutor` — :class:`concurrent.futures.ProcessPoolExecutor` on
  all cores (the embedded default; no server). Workers are started with the
  ``forkserver`` method where available (fresh processes, not copies of the
  caller) and ignore SIGINT, so Ctrl-C reaches only the driver, which then stops
  cleanly. Each worker runs its BLAS single-threaded (:func:`single_thread_blas`).
- :class:`DaskExecutor` — a :class:`distributed.Client` on an existing scheduler
  (``tcp://HOST:PORT``) or on a :class:`distributed.LocalCluster` it starts and
  stops itself. Needs the optional extra ``pip install 'archself[dask]'``.

Both return futures with ``result()``, ``done()`` and ``cancel()``.
The implementations live in :mod:`~archself.campaign.local_executor`,
:mod:`~archself.campaign.dask_executor` and :mod:`~archself.campaign.inline_executor`;
their names are re-exported here.

Examples
--------
>>> with make_executor("local", workers=1) as ex:     # doctest: +SKIP
...     list(ex.map(abs, [-1, -2]))
[1, 2]
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any, Protocol

from archself.campaign.dask_executor import DaskExecutor
from archself.campaign.inline_executor import InlineExecutor
from archself.campaign.local_executor import (
    BLAS_THREAD_VARIABLES,
    LocalExecutor,
    default_workers,
    single_thread_blas,
)
from archself.campaign.sweep import CampaignError

__all__ = [
    "BLAS_THREAD_VARIABLES",
    "DaskExecutor",
    "Executor",
    "InlineExecutor",
    "LocalExecutor",
    "default_workers",
    "make_executor",
    "single_thread_blas",
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
