"""N fixed runs of one scenario as one lane-batched simulation.

:func:`simulate_lanes` is :func:`archself.sim.run.simulate` for many seeds (and
sweep points) at once: it compiles one per-run system per lane, steps them
together in a :class:`~archself.lanes.system.LaneSystem`, records the same series
and returns the same :class:`~archself.sim.result.RunResult` per lane.

Examples
--------
>>> from archself.loader import load_architecture
>>> from archself.resources import data_dir
>>> from archself.sim.run import simulate
>>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
>>> lanes = simulate_lanes(arch, "nominal", [1, 2], configuration="a1")
>>> one = simulate(arch, "nominal", seed=2, configuration="a1")
>>> abs(lanes[1].metrics["max_error"] - one.metrics["max_error"]) < 1e-9
True
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from archself.compiler import compile_system
from archself.errors import SimulationError
from archself.lanes.module import ALL
from archself.lanes.system import LaneSystem
from archself.model import Architecture
from archself.sim.metrics import error_metrics
from archself.sim.result import RunResult

__all__ = ["simulate_lanes"]


def _norms(actual: Any, reference: Any, comps: list[int], n: int) -> np.ndarray:
    """J per lane: ``sqrt(Σ d²)`` in component order, as :func:`objective_norm` sums it."""
    if actual is None or reference is None or type(actual) is list or type(reference) is list:
        return np.full(n, math.nan)
    a = actual if actual.ndim == 2 else actual[:, None]
    r = reference if reference.ndim == 2 else reference[:, None]
    s2 = np.zeros(n)
    for c in comps:
        if not (-a.shape[1] <= c < a.shape[1] and -r.shape[1] <= c < r.shape[1]):
            return np.full(n, math.nan)
        d = a[:, c] - r[:, c]
        s2 = s2 + d * d
    return np.sqrt(s2)


def simulate_lanes(
    arch: Architecture | Sequence[Architecture],
    scenario: str,
    seeds: Sequence[int],
    *,
    configuration: str | None = None,
) -> list[RunResult]:
    """Simulate ``scenario`` fixed in ``configuration`` for every seed, as lanes.

    Parameters
    ----------
    arch : Architecture or sequence of Architecture
        The architecture, or one per lane (sweep points: the same structure, other
        values).
    scenario : str
        A scenario every architecture has.
    seeds : sequence of int
        One seed per lane.
    configuration : str, optional
        The configuration (default: the file's initial one).

    Returns
    -------
    list of RunResult
        One per lane, in order: what :func:`archself.sim.run.simulate` gives for
        that architecture and seed (errors within 1e-9).

    Raises
    ------
    SimulationError
        Unknown scenario, lanes of different structure or duration.
    CompileError
        The configuration cannot be built.
    """
    from archself.sim.run import _publisher, _report_context

    archs = [arch] * len(seeds) if isinstance(arch, Architecture) else list(arch)
    if len(archs) != len(seeds) or not seeds:
        raise SimulationError("simulate_lanes needs one seed per lane (and one architecture)")
    first = archs[0]
    sc = first.scenarios.get(scenario)
    if sc is None:
        known = ", ".join(first.scenarios) or "none"
        raise SimulationError(f"unknown scenario {scenario!r}; known: {known}")
    start = configuration or first.initial_configuration()
    systems = []
    for a, seed in zip(archs, seeds, strict=True):
        s = a.scenarios.get(scenario)
        if s is None or s.duration_s != sc.duration_s:
            raise SimulationError(f"lanes must share scenario {scenario!r} and its duration")
        systems.append(compile_system(a, start, seed=int(seed), scenario=s))
    lanes = LaneSystem(systems)
    n_lanes = lanes.n
    rt = first.runtime
    dt = float(rt.step_s)
    n = int(round(sc.duration_s / dt))
    act_mod, act_sig = rt.objective.actual.rsplit(".", 1)
    ref_mod, ref_sig = rt.objective.reference.rsplit(".", 1)
    comps = list(rt.objective.components)
    record = list(rt.record.items())
    res_mods = [(m, spec.residual.signal) for m, spec in first.modules.items() if spec.residual]
    sources = [
        (key, src, sig) for key, sig in record
        if (src := _publisher(systems[0], sig)) is not None
    ]
    active = lanes.plan(start).active_set

    t_arr = np.empty(n)
    J = np.empty((n, n_lanes))
    res = np.full((n, n_lanes, len(res_mods)), math.nan)
    cols: dict[str, np.ndarray] = {}

    def put(key: str, i: int, val: Any) -> None:
        if val is None or type(val) is list:
            return
        arr = cols.get(key)
        if arr is None:
            w = 1 if val.ndim == 1 else val.shape[1]
            arr = cols[key] = np.full((n, n_lanes, w), math.nan)
        arr[i] = val if val.ndim == 2 else val[:, None]

    signal = lanes.signal
    res_idx = [(j, lanes.module(m), s) for j, (m, s) in enumerate(res_mods) if m in active]
    for i in range(n):
        lanes.step()
        t_arr[i] = lanes.t
        a = signal(act_mod, act_sig)
        r = signal(ref_mod, ref_sig)
        J[i] = _norms(a, r, comps, n_lanes)
        put("reference", i, r)
        put("actual", i, a)
        for key, src, sig in sources:
            put(key, i, signal(src, sig))
        for j, mod, s in res_idx:
            v = mod.local_signals(ALL).get(s)
            if v is not None:
                res[i, :, j] = v

    conf_index = list(first.configurations).index(start)
    results = []
    for lane, (a, seed) in enumerate(zip(archs, seeds, strict=True)):
        series: dict[str, np.ndarray] = {"t": t_arr.copy(), "J": J[:, lane].copy()}
        for key in ("reference", "actual", *(k for k, _ in record)):
            if key in cols:
                arr = cols[key][:, lane]
                series[key] = arr[:, 0].copy() if arr.shape[1] == 1 else arr.copy()
        series["configuration"] = np.full(n, conf_index, dtype=int)
        for j, (m, _s) in enumerate(res_mods):
            series[f"residual.{m}"] = res[:, lane, j].copy()
        s = a.scenarios[scenario]
        meta = {
            "architecture": a.name,
            "step_s": dt,
            "period_s": float(a.runtime.period_s),
            "duration_s": float(s.duration_s),
            "objective": {
                "actual": a.runtime.objective.actual,
                "reference": a.runtime.objective.reference,
                "components": comps,
                "unit": a.runtime.objective.unit,
            },
            "residuals": {m: sig for m, sig in res_mods},
            "report": _report_context(a, s),
        }
        results.append(
            RunResult(
                scenario=scenario,
                seed=int(seed),
                mode="fixed",
                configuration=start,
                final_configuration=start,
                metrics=error_metrics(t_arr, J[:, lane], a.runtime.objective.unit),
                switches=[],
                series=series,
                decisions=[],
                meta=meta,
                configurations=list(a.configurations),
                unit=a.runtime.objective.unit,
            )
        )
    return results
