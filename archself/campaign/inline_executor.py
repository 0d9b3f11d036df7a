"""The inline executor: every job in the calling process, when its result is asked for.

For debugging (a breakpoint in a module works) and for tests; not offered by the
command line. Its futures (:class:`_Deferred`) compute on first ``result()``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future
from typing import Any

__all__ = ["InlineExecutor"]


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


class InlineExecutor:
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

    def cancel(self, futures: Iterable[Any]) -> None:
        for f in futures:
            f.cancel()

    def close(self) -> None:
        pass

    def __enter__(self) -> InlineExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
