"""The objective J of Eq. 11: the error between an actual and a reference signal."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def component_error(actual: Any, reference: Any, components: list[int]) -> np.ndarray:
    """``actual[c] − reference[c]`` for the objective components (a scalar is a 1-vector).

    Components a signal does not have, and values that are not numbers, give NaN.

    Examples
    --------
    >>> component_error([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [0, 1]).tolist()
    [1.0, 2.0]
    >>> component_error(2.0, 0.5, [0]).tolist()
    [1.5]
    """
    try:
        a = np.asarray(actual, dtype=float).reshape(-1)  # a scalar is a 1-vector
        r = np.asarray(reference, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return np.full(len(components), np.nan)
    out = np.full(len(components), np.nan)
    for k, c in enumerate(components):
        if -a.size <= c < a.size and -r.size <= c < r.size:
            out[k] = a[c] - r[c]
    return out


def objective_norm(actual: Any, reference: Any, components: list[int]) -> float:
    """J = ‖actual[c] − reference[c]‖ over the objective components (NaN when unknown).

    The norm is ``sqrt(Σ d²)`` summed in component order, on floats: the per-step
    series J of a run and J_obs of the MAPE-K loop come from this one function, so
    they agree to the last bit.

    Examples
    --------
    >>> objective_norm([3.0, 4.0, 9.0], [0.0, 0.0, 0.0], [0, 1])
    5.0
    >>> objective_norm(None, [0.0], [0])
    nan
    """
    if actual is None or reference is None:
        return math.nan
    if type(actual) is np.ndarray and type(reference) is np.ndarray:  # the common case
        al, rl = actual.tolist(), reference.tolist()
        if type(al) is list and type(rl) is list:
            try:
                s2 = 0.0
                for c in components:
                    d = al[c] - rl[c]
                    s2 += d * d
                return math.sqrt(s2)
            except (IndexError, TypeError):
                pass
    s2 = 0.0
    for d in component_error(actual, reference, components).tolist():
        s2 += d * d
    return math.sqrt(s2)
