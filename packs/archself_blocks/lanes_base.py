"""What the block library's batched classes share: lane values as rows, screens, streams.

The batched classes (``lanes_*`` modules of this pack) are the
:class:`~archself.lanes.LaneModule` counterparts of the ``generic.*`` types: each
keeps one module's state in N lanes with a leading lane axis and computes, lane by
lane, the floats its per-run instance computes from the same inputs. Matrix
products go through ``numpy.matmul`` on stacks of per-lane matrices, which gives
each lane's ``A @ x`` of the per-run code bit for bit on the platforms tested
(x86-64, numpy 2.4; the tests allow 1e-9 for another BLAS).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from archself.lanes.module import LaneModule

__all__ = [
    "BlockLanes", "as_rows", "present", "factors", "zoh",
]


def as_rows(value: Any) -> np.ndarray | None:
    """A numeric lane value as ``(L, w)`` rows (a scalar signal is one column).

    None (absent everywhere) and lists (objects, which the per-run blocks do not read
    as numbers) give None.

    Examples
    --------
    >>> as_rows(np.array([1.0, np.nan])).tolist()
    [[1.0], [nan]]
    >>> as_rows(None) is None
    True
    """
    if value is None or type(value) is list:
        return None
    arr = np.asarray(value, dtype=float)
    return arr[:, None] if arr.ndim == 1 else arr


def present(rows: np.ndarray) -> np.ndarray:
    """The lanes where ``rows`` (from :func:`as_rows`) hold a value (not a NaN row)."""
    return ~np.isnan(rows[:, 0])


def factors(values: np.ndarray, of: Callable[[float], float]) -> np.ndarray:
    """``of(v)`` for each lane's ``v`` with :mod:`math` (numpy's exp may differ in the last bit).

    Examples
    --------
    >>> factors(np.array([0.0, 1.0]), lambda tau: 2.0 * tau).tolist()
    [0.0, 2.0]
    """
    return np.array([of(v) for v in values.tolist()], dtype=float)


def zoh(model: Any, dt: float, shared: dict[Any, Any]) -> tuple[np.ndarray, np.ndarray]:
    """``model.discrete(dt)``, computed once for the lanes whose models have the same A and B.

    Each lane has its own model object (its per-run instance's); ``control.c2d`` of the
    same matrices gives the same ``(Ad, Bd)``, so the first lane's result is put into
    the cache of the others (``shared`` maps the matrices to it) instead of computing it
    per lane.

    Examples
    --------
    >>> from archself_blocks.lti import LtiModel
    >>> a, b, shared = LtiModel([[-1.0]], [[1.0]]), LtiModel([[-1.0]], [[1.0]]), {}
    >>> zoh(a, 0.1, shared)[0] is zoh(b, 0.1, shared)[0]
    True
    """
    if model.dt > 0:
        return model.A, model.B
    hit = model._cache.get(dt)
    if hit is None:
        key = (model.A.shape, model.B.shape, model.A.tobytes(), model.B.tobytes(), dt)
        hit = shared.get(key)
        if hit is None:
            hit = shared[key] = model.discrete(dt)
        else:
            model._cache[dt] = hit
    return hit


class BlockLanes(LaneModule):
    """A batched block: the non-finite screen (``_read``: the core's)."""

    def _screen(self, lanes: slice | np.ndarray, has: np.ndarray, *values: Any) -> None:
        """Report the lanes in ``has`` whose value is not finite (the per-run check).

        A per-run system publishes nothing of a module with a non-finite output
        (``non-finite output``: the lane's last outputs are held), judged by the sum
        of each value's entries.
        """
        bad: np.ndarray | None = None
        for v in values:
            if v is None:
                continue
            total = v if v.ndim == 1 else v.sum(axis=1)
            if math.isfinite(float(total[has].sum())):
                continue
            here = has & ~np.isfinite(total)
            bad = here if bad is None else bad | here
        if bad is not None and bad.any():
            for i in self.indices(lanes)[bad]:
                self.failed.setdefault(int(i), "non-finite output")
