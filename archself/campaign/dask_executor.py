"""The Dask executor: a dask.distributed client on a scheduler or on a LocalCluster.

Needs the optional extra ``pip install 'archself[dask]'``; without it, or without a
reachable scheduler, :class:`DaskExecutor` is a one-line
:class:`~archself.campaign.sweep.CampaignError`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any

from archself.campaign.local_executor import default_workers
from archself.campaign.sweep import CampaignError

__all__ = ["DaskExecutor"]

#: How long the client waits for the scheduler (seconds).
TIMEOUT_S = 30.0


class DaskExecutor:
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

    def __enter__(self) -> DaskExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
