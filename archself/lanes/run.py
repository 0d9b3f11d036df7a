"""N runs of one scenario as one lane-batched simulation, fixed or adaptive.

:func:`simulate_lanes` is :func:`archself.sim.run.simulate` for many seeds (and
sweep points) at once: it compiles one per-run system per lane, steps them
together in a :class:`~archself.lanes.system.LaneSystem`, records the same series
and returns the same :class:`~archself.sim.result.RunResult` per lane. With
``adapt=True`` every lane has its own MAPE-K loop, called every ``runtime.period_s``
with the lane's :class:`~archself.lanes.view.LaneView`: the same decisions, the same
switches, the lane moving between configuration groups.

Examples
--------
>>> from archself.model.loader import load_architecture
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
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from archself.errors import SimulationError
from archself.lanes.module import ALL
from archself.lanes.system import LaneSystem
from archself.model.architecture import Architecture
from archself.sim.metrics import error_metrics
from archself.sim.result import RunResult
from archself.system.compiler import compile_system

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
    adapt: bool | Callable[[Architecture], Any] = False,
) -> list[RunResult]:
    """Simulate ``scenario`` for every seed as lanes, fixed or with a MAPE-K loop per lane.

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
        The configuration to start in (default: the file's initial one).
    adapt : bool or callable
        True: run each lane with its own :class:`~archself.runtime.MapeK` (the
        ``adapt=MapeK(arch)`` of :func:`~archself.sim.run.simulate`); a callable:
        ``adapt(arch)`` makes each lane's loop (any ``adapt`` object of
        ``simulate``: called every ``runtime.period_s`` with the lane's
        :class:`~archself.lanes.view.LaneView`; its ``updates`` and ``decisions``
        lists, if it has them, are read as MapeK's).

    Returns
    -------
    list of RunResult
        One per lane, in order: what :func:`archself.sim.run.simulate` gives for
        that architecture and seed (errors within 1e-9, the same switches and
        decision log).

    Raises
    ------
    SimulationError
        Unknown scenario, lanes of different structure or duration.
    CompileError
        The configuration cannot be built.
    """
    from archself.sim.run import run_meta

    archs = [arch] * len(seeds) if isinstance(arch, Architecture) else list(arch)
    if len(archs) != len(seeds) or not len(seeds):
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
    N = lanes.n
    rt = first.runtime
    dt = float(rt.step_s)
    n = int(round(sc.duration_s / dt))
    per = max(1, int(round(rt.period_s / dt)))
    act_mod, act_sig = rt.objective.actual.rsplit(".", 1)
    ref_mod, ref_sig = rt.objective.reference.rsplit(".", 1)
    comps = list(rt.objective.components)
    record = list(rt.record.items())
    res_mods = [(m, spec.residual.signal) for m, spec in first.modules.items() if spec.residual]
    conf_index = {c: k for k, c in enumerate(first.configurations)}
    loops = views = monitors = None
    if adapt:
        from archself.lanes.monitor import observe_group
        from archself.lanes.view import LaneView
        from archself.runtime.mapek import MapeK
        from archself.runtime.monitor import Monitor

        make = MapeK if adapt is True else adapt
        loops = [make(a) for a in archs]
        views = [LaneView(lanes, i) for i in range(N)]
        # loops observing with the runtime's Monitor take the lanes' bulk Monitor stage
        if all(isinstance(getattr(lp, "monitor", None), Monitor) for lp in loops):
            monitors = [lp.monitor for lp in loops]
    switches: list[list[dict[str, Any]]] = [[] for _ in range(N)]

    per_conf: dict[str, tuple[list, list]] = {}

    def layout(conf: str) -> tuple[list, list]:
        """The recorded sources and residual modules of ``conf`` (per-run: on a change)."""
        got = per_conf.get(conf)
        if got is None:
            plan = lanes.plan(conf)
            pool = lanes.systems[0]
            srcs = []
            for key, sig in record:
                src = next((m for m in plan.active if sig in pool._module(m).outputs), None)
                if src is not None:
                    srcs.append((key, src, sig))
            res = [(j, m, s) for j, (m, s) in enumerate(res_mods) if m in plan.active_set]
            got = per_conf[conf] = (srcs, res)
        return got

    t_arr = np.empty(n)
    J = np.empty((n, N))
    res = np.full((n, N, len(res_mods)), math.nan)
    conf_arr = np.zeros((n, N), dtype=int)
    cols: dict[str, np.ndarray] = {}

    def put(key: str, i: int, val: Any, idx: Any) -> None:
        if val is None or type(val) is list:
            return
        arr = cols.get(key)
        if arr is None:
            w = 1 if val.ndim == 1 else val.shape[1]
            arr = cols[key] = np.full((n, N, w), math.nan)
        arr[i, idx] = (val if val.ndim == 2 else val[:, None])[idx]

    signal = lanes.signal
    for i in range(n):
        lanes.step()
        t_arr[i] = lanes.t
        a = signal(act_mod, act_sig)
        r = signal(ref_mod, ref_sig)
        J[i] = _norms(a, r, comps, N)
        put("reference", i, r, ALL)
        put("actual", i, a, ALL)
        for conf, idx in lanes.groups.items():
            sel = ALL if len(idx) == N else idx
            conf_arr[i, sel] = conf_index.get(conf, -1)
            srcs, res_idx = layout(conf)
            for key, src, sig in srcs:
                put(key, i, signal(src, sig), sel)
            for j, m, s in res_idx:
                v = lanes.signal_arrays(m).get(s)
                if v is not None:
                    res[i, sel, j] = v[sel]
        if loops is not None and views is not None and (i + 1) % per == 0:
            lanes.objective = J[i]
            observed: dict[int, Any] = {}
            if monitors is not None:
                for idx in lanes.groups.values():
                    observed.update(observe_group(monitors, lanes, idx, J[i]))
            for lane in range(N):
                obs = observed.get(lane)
                view = views[lane]
                out = loops[lane](view) if obs is None else loops[lane](view, observation=obs)
                view.done(len(getattr(loops[lane], "updates", ())))
                if out:
                    switches[lane].extend(dict(s) for s in out)

    results = []
    for lane, (a, seed) in enumerate(zip(archs, seeds, strict=True)):
        series: dict[str, np.ndarray] = {"t": t_arr.copy(), "J": J[:, lane].copy()}
        for key in ("reference", "actual", *(k for k, _ in record)):
            if key in cols:
                arr = cols[key][:, lane]
                series[key] = arr[:, 0].copy() if arr.shape[1] == 1 else arr.copy()
        series["configuration"] = conf_arr[:, lane].copy()
        for j, (m, _s) in enumerate(res_mods):
            series[f"residual.{m}"] = res[:, lane, j].copy()
        results.append(
            RunResult(
                scenario=scenario,
                seed=int(seed),
                mode="adaptive" if adapt else "fixed",
                configuration=start,
                final_configuration=lanes.configuration[lane],
                metrics=error_metrics(t_arr, J[:, lane], a.runtime.objective.unit),
                switches=switches[lane],
                series=series,
                decisions=list(getattr(loops[lane], "decisions", None) or [])
                if loops is not None else [],
                meta=run_meta(a, a.scenarios[scenario], dt, comps, res_mods),
                configurations=list(a.configurations),
                unit=a.runtime.objective.unit,
            )
        )
    return results
