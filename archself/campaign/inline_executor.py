"""The inline executor: every job in the calling process, when its result is asked for.

For debugging (a breakpoint in a module works) and for tests; not offered by the
command line. Its futures (:class:`_Deferred`) compute on first ``result()``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any

__all__ = ["InlineExecutor"]


class _Deferred:
    """A future of :class:`InlineExecutor`: computed when first asked for."""

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        self._fn, self._args = fn, args
        self._done = self._cancelled = False
        self._value: Any = None
        self._exc: BaseException | None = None

    def _run(self) -> None:
        if not self._done and not self._cancelled:
            try:
                self._value = self._fn(*self._args)
            except Exception as exc:  # noqa: BLE001 - kept for result(), like a real future
                self._exc = exc
            self._done = True

    def result(self) -> Any:
        if self._cancelled:
            import concurrent.futures

            raise concurrent.futures.CancelledError()
        self._run()
        if self._exc is not None:
            raise self._exc
        return self._value

    def done(self) -> bool:
        return self._done or self._cancelled

    def cancel(self) -> bool:
        if self._done:
            return False
        self._cancelled = True
        return True


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
            if not f._cancelled:
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
