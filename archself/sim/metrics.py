"""The metrics of a run's objective error J: maximum, final, RMS, time of the peak.

:func:`error_metrics` computes them from the recorded series (units of
``runtime.objective.unit``; the deprecated metre names beside them for an objective
in ``m``), :func:`metric_rows` labels them for tables.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["METRICS", "METRE_ALIASES", "error_metrics", "metric_rows"]

#: The metrics of a run's objective error J; the first three are in the objective's unit.
METRICS = ("max_error", "final_error", "rms_error", "peak_time_s")
#: Deprecated names (until the next release) of the first three, written beside them when
#: the objective's unit is ``m`` (the names archself used when every objective was a distance).
METRE_ALIASES = {"max_error_m": "max_error", "final_error_m": "final_error",
                 "rms_error_m": "rms_error"}


def error_metrics(t: np.ndarray, err: np.ndarray, unit: str | None = None) -> dict[str, float]:
    """``max_error``, ``final_error``, ``rms_error`` and ``peak_time_s`` of an error series.

    With ``unit="m"`` the deprecated aliases ``max_error_m``, ``final_error_m`` and
    ``rms_error_m`` follow (:data:`METRE_ALIASES`).

    Examples
    --------
    >>> error_metrics(np.array([0.0, 1.0, 2.0]), np.array([0.0, 2.0, 1.0]))
    {'max_error': 2.0, 'final_error': 1.0, 'rms_error': 1.2909944487358056, 'peak_time_s': 1.0}
    >>> list(error_metrics(np.array([0.0]), np.array([0.5]), unit="m"))[4:]
    ['max_error_m', 'final_error_m', 'rms_error_m']
    """
    err = np.asarray(err, dtype=float)
    ok = np.isfinite(err)
    if not ok.any():
        out = dict.fromkeys(METRICS, math.nan)
    else:
        e = np.where(ok, err, -np.inf)
        i = int(np.argmax(e))
        out = {
            "max_error": float(err[i]),
            "final_error": float(err[ok][-1]),
            "rms_error": float(np.sqrt(np.mean(err[ok] ** 2))),
            "peak_time_s": float(t[i]),
        }
    if unit == "m":
        out.update({alias: out[name] for alias, name in METRE_ALIASES.items()})
    return out


def metric_rows(unit: str | None) -> list[tuple[str, str, int]]:
    """``(label, metric, decimals)`` of the metrics as tables show them, unit from the file.

    Examples
    --------
    >>> [label for label, _, _ in metric_rows("m")]
    ['max error [m]', 'final error [m]', 'RMS error [m]', 'peak time [s]']
    >>> metric_rows(None)[0]
    ('max error', 'max_error', 3)
    """
    u = f" [{unit}]" if unit else ""
    return [(f"max error{u}", "max_error", 3), (f"final error{u}", "final_error", 3),
            (f"RMS error{u}", "rms_error", 3), ("peak time [s]", "peak_time_s", 1)]

