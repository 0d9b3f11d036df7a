"""The outcome of one simulation: :class:`RunResult`, its metrics, its trace, its pandas frames.

:func:`error_metrics` computes the metrics of a run's objective error J (maximum,
final, RMS, time of the peak; units of ``runtime.objective.unit``, the deprecated
metre names beside them for an objective in ``m``), :func:`metric_rows` labels them
for tables. A :class:`RunResult` holds a run's recorded series, metrics, switches and decision
log; it gives them as plain data (:meth:`RunResult.to_dict`, :meth:`RunResult.trace`:
the models of :mod:`archself.io.jsondata`),
as tidy pandas frames (:meth:`RunResult.to_pandas`, :meth:`RunResult.decisions_frame`),
as a notebook summary, and writes the trace file (:mod:`archself.io.trace`).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from archself.io.jsondata import DecisionLog, RunDoc, TraceMeta, document
from archself.io.trace import (
    TraceParts,
    component_columns,
    read_trace_parts,
    trace_parts_from_bytes,
    write_trace,
)

__all__ = [
    "METRICS", "METRE_ALIASES", "RunResult", "error_metrics", "metric_rows", "read_trace",
    "trace_from_bytes",
]

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



@dataclasses.dataclass(repr=False)
class RunResult:
    """The outcome of one simulation.

    Attributes
    ----------
    scenario : str
    seed : int
    mode : str
        ``"fixed"`` (no adaptation loop) or ``"adaptive"``.
    configuration : str
        The configuration the run started in.
    final_configuration : str
    metrics : dict
        ``max_error``, ``final_error``, ``rms_error`` (in :attr:`unit`) and
        ``peak_time_s`` of the objective error J; when the unit is ``m`` also the
        deprecated ``max_error_m``, ``final_error_m``, ``rms_error_m`` (same values).
    switches : list of dict
        Architecture switches ``{t_s, from, to, action, ...}`` (empty when fixed).
    series : dict of str -> ndarray
        Recorded time series, one row per step: ``t``, ``J`` (objective error),
        ``reference`` and ``actual`` (the objective's signals), one series per
        entry of ``runtime.record`` (the signal of the first active module that
        publishes it; diffdrive and the process plant record ``estimate`` and
        ``command``), ``configuration`` (index into :attr:`configurations`) and
        ``residual.<module>`` (each module's declared residual signal, NaN while
        inactive).
    decisions : list
        The adaptation loop's decision log (its ``decisions`` attribute), if any.

    :meth:`to_pandas` and :meth:`decisions_frame` give the series and the decision
    log as tidy pandas frames (named columns, configuration names); in a notebook
    the result shows as a small HTML summary.
    meta : dict
        Architecture name, step, period, duration.
    unit : str or None
        Unit of the error metrics: ``runtime.objective.unit`` (None if not declared).
    faults : list of dict
        The modules that were unavailable while active, one entry per module and
        reason, in the order first seen: ``{module, reason, first_s, last_s, steps}``
        (``reason`` as :meth:`LiveSystem.health` gives it, without a running count:
        ``raised RuntimeError``, ``non-finite output``, ``silent``, ``stale <signal>``,
        ``lost input <signal>``). Filled by :func:`archself.simulate` and, per lane,
        :func:`archself.lanes.run.simulate_lanes`; in the JSON (``--json``, a trace's
        ``meta``) only when not empty, so a trace without it reads back with ``[]``.
    """

    scenario: str
    seed: int
    mode: str
    configuration: str
    final_configuration: str
    metrics: dict[str, float]
    switches: list[dict[str, Any]]
    series: dict[str, np.ndarray]
    decisions: list[Any] = dataclasses.field(default_factory=list)
    meta: dict[str, Any] = dataclasses.field(default_factory=dict)
    configurations: list[str] = dataclasses.field(default_factory=list)
    unit: str | None = None
    faults: list[dict[str, Any]] = dataclasses.field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """The run as JSON data (one of ``archself simulate --json``'s ``runs``): its
        :class:`~archself.io.jsondata.RunDoc`."""
        return document(RunDoc, self)  # type: ignore[no-any-return]

    def trace(self) -> dict[str, Any]:
        """The trace document ``{meta, series, decisions}`` as plain JSON data."""
        series = {name: _series_list(arr) for name, arr in self.series.items()}
        return {"meta": self.trace_meta(), "series": series,
                "decisions": self.trace_decisions()}

    def trace_meta(self) -> dict[str, Any]:
        """The trace's ``meta`` (a :class:`~archself.io.jsondata.TraceMeta`): :attr:`meta`,
        the run (a :class:`~archself.io.jsondata.RunDoc`, one of ``simulate --json``'s
        ``runs``) and the configuration names."""
        return document(TraceMeta, {**self.meta, **{
            k: getattr(self, k) for k in (*RunDoc.model_fields, "configurations")}})

    def trace_decisions(self) -> list[Any]:
        """The decision log as plain data (dicts), as the trace stores it."""
        return list(document(DecisionLog, self.decisions, "decisions"))

    # ------------------------------------------------------------------ notebooks
    def to_pandas(self) -> Any:
        """The recorded series as a tidy :class:`pandas.DataFrame`, one row per step.

        Columns, in the order of :attr:`series`: ``t`` [s], ``J`` (the objective
        error, in :attr:`unit`), then every other series; a 2-D series (a vector
        signal) becomes one column per component, ``<name>_<element>`` where the
        publishing type names its elements (diffdrive: ``reference_x``, ``reference_y``,
        ``reference_theta``, ``reference_v``, ``reference_omega``, ``actual_x`` …,
        ``estimate_x`` …, ``command_left``, ``command_right``), else ``<name>_<k>``
        (``reference_0`` …); the objective compares ``runtime.objective.components``
        of ``reference`` and ``actual``; ``residual.<module>`` (NaN while inactive) and
        ``configuration``, the name of the configuration active at that step (a
        categorical over :attr:`configurations`, in file order). ``attrs`` holds
        ``scenario``, ``seed``, ``mode``, ``unit`` and ``objective``.

        Requires pandas (``pip install 'archself[pandas]'``). The largest error per
        configuration: ``res.to_pandas().groupby("configuration", observed=True)["J"].max()``.
        """
        pd = _pandas("to_pandas")
        cols: dict[str, Any] = {}
        for name, arr in self.series.items():
            a = np.asarray(arr)
            if name == "configuration":
                cols[name] = self._configuration_names(pd, a)
            elif a.ndim == 2:
                for k, col in enumerate(component_columns(name, a.shape[1], self.meta)):
                    cols[col] = a[:, k]
            else:
                cols[name] = a
        df = pd.DataFrame(cols)
        df.attrs.update(self._attrs())
        return df

    def decisions_frame(self) -> Any:
        """The decision log as a tidy :class:`pandas.DataFrame`: one row per cycle and module.

        One row for every MAPE-K cycle and every module active in it: ``cycle``,
        ``t`` [s], ``configuration`` (name, categorical as in :meth:`to_pandas`),
        ``phase`` (``warmup`` or ``adapt``), ``module``, ``r`` (the module's residual
        r_i, Eq. 12), ``z`` (its influence z_i, Eq. 14) and ``candidate`` (True when
        the module was in the cycle's candidate set, Eq. 16). Empty (same columns)
        for a fixed run, which has no loop.

        Requires pandas (``pip install 'archself[pandas]'``).
        """
        pd = _pandas("decisions_frame")
        rows: list[tuple[Any, ...]] = []
        for d in self.decisions:
            zs = _field(d, "z") or {}
            rs = _field(d, "r") or {}
            cs = set(_field(d, "candidates") or ())
            head = (int(_field(d, "cycle") or 0), _float(_field(d, "t")),
                    str(_field(d, "configuration")), str(_field(d, "phase")))
            rows += [(*head, m, _float(rs.get(m)), _float(zs.get(m)), m in cs) for m in zs]
        cycle, t, conf, phase, module, r, z, cand = list(zip(*rows, strict=True)) or [()] * 8
        df = pd.DataFrame({
            "cycle": np.asarray(cycle, dtype=np.int64),
            "t": np.asarray(t, dtype=float),
            "configuration": self._configuration_names(pd, conf),
            "phase": pd.Series(phase, dtype=object).astype(str),
            "module": pd.Series(module, dtype=object).astype(str),
            "r": np.asarray(r, dtype=float),
            "z": np.asarray(z, dtype=float),
            "candidate": np.asarray(cand, dtype=bool),
        })
        df.attrs.update(self._attrs())
        return df

    def _configuration_names(self, pd: Any, values: Any) -> Any:
        """Configuration codes (int array) or names as a categorical over the file's names."""
        a = np.asarray(values)
        if a.dtype.kind in "iu":
            if self.configurations:
                return pd.Categorical.from_codes(a.astype(np.int64), categories=self.configurations)
            return a
        return pd.Categorical(a.tolist(), categories=self.configurations or None)

    def _attrs(self) -> dict[str, Any]:
        return {"scenario": self.scenario, "seed": self.seed, "mode": self.mode,
                "unit": self.unit, "objective": dict(self.meta.get("objective") or {})}

    def __repr__(self) -> str:
        """One line: what ran, the configurations it went through, the worst error.

        The series (thousands of samples) are left out: ``result.series``,
        :meth:`to_pandas`.
        """
        path = " → ".join([self.configuration, *(str(s.get("to")) for s in self.switches)])
        worst = self.metrics.get("max_error", math.nan)
        unit = f" {self.unit}" if self.unit else ""
        steps = len(self.series.get("t", ()))
        return (f"RunResult(scenario={self.scenario!r}, seed={self.seed}, mode={self.mode!r}, "
                f"steps={steps}, configurations={path!r}, max_error={worst:.4g}{unit})")

    def _repr_html_(self) -> str:
        """A small HTML summary for notebooks: the run, its configuration path, the metrics.

        Bounded: at most :data:`archself.io.html.MAX_ROWS` switches are listed.
        """
        from html import escape

        from archself.io.html import MAX_ROWS

        path = [self.configuration, *(str(s.get("to")) for s in self.switches)]
        if path[-1] != self.final_configuration:
            path.append(self.final_configuration)
        if len(path) > MAX_ROWS:
            path = [*path[:MAX_ROWS - 1], f"… ({len(path) - MAX_ROWS} more)", path[-1]]
        rows = "".join(
            f"<tr><td>{escape(label)}</td><td>{self.metrics.get(key, math.nan):.{dec}f}</td></tr>"
            for label, key, dec in metric_rows(self.unit)
        )
        switches = "".join(
            f"<li>t = {float(s.get('t_s', math.nan)):.1f} s: {escape(str(s.get('from')))} → "
            f"{escape(str(s.get('to')))} ({escape(str(s.get('action')))})</li>"
            for s in self.switches[:MAX_ROWS]
        ) + (f"<li>… ({len(self.switches) - MAX_ROWS} more)</li>"
             if len(self.switches) > MAX_ROWS else "")
        name = self.meta.get("architecture")
        head = (f"<b>{escape(str(name))}</b> · " if name else "") + (
            f"scenario <b>{escape(self.scenario)}</b> · seed {int(self.seed)} · "
            f"{escape(self.mode)}")
        return (
            "<div class=\"archself-run\">"
            f"<p>{head}<br>configurations: {escape(' → '.join(path))}</p>"
            f"<table><thead><tr><th>metric</th><th>value</th></tr></thead>"
            f"<tbody>{rows}</tbody></table>"
            + (f"<p>switches:</p><ul>{switches}</ul>" if switches else "")
            + "</div>"
        )

    def plot(self, *others: RunResult, size: str | tuple[float, float] | None = None,
             title: bool | str = False) -> Any:
        """The objective error J over time: a :class:`matplotlib.figure.Figure`.

        Switches and fault onsets are marked, the acceptable error drawn where the file
        declares one. Saved as PDF it embeds TrueType fonts (no Type 3); no title unless
        asked for. Needs matplotlib.

        Parameters
        ----------
        *others : RunResult
            Runs of the same scenario to draw beside this one (e.g. the fixed run).
        size : {"one", "two"} or (float, float), optional
            One column (3.5 in) or two (7.16 in) wide, or (width, height) in inches.
        title : bool or str
            True: ``Tracking error: <scenario>``; a string: that title.

        Examples
        --------
        >>> res.plot(fixed, size="one").savefig("error.pdf")  # doctest: +SKIP

        See :mod:`archself.reports.figures` for the trajectory and the influence channels.
        """
        from archself.sim.plot import plot_run

        return plot_run(*others, self, size=size, title=title)

    def write_trace(self, path: str | Path) -> None:
        """Write the trace to ``path``, atomically and deterministically.

        ``.parquet`` (or ``.pq``) writes Parquet (``pd.read_parquet(path)`` gives the
        columns of :meth:`to_pandas`; float32 series, the decision log in the schema
        metadata), any other suffix JSON (:meth:`trace`; NaN as ``null``, series rounded
        to 1e-6). The same seed gives a byte-identical file; :func:`archself.read_trace`
        reads either back. See :mod:`archself.io.trace`.

        Raises
        ------
        OutputError
            If the file cannot be written.
        """
        write_trace(self, path)

    @classmethod
    def from_trace(cls, parts: TraceParts) -> RunResult:
        """The run a trace holds (:func:`archself.io.trace.read_trace_parts`)."""
        meta, series, decisions = parts  # checked: a TraceMeta
        run: dict[str, Any] = {k: meta.get(k) for k in (*RunDoc.model_fields, "configurations")}
        return cls(**{**run, "metrics": {k: math.nan if v is None else float(v)
                                         for k, v in meta["metrics"].items()},
                      "switches": [dict(s) for s in run["switches"] or []],
                      "faults": [dict(f) for f in run["faults"] or []],  # absent: none
                      "configurations": list(run["configurations"] or [])},
                   series=series, decisions=decisions,
                   meta={k: v for k, v in meta.items() if k not in run})


def read_trace(path: str | Path) -> RunResult:
    """The :class:`RunResult` of a trace file (Parquet or JSON).

    Series come back as float arrays (NaN where the JSON has ``null``), the
    decision log as a list of dicts (what :func:`archself.explain` and
    :meth:`RunResult.decisions_frame` take).

    Raises
    ------
    TraceError
        ``PATH: error: not an archself trace (…)`` for any other file.
    """
    return RunResult.from_trace(read_trace_parts(path))


def trace_from_bytes(raw: bytes, name: str = "<trace>") -> RunResult:
    """:func:`read_trace` of a trace's bytes (stdin: ``archself explain -``)."""
    return RunResult.from_trace(trace_parts_from_bytes(raw, name))


def _pandas(method: str) -> Any:
    """pandas, or a one-line ImportError saying how to install it."""
    try:
        import pandas
    except ImportError:
        raise ImportError(
            f"RunResult.{method}() needs pandas: pip install 'archself[pandas]'"
        ) from None
    return pandas


def _field(d: Any, key: str) -> Any:
    """``d[key]`` of a decision dict (from a trace), or the attribute of a DecisionRecord."""
    return d.get(key) if isinstance(d, dict) else getattr(d, key, None)


def _float(x: Any) -> float:
    """``float(x)``, NaN for None."""
    return math.nan if x is None else float(x)


def _series_list(arr: np.ndarray) -> list:
    """A series as JSON lists: integers as is, floats rounded to 1e-6, NaN/inf as None."""
    a = np.asarray(arr)
    if a.dtype.kind in "iub":
        return a.tolist()
    a = np.round(a.astype(float), 6)
    finite = np.isfinite(a)
    if finite.all():
        return a.tolist()  # type: ignore[no-any-return]
    out = a.astype(object)  # Python floats, None where not finite
    out[~finite] = None
    return out.tolist()  # type: ignore[no-any-return]
