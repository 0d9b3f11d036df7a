"""Linear models in discrete time: zero-order hold at the run's step, unit-delay lines.

:func:`discretize` brings a module's :class:`~archself.modules.base.LinearModel` to
the executor's period (a discrete model of another period is a
:class:`LinearizationError`); :func:`delay_line` is an edge's latency as states.
"""

from __future__ import annotations

import numpy as np

from archself.modules.base import LinearModel

__all__ = ["LinearizationError", "delay_line", "discretize"]


class LinearizationError(ValueError):
    """The models of a configuration cannot be wired (widths or periods disagree)."""


def discretize(model: LinearModel, dt: float) -> LinearModel:
    """``model`` at period ``dt``: zero-order hold of a continuous one, a discrete one as is.

    Raises
    ------
    LinearizationError
        For a discrete model whose period is not ``dt``.

    Examples
    --------
    >>> m = LinearModel([[-1.0]], [[1.0]], [[1.0]], [[0.0]], [("u", 1)], [("y", 1)])
    >>> d = discretize(m, 0.1)
    >>> round(float(d.A[0, 0]), 6), round(float(d.B[0, 0]), 6), d.dt
    (0.904837, 0.095163, 0.1)
    """
    if model.dt > 0:
        if abs(model.dt - dt) > 1e-9 * max(1.0, dt):
            raise LinearizationError(
                f"a discrete model of period {model.dt:g} s in a run with step {dt:g} s"
            )
        return model
    n, m = model.n, model.m
    if n == 0:
        Ad, Bd = model.A, model.B
    else:
        from scipy.linalg import expm

        big = np.zeros((n + m, n + m))
        big[:n, :n] = model.A * dt
        big[:n, n:] = model.B * dt
        e = expm(big)
        Ad, Bd = e[:n, :n], e[:n, n:]
    return LinearModel(Ad, Bd, model.C, model.D, model.inputs, model.outputs, dt, model.states)


def delay_line(signal: str, width: int, steps: int, dt: float) -> LinearModel:
    """``steps`` unit delays of a ``width``-vector: ``y_k = u_{k−steps}``."""
    n = width * steps
    A = np.zeros((n, n))
    A[width:, :-width] = np.eye(n - width)
    B = np.zeros((n, width))
    B[:width] = np.eye(width)
    C = np.zeros((width, n))
    C[:, -width:] = np.eye(width)
    states = [f"{signal}[t-{k + 1}]" for k in range(steps) for _ in range(width)]
    return LinearModel(
        A, B, C, np.zeros((width, width)), [(signal, width)], [(signal, width)], dt, states
    )
