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

The metrics and :class:`RunResult` are in :mod:`archself.sim.result`; both are
re-exported here.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from archself.errors import SimulationError, unknown
from archself.model.architecture import Architecture, split_ref
from archself.model.loader import load_architecture
from archself.registry import lookup
from archself.sim.result import METRE_ALIASES, METRICS, RunResult, error_metrics, metric_rows
from archself.system.live import compile_system, objective_norm

__all__ = [
    "METRICS", "METRE_ALIASES", "Recording", "RunResult", "simulate", "error_metrics",
    "metric_rows", "series_names",
]


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
        "elements": _elements(arch),
        "report": _report_context(arch, sc),
    }


def _elements(arch: Architecture) -> dict[str, list[str]]:
    """The element names of the vector series whose publishing type declares them
    (``output_elements``): ``reference``, ``actual`` and each ``runtime.record`` series.

    The objective names its module (``chassis.pose``); a recorded signal is the first
    module's (file order) whose type publishes it with names.
    """

    rt = arch.runtime
    types = {m: lookup(spec.type) for m, spec in arch.modules.items()}
    out: dict[str, list[str]] = {}
    for key, ref in (("reference", rt.objective.reference), ("actual", rt.objective.actual)):
        mod, sig = split_ref(ref, arch.modules)
        names = getattr(types.get(mod), "output_elements", {}).get(sig or "")
        if names:
            out[key] = list(names)
    for key, sig in rt.record.items():
        names = next((cls.output_elements[sig] for cls in types.values()
                      if cls is not None and sig in cls.output_elements), None)
        if names:
            out[key] = list(names)
    return out


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


@dataclass
class Recording:
    """The series of ``width`` runs of one scenario stepped together, one row a step.

    The one recorder of :func:`simulate` (``width`` 1) and of the lane batches
    (:func:`archself.lanes.simulate_lanes`): the driver fills ``t``, ``J``,
    ``conf`` (the configuration's index per run), ``res`` (the residual signals)
    and, with :meth:`put` or :meth:`put_lanes`, the objective's signals and the
    file's ``runtime.record`` series; :meth:`result` makes a run's
    :class:`RunResult`.

    Attributes
    ----------
    scenario : str
    n : int
        Steps of the scenario.
    dt : float
        ``runtime.step_s``.
    comps : list of int
        The objective's components.
    record : list of (str, str)
        ``runtime.record``: (series, signal).
    res_mods : list of (str, str)
        The modules with a residual block and their residual signal.
    conf_index : dict of str to int
        A configuration's index in the file.
    t : ndarray, shape (n,)
    J, conf : ndarray, shape (n, width)
    res : ndarray, shape (n, width, len(res_mods))
    cols : dict of str to ndarray, shape (n, width, w)
    """

    scenario: str
    n: int
    dt: float
    comps: list[int]
    record: list[tuple[str, str]]
    res_mods: list[tuple[str, str]]
    conf_index: dict[str, int]
    t: np.ndarray
    J: np.ndarray
    conf: np.ndarray
    res: np.ndarray
    cols: dict[str, np.ndarray] = field(default_factory=dict)
    keep: frozenset[str] | None = None

    @classmethod
    def of(
        cls, arch: Architecture, scenario: str, width: int, keep: Collection[str] | None = None
    ) -> Recording:
        """Empty series of ``width`` runs of ``scenario`` (a scenario of ``arch``).

        ``keep``: the series to record besides ``t``, ``J`` and ``configuration``
        (:func:`series_names`); None: every one.
        """
        rt = arch.runtime
        dt = float(rt.step_s)
        n = int(round(arch.scenarios[scenario].duration_s / dt))
        wanted = None if keep is None else frozenset(keep)
        res_mods = [(m, spec.residual.signal) for m, spec in arch.modules.items()
                    if spec.residual and (wanted is None or f"residual.{m}" in wanted)]
        record = [(k, sig) for k, sig in rt.record.items() if wanted is None or k in wanted]
        return cls(
            scenario, n, dt, list(rt.objective.components), record, res_mods,
            {c: k for k, c in enumerate(arch.configurations)}, np.empty(n),
            np.full((n, width), np.nan), np.zeros((n, width), dtype=int),
            np.full((n, width, len(res_mods)), np.nan), keep=wanted,
        )

    def wants(self, key: str) -> bool:
        """Whether series ``key`` is recorded."""
        return self.keep is None or key in self.keep

    def put(self, key: str, i: int, val: Any) -> None:
        """One run's value of series ``key`` at step ``i``: any number or vector, its width
        that of the first value (a value of another width is left out, NaN)."""
        if val is None:
            return
        arr = self.cols.get(key)
        if arr is None:
            arr = self.cols[key] = np.full((self.n, 1, int(np.size(val))), np.nan)
        if type(val) is np.ndarray and val.ndim == 1 and val.dtype.kind == "f":
            if val.shape[0] == arr.shape[2]:  # the common case: a float vector
                arr[i, 0] = val
            return
        v = np.asarray(val, dtype=float).ravel()
        if v.size == arr.shape[2]:
            arr[i, 0] = v

    def put_lanes(self, key: str, i: int, val: Any, idx: Any) -> None:
        """The lanes ``idx`` of series ``key`` at step ``i`` from a lane array ``val``
        (shape (width,) or (width, w); None or a list of per-lane values: left out)."""
        if val is None or type(val) is list:
            return
        arr = self.cols.get(key)
        if arr is None:
            w = 1 if val.ndim == 1 else val.shape[1]
            arr = self.cols[key] = np.full((self.n, self.J.shape[1], w), np.nan)
        arr[i, idx] = (val if val.ndim == 2 else val[:, None])[idx]

    def series(self, lane: int) -> dict[str, np.ndarray]:
        """Run ``lane``'s series, as :attr:`RunResult.series` holds them (copies)."""
        series: dict[str, np.ndarray] = {"t": self.t.copy(), "J": self.J[:, lane].copy()}
        for key in ("reference", "actual", *(k for k, _ in self.record)):
            if key in self.cols:
                arr = self.cols[key][:, lane]
                series[key] = arr[:, 0].copy() if arr.shape[1] == 1 else arr.copy()
        series["configuration"] = self.conf[:, lane].copy()
        for j, (m, _s) in enumerate(self.res_mods):
            series[f"residual.{m}"] = self.res[:, lane, j].copy()
        return series

    def result(
        self, lane: int, arch: Architecture, seed: int, mode: str, start: str, final: str,
        switches: list[dict[str, Any]], decisions: list[Any],
    ) -> RunResult:
        """Run ``lane`` of ``arch`` (its file: the meta, the unit) as a :class:`RunResult`."""
        unit = arch.runtime.objective.unit
        return RunResult(
            scenario=self.scenario,
            seed=int(seed),
            mode=mode,
            configuration=start,
            final_configuration=final,
            metrics=error_metrics(self.t, self.J[:, lane], unit),
            switches=switches,
            series=self.series(lane),
            decisions=decisions,
            meta=run_meta(arch, arch.scenarios[self.scenario], self.dt, self.comps, self.res_mods),
            configurations=list(arch.configurations),
            unit=unit,
        )


@dataclass
class _Run:
    """What :func:`simulate` plans: the file, the compiled system, the seed, the series."""

    arch: Architecture
    seed: int
    start: str
    system: Any
    rec: Recording


def _plan(
    arch: Architecture | str | Path, scenario: str, configuration: str | None, seed: int | None,
    adapt: Any, progress: Any, keep: Collection[str] | None = None,
) -> _Run:
    """Check the arguments, load the file if a path, compile the start configuration.

    Raises
    ------
    SimulationError, CompileError, LoadError
        As :func:`simulate`.
    """
    if not isinstance(arch, Architecture):
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
        raise SimulationError(unknown("scenario", scenario, arch.scenarios))
    if keep is not None:
        names = series_names(arch)
        keep = [keep] if isinstance(keep, str) else list(keep)
        for key in keep:
            if key not in names:
                raise SimulationError(unknown("series", key, names))
    seed = sc.seed if seed is None else int(seed)
    start = configuration or arch.initial_configuration()
    system = compile_system(arch, start, seed=seed, scenario=sc)
    return _Run(arch, seed, start, system, Recording.of(arch, scenario, 1, keep))


def series_names(arch: Architecture) -> list[str]:
    """The series a run can record besides ``t``, ``J`` and ``configuration``: the
    objective's ``reference`` and ``actual``, each ``runtime.record`` series and
    ``residual.<module>`` of each module with a residual block (``simulate(keep=…)``)."""
    return ["reference", "actual", *arch.runtime.record,
            *(f"residual.{m}" for m, spec in arch.modules.items() if spec.residual)]


def _columns(rec: Recording, values: list[tuple[str, Any, str]]) -> list[Any]:
    """The recorded vector series of a configuration: ``[key, module, signal, row view,
    row shape]``; a series without a column yet gets it from :meth:`Recording.put` (the
    width of its first value), its view then."""
    cols = []
    for key, src, sig in values:
        arr = rec.cols.get(key)
        cols.append([key, src, sig, None if arr is None else arr[:, 0],
                     None if arr is None else arr.shape[2:]])
    return cols


def _step(
    run: _Run,
    adapt: Callable[[Any], list[dict[str, Any]] | None] | None,
    progress: Callable[[int, int], None] | None,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Step the run's system through the scenario, record every step (the series the
    recording keeps), call ``adapt`` every ``runtime.period_s``; the switches it made and
    the module faults seen (:func:`fault_spans`)."""
    system, rec, rt = run.system, run.rec, run.arch.runtime
    n = rec.n
    per = max(1, int(round(rt.period_s / rec.dt)))
    every = max(1, n // 100)
    act_mod, act_sig = rt.objective.actual.rsplit(".", 1)
    ref_mod, ref_sig = rt.objective.reference.rsplit(".", 1)
    fixed = [(k, m, sig) for k, m, sig in (("reference", ref_mod, ref_sig),
                                           ("actual", act_mod, act_sig)) if rec.wants(k)]
    switches: list[dict[str, Any]] = []
    cols: list[Any] = []  # _columns of the configuration
    res_idx: list[tuple[int, Any, str]] = []
    cur_conf, index = None, -1
    outputs = system.outputs
    t_col, J_col, conf_col, res = rec.t, rec.J[:, 0], rec.conf[:, 0], rec.res[:, 0]
    comps, put = rec.comps, rec.put
    empty: dict[str, Any] = {}
    faults: dict[tuple[str, str], list[Any]] = {}
    for i in range(n):
        system.step()
        if system.unavailable:
            note_faults(faults, system.t, system.active, system.unavailable)
        if system.configuration != cur_conf:
            cur_conf = system.configuration
            index = rec.conf_index.get(cur_conf, -1)
            cols = _columns(rec, fixed + [(key, src, sig) for key, sig in rec.record
                                             if (src := _publisher(system, sig)) is not None])
            active, modules = system.active, system.modules
            res_idx = [(j, modules[m], s) for j, (m, s) in enumerate(rec.res_mods) if m in active]
        t_col[i] = system.t
        J_col[i] = objective_norm(outputs.get(act_mod, empty).get(act_sig),
                                  outputs.get(ref_mod, empty).get(ref_sig), comps)
        conf_col[i] = index
        for col in cols:
            val = outputs.get(col[1], empty).get(col[2])
            if val is None:
                continue
            if col[3] is not None and type(val) is np.ndarray and val.shape == col[4]:
                col[3][i] = val  # the common case: a vector of the column's width
            else:
                put(col[0], i, val)
                if col[3] is None and col[0] in rec.cols:  # its first value made the column
                    arr = rec.cols[col[0]]
                    col[3], col[4] = arr[:, 0], arr.shape[2:]
        for j, mod, s in res_idx:
            sigs = getattr(mod, "signals", None)
            v = sigs.get(s) if sigs is not None else None
            res[i, j] = mod.local_signals().get(s, math.nan) if v is None else v
        if adapt is not None and (i + 1) % per == 0:
            out = adapt(system)
            if out:
                switches.extend(dict(s) for s in out)
        if progress is not None and ((i + 1) % every == 0 or i + 1 == n):
            progress(i + 1, n)
    return switches, fault_spans(faults)


_VARYING = re.compile(r" for [-+0-9.e]+ s$| \(\d+ identical values\)$")


@lru_cache(maxsize=4096)
def _bare(why: str) -> str:
    """``why`` without its running count (``silent for 1.2 s`` -> ``silent``); cached:
    a down module gives the same reason step after step, in every lane."""
    return _VARYING.sub("", why)


def note_faults(faults: dict[tuple[str, str], list[Any]], t: float,
                active: Collection[str], unavailable: dict[str, str]) -> None:
    """Count one step's unavailable active modules (``unavailable``: module -> reason)
    into ``faults``: (module, reason without its running count) -> [first t, last t,
    steps, reason as first seen]. Shared by the per-run and the lane-batched run."""
    for name, why in unavailable.items():
        if name not in active:
            continue
        key = (name, _bare(why))
        span = faults.get(key)
        if span is None:
            faults[key] = [t, t, 1, why]
        else:
            span[1] = t
            span[2] += 1


def fault_spans(faults: dict[tuple[str, str], list[Any]]) -> list[dict[str, Any]]:
    """The module faults of a run as data, in the order first seen (the same step: by
    module and reason, so that lanes and per-run runs list them alike): ``{module,
    reason, first_s, last_s, steps}`` (``reason`` without a running count: ``raised
    RuntimeError``, ``silent``, ``stale estimate``, ``lost input pose`` …)."""
    return [{"module": m, "reason": r, "first_s": float(v[0]), "last_s": float(v[1]),
             "steps": int(v[2])}
            for (m, r), v in sorted(faults.items(), key=lambda kv: (kv[1][0], kv[0]))]


def simulate(
    arch: Architecture | str | Path,
    scenario: str,
    *,
    configuration: str | None = None,
    seed: int | None = None,
    adapt: Callable[[Any], list[dict[str, Any]] | None] | None = None,
    progress: Callable[[int, int], None] | None = None,
    keep: Collection[str] | None = None,
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
        If it has a ``decisions`` list attribute, that log goes into the trace; what a
        ``saved_knowledge()`` method returns (not None) goes into ``meta["knowledge"]``.
    progress : callable, optional
        ``progress(done_steps, total_steps)``, called about 100 times.
    keep : collection of str, optional
        The series to record besides ``t``, ``J`` and ``configuration`` (names from
        :func:`series_names`: ``reference``, ``actual``, the ``runtime.record`` series,
        ``residual.<module>``); ``()`` records J alone (a campaign that keeps the
        metrics). None (the default): every series.

    Returns
    -------
    RunResult

    Raises
    ------
    SimulationError
        Unknown scenario or series.
    CompileError
        The configuration cannot be built.
    """
    run = _plan(arch, scenario, configuration, seed, adapt, progress, keep)
    switches, faults = _step(run, adapt, progress)
    res = run.rec.result(
        0, run.arch, run.seed, "fixed" if adapt is None else "adaptive", run.start,
        run.system.configuration, switches, list(getattr(adapt, "decisions", None) or []),
    )
    res.faults = faults
    saved = getattr(adapt, "saved_knowledge", None)  # what the loop learned: in the trace
    known = saved() if callable(saved) else None
    if known is not None:
        res.meta["knowledge"] = known
    return res
