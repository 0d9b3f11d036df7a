"""The objective J of Eq. 11: the error between an actual and a reference signal."""

from __future__ import annotations

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
        a = np.atleast_1d(np.asarray(actual, dtype=float))
        r = np.atleast_1d(np.asarray(reference, dtype=float))
    except (TypeError, ValueError):
        return np.full(len(components), np.nan)
    out = np.full(len(components), np.nan)
    for k, c in enumerate(components):
        if -a.size <= c < a.size and -r.size <= c < r.size:
            out[k] = a[c] - r[c]
    return out
