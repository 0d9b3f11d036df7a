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
>>> from archself.model.loader import load_architecture
>>> from archself.resources import data_dir
>>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
>>> res = simulate(arch, "nominal", configuration="a1")
>>> res.metrics["max_error"] < 0.5, res.unit
(True, 'm')

The metrics are in :mod:`archself.sim.metrics` and :class:`RunResult` in
:mod:`archself.sim.result`; both are re-exported here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from archself.errors import SimulationError
from archself.model.architecture import Architecture
from archself.sim.metrics import METRE_ALIASES, METRICS, error_metrics, metric_rows
from archself.sim.result import RunResult
from archself.system.compiler import compile_system
from archself.system.objective import objective_norm

__all__ = ["METRICS", "METRE_ALIASES", "RunResult", "simulate", "error_metrics", "metric_rows"]


def run_meta(
    arch: Architecture, sc: Any, dt: float, comps: Any, res_mods: list[tuple[str, str]]
) -> dict[str, Any]:
    """A run's ``meta``: the file's clock and objective, the residual signals recorded
    and :func:`_report_context` (shared by :func:`simulate` and the lane batches)."""
    rt = arch.runtime
    return {
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
        "residuals": dict(res_mods),
        "report": _report_context(arch, sc),
    }


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
        The architecture (a path is loaded with :func:`archself.model.loader.load_architecture`).
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
        from archself.model.loader import load_architecture

        arch = load_architecture(arch).arch
    assert isinstance(arch, Architecture)
    if seed is not None and (not isinstance(seed, int | np.integer) or isinstance(seed, bool)
                             or seed < 0):
        raise SimulationError(f"seed: expected an integer ≥ 0 or None, got {seed!r}")
    for name, fn in (("adapt", adapt), ("progress", progress)):
        if fn is not None and not callable(fn):
            raise SimulationError(f"{name}: expected a callable or None"
                                  + (" (adapt=MapeK(arch))" if name == "adapt" else "")
                                  + f", got {type(fn).__name__}")
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
    res = np.array(res_rows, dtype=float).reshape(n, len(res_mods))
    series: dict[str, np.ndarray] = {"t": t_arr, "J": J}
    for key in ("reference", "actual", *(k for k, _ in record)):
        if key in cols:
            arr = cols[key]
            series[key] = arr[:, 0] if arr.shape[1] == 1 else arr
    series["configuration"] = conf_arr
    for j, (m, _s) in enumerate(res_mods):
        series[f"residual.{m}"] = res[:, j]
    decisions = list(getattr(adapt, "decisions", None) or [])
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
        meta=run_meta(arch, sc, dt, comps, res_mods),
        configurations=confs,
        unit=rt.objective.unit,
    )
