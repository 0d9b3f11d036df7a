"""The simulation driver: step a compiled system through a scenario and record it.

:func:`simulate` compiles the architecture in a configuration with the
scenario's faults, steps it for the scenario's duration at ``runtime.step_s``,
calls the adaptation loop (if any) every ``runtime.period_s``, and returns a
:class:`RunResult` with the recorded series and the metrics of the
``runtime.objective`` error J: ``max_error``, ``final_error``, ``rms_error`` (in the
objective's ``unit``) and ``peak_time_s``. What is recorded besides J, the objective's
signals and the residuals is the file's choice (``runtime.record``), not a role's.

Examples
--------
>>> from archself.loader import load_architecture
>>> from archself.resources import data_dir
>>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
>>> res = simulate(arch, "nominal", configuration="a1")
>>> res.metrics["max_error"] < 0.5, res.unit
(True, 'm')
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from archself.compiler import compile_system
from archself.errors import SimulationError
from archself.jsondata import jsonable
from archself.model import Architecture
from archself.objective import objective_norm

__all__ = ["METRICS", "METRE_ALIASES", "RunResult", "simulate", "error_metrics"]

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


@dataclasses.dataclass
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

    def to_dict(self) -> dict[str, Any]:
        """Summary as plain data (one of the ``runs`` of ``archself simulate --json``)."""
        return {
            "scenario": self.scenario,
            "seed": self.seed,
            "mode": self.mode,
            "configuration": self.configuration,
            "final_configuration": self.final_configuration,
            "unit": self.unit,
            "metrics": {k: jsonable(v) for k, v in self.metrics.items()},
            "switches": jsonable(self.switches),
        }

    def trace(self) -> dict[str, Any]:
        """The trace document ``{meta, series, decisions}`` as plain JSON data."""
        series = {name: _series_list(arr) for name, arr in self.series.items()}
        return {"meta": self.trace_meta(), "series": series,
                "decisions": jsonable(self.trace_decisions())}

    def trace_meta(self) -> dict[str, Any]:
        """The trace's ``meta``: :attr:`meta`, :meth:`to_dict` and the configuration names."""
        return {**self.meta, **self.to_dict(), "configurations": list(self.configurations)}

    def trace_decisions(self) -> list[Any]:
        """The decision log as plain data (dicts), as the trace stores it."""
        return [_decision(d) for d in self.decisions]

    # ------------------------------------------------------------------ notebooks
    def to_pandas(self) -> Any:
        """The recorded series as a tidy :class:`pandas.DataFrame`, one row per step.

        Columns, in the order of :attr:`series`: ``t`` [s], ``J`` (the objective
        error, in :attr:`unit`), then every other series; a 2-D series (a vector
        signal) becomes one column per component, ``<name>_<k>``: ``reference_0`` …,
        ``actual_0`` … (the objective compares ``runtime.objective.components`` of
        them), ``estimate_0`` …; ``residual.<module>`` (NaN while inactive) and
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
                for k in range(a.shape[1]):
                    cols[f"{name}_{k}"] = a[:, k]
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
        cycle: list[int] = []
        t: list[float] = []
        conf: list[str] = []
        phase: list[str] = []
        module: list[str] = []
        r: list[float] = []
        z: list[float] = []
        cand: list[bool] = []
        for d in self.decisions:
            zs = _field(d, "z") or {}
            rs = _field(d, "r") or {}
            cs = set(_field(d, "candidates") or ())
            names = list(zs)
            n = len(names)
            cycle += [int(_field(d, "cycle") or 0)] * n
            t += [_float(_field(d, "t"))] * n
            conf += [str(_field(d, "configuration"))] * n
            phase += [str(_field(d, "phase"))] * n
            module += names
            z += [_float(zs.get(m)) for m in names]
            r += [_float(rs.get(m)) for m in names]
            cand += [m in cs for m in names]
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

    def _repr_html_(self) -> str:
        """A small HTML summary for notebooks: the run, its configuration path, the metrics."""
        from html import escape

        path = [self.configuration, *(str(s.get("to")) for s in self.switches)]
        if path[-1] != self.final_configuration:
            path.append(self.final_configuration)
        rows = "".join(
            f"<tr><td>{escape(label)}</td><td>{self.metrics.get(key, math.nan):.{dec}f}</td></tr>"
            for label, key, dec in metric_rows(self.unit)
        )
        switches = "".join(
            f"<li>t = {float(s.get('t_s', math.nan)):.1f} s: {escape(str(s.get('from')))} → "
            f"{escape(str(s.get('to')))} ({escape(str(s.get('action')))})</li>"
            for s in self.switches
        )
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

    def write_trace(self, path: str | Path) -> None:
        """Write the trace to ``path``, atomically and deterministically.

        ``.parquet`` (or ``.pq``) writes Parquet (``pd.read_parquet(path)`` gives the
        columns of :meth:`to_pandas`; float32 series, the decision log in the schema
        metadata), any other suffix JSON (:meth:`trace`; NaN as ``null``, series rounded
        to 1e-6). The same seed gives a byte-identical file; :func:`archself.read_trace`
        reads either back. See :mod:`archself.sim.trace`.

        Raises
        ------
        OutputError
            If the file cannot be written.
        """
        from archself.sim.trace import write_trace

        write_trace(self, path)


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
    return math.nan if x is None else float(x)


def _series_list(arr: np.ndarray) -> list:
    a = np.asarray(arr)
    if a.dtype.kind in "iub":
        return a.tolist()
    a = np.round(a.astype(float), 6)
    if a.ndim == 1:
        return [None if v != v or v in (math.inf, -math.inf) else v for v in a.tolist()]
    return [
        [None if v != v or v in (math.inf, -math.inf) else v for v in row] for row in a.tolist()
    ]


def _decision(d: Any) -> Any:
    if hasattr(d, "to_dict"):
        return d.to_dict()
    if dataclasses.is_dataclass(d) and not isinstance(d, type):
        return dataclasses.asdict(d)
    return d


def _report_context(arch: Architecture, sc: Any) -> dict[str, Any]:
    """What a run report needs of the file beyond the run (``archself report --trace``)."""
    rt = arch.runtime
    h = rt.hysteresis
    return {
        "scenario_description": sc.description or "",
        "faults": [f.model_dump(exclude_none=True) for f in sc.faults],
        "acceptable": float(rt.objective.acceptable),
        "threshold": None if rt.threshold is None else float(rt.threshold),
        "top_k": rt.top_k,
        "hysteresis": None if h is None else {"on": float(h.on), "off": float(h.off)},
        "warmup_s": float(rt.warmup_time_s),
        "min_confidence": float(rt.min_confidence),
    }


def _publisher(system: Any, signal: str) -> str | None:
    """The first active module (file order) whose type publishes ``signal``."""
    for name, mod in system.modules.items():
        if signal in mod.outputs:
            return name
    return None


def simulate(
    arch: Architecture | str | Path,
    scenario: str,
    *,
    configuration: str | None = None,
    seed: int | None = None,
    adapt: Callable[[Any], list[dict[str, Any]] | None] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RunResult:
    """Simulate ``scenario`` on ``arch``, fixed or with an adaptation loop.

    Parameters
    ----------
    arch : Architecture or path
        The architecture (a path is loaded with :func:`archself.loader.load_architecture`).
    scenario : str
        Name of a scenario of the file.
    configuration : str, optional
        Configuration to start in (default: the file's initial one).
    seed : int, optional
        Seed of every random stream (default: the scenario's ``seed``).
    adapt : callable, optional
        ``adapt(system) -> list of switch dicts`` called every
        ``runtime.period_s`` (the MAPE-K loop); None runs the architecture fixed.
        If it has a ``decisions`` list attribute, that log goes into the trace.
    progress : callable, optional
        ``progress(done_steps, total_steps)``, called about 100 times.

    Returns
    -------
    RunResult

    Raises
    ------
    SimulationError
        Unknown scenario.
    CompileError
        The configuration cannot be built.
    """
    if not isinstance(arch, Architecture):
        from archself.loader import load_architecture

        arch = load_architecture(arch).arch
    assert isinstance(arch, Architecture)
    sc = arch.scenarios.get(scenario)
    if sc is None:
        known = ", ".join(arch.scenarios) or "none"
        raise SimulationError(f"unknown scenario {scenario!r}; known: {known}")
    seed = sc.seed if seed is None else int(seed)
    start = configuration or arch.initial_configuration()
    system = compile_system(arch, start, seed=seed, scenario=sc)
    rt = arch.runtime
    dt = float(rt.step_s)
    n = int(round(sc.duration_s / dt))
    per = max(1, int(round(rt.period_s / dt)))
    every = max(1, n // 100)

    confs = list(arch.configurations)
    conf_index = {c: i for i, c in enumerate(confs)}
    act_mod, act_sig = rt.objective.actual.rsplit(".", 1)
    ref_mod, ref_sig = rt.objective.reference.rsplit(".", 1)
    comps = list(rt.objective.components)
    record = list(rt.record.items())  # (series, signal)
    res_mods = [(m, spec.residual.signal) for m, spec in arch.modules.items() if spec.residual]

    t_arr = np.empty(n)
    J = np.full(n, np.nan)
    conf_arr = np.zeros(n, dtype=int)
    res = np.full((n, len(res_mods)), np.nan)
    cols: dict[str, np.ndarray] = {}
    widths: dict[str, int] = {}

    def put(key: str, i: int, val: Any) -> None:
        if val is None:
            return
        arr = cols.get(key)
        if arr is None:
            w = int(np.size(val))
            widths[key] = w
            arr = cols[key] = np.full((n, w), np.nan)
        if type(val) is np.ndarray and val.ndim == 1 and val.dtype.kind == "f":
            if val.shape[0] == widths[key]:  # the common case: a float vector
                arr[i] = val
            return
        v = np.asarray(val, dtype=float).ravel()
        if v.size == widths[key]:
            arr[i] = v

    switches: list[dict[str, Any]] = []
    sources: list[tuple[str, str, str]] = []  # (series, module, signal) of the configuration
    cur_conf = None
    conf_from: list[tuple[int, int]] = []  # (step, configuration index) at every change
    res_rows: list[list[float]] = []
    nan_row = [math.nan] * len(res_mods)
    outputs = system.outputs
    for i in range(n):
        system.step()
        if system.configuration != cur_conf:
            cur_conf = system.configuration
            conf_from.append((i, conf_index.get(cur_conf, -1)))
            sources = [(key, src, sig) for key, sig in record
                       if (src := _publisher(system, sig)) is not None]
            active = system.active
            modules = system.modules
            res_idx = [(j, modules[m], s) for j, (m, s) in enumerate(res_mods) if m in active]
        t_arr[i] = system.t
        a = outputs.get(act_mod, {}).get(act_sig)
        r = outputs.get(ref_mod, {}).get(ref_sig)
        J[i] = objective_norm(a, r, comps)
        put("reference", i, r)
        put("actual", i, a)
        for key, src, sig in sources:
            put(key, i, outputs.get(src, {}).get(sig))
        row = nan_row.copy()
        for j, mod, s in res_idx:
            sigs = getattr(mod, "signals", None)
            v = sigs.get(s) if sigs is not None else None
            if v is None:
                v = mod.local_signals().get(s, math.nan)
            row[j] = v
        res_rows.append(row)
        if adapt is not None and (i + 1) % per == 0:
            out = adapt(system)
            if out:
                switches.extend(dict(s) for s in out)
        if progress is not None and ((i + 1) % every == 0 or i + 1 == n):
            progress(i + 1, n)

    for k, (first, index) in enumerate(conf_from):
        conf_arr[first : conf_from[k + 1][0] if k + 1 < len(conf_from) else n] = index
    if res_rows and res_mods:
        res[:] = np.array(res_rows, dtype=float)
    series: dict[str, np.ndarray] = {"t": t_arr, "J": J}
    for key in ("reference", "actual", *(k for k, _ in record)):
        if key in cols:
            arr = cols[key]
            series[key] = arr[:, 0] if arr.shape[1] == 1 else arr
    series["configuration"] = conf_arr
    for j, (m, _s) in enumerate(res_mods):
        series[f"residual.{m}"] = res[:, j]
    decisions = list(getattr(adapt, "decisions", []) or []) if adapt is not None else []
    meta = {
        "architecture": arch.name,
        "step_s": dt,
        "period_s": float(rt.period_s),
        "duration_s": float(sc.duration_s),
        "objective": {
            "actual": rt.objective.actual,
            "reference": rt.objective.reference,
            "components": comps,
            "unit": rt.objective.unit,
        },
        "residuals": {m: s for m, s in res_mods},
        "report": _report_context(arch, sc),
    }
    return RunResult(
        scenario=scenario,
        seed=seed,
        mode="fixed" if adapt is None else "adaptive",
        configuration=start,
        final_configuration=system.configuration,
        metrics=error_metrics(t_arr, J, rt.objective.unit),
        switches=switches,
        series=series,
        decisions=decisions,
        meta=meta,
        configurations=confs,
        unit=rt.objective.unit,
    )
