"""The run report model: what a simulation did, as data (no plotting, no HTML here).

:func:`build_run_report` takes the :class:`archself.sim.run.RunResult` of one run
(or of a fixed and an adaptive run, ``simulate --compare``) and extracts:

- a summary per run (metrics, start and final configuration, switches) and the unit
  of the error metrics (``runtime.objective.unit``);
- the z channels per module per MAPE-K cycle from the decision records
  (``decisions[i]['z']``; NaN where a module was inactive), τ from
  ``runtime.threshold`` (or τ_on/τ_off), the warm-up in seconds
  (``runtime.warmup_time_s``), the trust setting (``runtime.min_confidence``) and
  the switch events;
- the decision log reduced to the cycles where something happened: a candidate
  set, an action chosen, a note, or the end of the warm-up. Consecutive cycles
  in the same situation (configuration, candidates, rejections) are folded into
  one row.

:meth:`RunReport.summary` is deterministic plain JSON (floats rounded to 6
significant digits), the file the docs test compares.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from archself import __version__
from archself.errors import TraceError
from archself.io.html import card, table
from archself.io.jsondata import RunReportSummary, document
from archself.model.architecture import Architecture

__all__ = ["DecisionRow", "Rejection", "RunReport", "RunSummary", "build_run_report",
           "quality_table"]


def _round(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _round(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_round(v) for v in x]
    if isinstance(x, (bool, str)) or x is None:
        return x
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        v = float(x)
        return float(f"{v:.6g}") if math.isfinite(v) else None
    return x


@dataclass(frozen=True)
class RunSummary:
    mode: str
    configuration: str
    final_configuration: str
    metrics: dict[str, float]
    switches: tuple[dict[str, Any], ...]
    updates: tuple[dict[str, Any], ...] = ()
    faults: tuple[dict[str, Any], ...] = ()  # the run's module faults (RunResult.faults)


@dataclass(frozen=True)
class DecisionRow:
    """One line of the decision-log table (one cycle, or a run of similar cycles)."""

    t_from: float
    t_to: float
    cycles: int
    configuration: str
    phase: str
    j_obs: float | None
    candidates: tuple[tuple[str, float | None], ...]  # (module, z)
    outcome: str  # "switch", "update", "rejected", "warm-up", "note", "no candidate"
    detail: str


@dataclass(frozen=True)
class Rejection:
    """Cycles whose candidates were all turned down for one reason (action and verdict)."""

    action: str
    reason: str  # "not applicable", "no improvement", "unstable", "constraint", ...
    detail: str  # the planner's detail: the same in every cycle, or that of the first
    same_detail: bool
    t: tuple[float, ...]  # the cycles' times [s]

    @property
    def label(self) -> str:
        if not self.detail:
            return f"{self.action}: {self.reason}"
        return f"{self.action}: {self.reason} ({'' if self.same_detail else 'e.g. '}{self.detail})"


@dataclass
class RunReport:
    """Everything the run report shows, as data."""

    architecture: str
    scenario: str
    scenario_description: str
    seed: int
    faults: list[dict[str, Any]]
    objective: dict[str, Any]
    acceptable: float
    unit: str | None  # of J and the error metrics (runtime.objective.unit)
    selector: str
    tau: list[tuple[str, float]]  # [("τ", 0.55)] or [("τ_on", ..), ("τ_off", ..)] or []
    period_s: float
    warmup_s: float  # runtime.warmup_time_s: max(warmup_s, warmup_steps · period_s)
    min_confidence: float
    runs: list[RunSummary]
    decision_rows: list[DecisionRow] = field(default_factory=list)
    z_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    z: dict[str, np.ndarray] = field(default_factory=dict)
    series: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # mode -> series
    #: why cycles with candidates changed nothing, most frequent first (adaptive run)
    rejections: list[Rejection] = field(default_factory=list)
    #: the file's quality attributes (:func:`quality_table`), None without ``qualities``
    qualities: dict[str, Any] | None = None

    def timeline(self, mode: str) -> list[tuple[float, str]]:
        """``(t, configuration)`` from the start of run ``mode`` and at each of its switches."""
        run = next(r for r in self.runs if r.mode == mode)
        t0 = float(np.asarray(self.series[mode]["t"])[0]) if self.series.get(mode) else 0.0
        return [(t0, run.configuration),
                *((float(s["t_s"]), str(s["to"])) for s in run.switches)]

    @property
    def adaptive(self) -> RunSummary | None:
        return next((r for r in self.runs if r.mode == "adaptive"), None)

    @property
    def switches(self) -> tuple[dict[str, Any], ...]:
        a = self.adaptive
        return a.switches if a else ()

    def __repr__(self) -> str:
        """One line (the series and z channels are left out: thousands of samples)."""
        runs = ", ".join(f"{r.mode}: {r.configuration}→{r.final_configuration}"
                         for r in self.runs)
        return (f"RunReport(architecture={self.architecture!r}, scenario={self.scenario!r}, "
                f"seed={self.seed}, runs=[{runs}], decision_rows={len(self.decision_rows)})")

    def _repr_html_(self) -> str:
        """A short card for notebooks: each run's path and worst error, the decision log's size."""

        unit = f" [{self.unit}]" if self.unit else ""
        runs = table(["mode", "configurations", f"max error{unit}"], [
            (r.mode, " → ".join([r.configuration, *(str(s["to"]) for s in r.switches)]),
             f"{r.metrics.get('max_error', math.nan):.4g}") for r in self.runs])
        return card(f"{self.architecture} · {self.scenario} · seed {self.seed}", [
            ("candidates", self.selector),
            ("faults", ", ".join(f"{f.get('kind')} on {f.get('module')} at {f.get('onset_s')} s"
                                 for f in self.faults[:4]) or "none"),
            ("decision log", f"{len(self.decision_rows)} rows; cycles turned down: "
                             f"{sum(len(r.t) for r in self.rejections)}"),
        ], runs)

    def summary(self) -> dict[str, Any]:
        """Deterministic plain-JSON summary (``summary.json`` of the run report)."""

        return document(RunReportSummary, _round({
            "archself_version": __version__,
            "architecture": self.architecture,
            "scenario": self.scenario,
            "seed": self.seed,
            "unit": self.unit,
            "faults": self.faults,
            "selector": self.selector,
            "warmup_s": self.warmup_s,
            "min_confidence": self.min_confidence,
            "runs": [
                {
                    "mode": r.mode,
                    "configuration": r.configuration,
                    "final_configuration": r.final_configuration,
                    "metrics": r.metrics,
                    "switches": list(r.switches),
                    "parameter_updates": list(r.updates),
                    "faults": list(r.faults),
                }
                for r in self.runs
            ],
            "decision_log": [
                {
                    "t_from": row.t_from,
                    "t_to": row.t_to,
                    "cycles": row.cycles,
                    "configuration": row.configuration,
                    "phase": row.phase,
                    "candidates": [[m, z] for m, z in row.candidates],
                    "outcome": row.outcome,
                    "detail": row.detail,
                }
                for row in self.decision_rows
            ],
        }), complete=True)  # type: ignore[no-any-return]


def _selector(ctx: dict[str, Any]) -> tuple[str, list[tuple[str, float]]]:
    h = ctx.get("hysteresis")
    if h is not None:
        return (f"hysteresis |z| ≥ {h['on']:g} on, < {h['off']:g} off",
                [("τ_on", float(h["on"])), ("τ_off", float(h["off"]))])
    if ctx.get("top_k") is not None:
        return f"top {ctx['top_k']} by |z|", []
    threshold = float(ctx["threshold"])
    return f"|z| ≥ τ = {threshold:g}", [("τ", threshold)]


def _outcome(d: dict[str, Any]) -> tuple[str, str]:
    chosen = d.get("chosen")
    if chosen:
        if chosen.get("to"):
            return "switch", (f"{chosen['action']}: {chosen.get('from')} → {chosen['to']} "
                              f"(score {_g(chosen.get('score'))})")
        score = _g(chosen.get("score"))
        return "update", f"{chosen['action']} on {chosen.get('module')} (score {score})"
    if d.get("note"):
        return "note", str(d["note"])
    evals = d.get("evaluations") or []
    if evals:
        parts = [f"{e['action']}: {e.get('rejected') or 'not chosen'}" for e in evals]
        return "rejected", "; ".join(parts)
    if d.get("phase") == "warmup":
        return "warm-up", "adaptation suppressed"
    return "no candidate", ""


def _g(x: Any) -> str:
    return "n/a" if x is None else f"{float(x):.3g}"


def _decision_rows(decisions: list[dict[str, Any]]) -> list[DecisionRow]:
    rows: list[DecisionRow] = []
    prev_sig = None
    prev_phase = None
    for d in decisions:
        cands = tuple((c, (d.get("z") or {}).get(c)) for c in d.get("candidates") or [])
        outcome, detail = _outcome(d)
        # the first cycle after the warm-up (the loop records phase "warmup" until then)
        first_after_warmup = prev_phase == "warmup" and d.get("phase") != "warmup"
        prev_phase = d.get("phase")
        interesting = bool(cands) or outcome in ("switch", "update", "note") or first_after_warmup
        if not interesting:
            prev_sig = None
            continue
        if first_after_warmup and outcome == "no candidate":
            outcome, detail = "warm-up over", "adaptation enabled from this cycle"
        sig = (d.get("configuration"), tuple(c for c, _ in cands), outcome, detail)
        t = float(d.get("t", math.nan))
        if sig == prev_sig and outcome not in ("switch", "update") and rows:
            rows[-1] = replace(rows[-1], t_to=t, cycles=rows[-1].cycles + 1)
            continue
        rows.append(DecisionRow(t, t, 1, str(d.get("configuration")), str(d.get("phase")),
                                d.get("j_obs"), cands, outcome, detail))
        prev_sig = sig
    return rows


def _rejections(decisions: list[dict[str, Any]]) -> list[Rejection]:
    """Cycles with candidates and no chosen action, grouped by what turned them down.

    A cycle counts once, under its first evaluated action's verdict (the candidates'
    actions are evaluated in the planner's order); a cycle whose candidates have no
    action at all counts under ``(none)``.
    """
    groups: dict[tuple[str, str], list[Any]] = {}
    for d in decisions:
        if not d.get("candidates") or d.get("chosen") or d.get("phase") == "warmup":
            continue
        evals = d.get("evaluations") or []
        if evals:
            e = evals[0]
            key = (str(e.get("action")), str(e.get("rejected") or "not chosen"))
            detail = str(e.get("detail") or "")
        else:
            key, detail = ("(none)", "no action for the candidates"), ""
        g = groups.setdefault(key, [detail, True, []])
        g[1] = g[1] and detail == g[0]
        g[2].append(float(d.get("t", math.nan)))
    out = [Rejection(a, r, g[0], g[1], tuple(g[2])) for (a, r), g in groups.items()]
    return sorted(out, key=lambda x: -len(x.t))


def quality_table(arch: Architecture | None) -> dict[str, Any] | None:
    """The quality attributes of every configuration, for the run report's figure.

    ``{"preferences": {q: w}, "units": {q: unit}, "configurations": {c: {"U": U(C),
    "attributes": {q: {"value", "utility"}}}}}`` (:class:`archself.runtime.planner.Utility`);
    None without ``arch`` (a trace read back) or without a ``qualities`` section.
    """
    if arch is None or arch.qualities is None:
        return None
    from archself.runtime.planner import Utility

    u = Utility(arch)
    q = arch.qualities
    return {"preferences": {n: float(q.preferences.get(n, 0.0)) for n in q.attributes},
            "units": {n: a.unit for n, a in q.attributes.items()},
            "configurations": {c: u.of(c) for c in arch.configurations}}


def build_run_report(arch: Architecture | None, results: list[Any]) -> RunReport:
    """The report model of one run or of a fixed/adaptive pair from the same start and seed.

    ``arch`` None takes what the report needs of the file from the runs' ``meta``
    (traces read with :func:`archself.read_trace`; ``archself report --trace``).

    Raises
    ------
    TraceError
        ``arch`` is None and the runs' ``meta`` lacks the report context (a trace
        written before archself recorded it: pass the architecture file).
    """
    first = results[0]
    ctx, name, objective, unit, period_s, modules = _settings(arch, first)
    selector, tau = _selector(ctx)
    runs, series, decisions = _runs(results)
    z_t, z = _influence(modules, decisions)
    return RunReport(
        architecture=name,
        scenario=first.scenario,
        scenario_description=str(ctx.get("scenario_description") or ""),
        seed=int(first.seed),
        faults=[dict(f) for f in ctx.get("faults") or []],
        objective=objective,
        acceptable=float(ctx.get("acceptable") or 0.0),
        unit=unit,
        selector=selector,
        tau=tau,
        period_s=period_s,
        warmup_s=float(ctx.get("warmup_s") or 0.0),
        min_confidence=float(ctx.get("min_confidence") or 0.0),
        runs=runs,
        decision_rows=_decision_rows(decisions),
        z_t=z_t,
        z=z,
        series=series,
        rejections=_rejections(decisions),
        qualities=quality_table(arch),
    )


def _settings(
    arch: Architecture | None, first: Any
) -> tuple[dict[str, Any], str, dict[str, Any], str | None, float, list[str]]:
    """What the report needs of the file: from ``arch``, else from the run's ``meta``;
    ``(context, name, objective, unit, period_s, modules)``.

    Raises
    ------
    TraceError
        As :func:`build_run_report`.
    """
    meta = dict(first.meta)
    if arch is not None:
        from archself.sim.run import _report_context

        ctx = _report_context(arch, arch.scenarios[first.scenario])  # a trace's meta.report
        objective = {"actual": arch.runtime.objective.actual,
                     "reference": arch.runtime.objective.reference,
                     "components": list(arch.runtime.objective.components)}
        return (ctx, arch.name, objective, arch.runtime.objective.unit,
                float(arch.runtime.period_s), list(arch.modules))

    if not isinstance(meta.get("report"), dict) or "objective" not in meta:
        raise TraceError("error: the trace does not hold the run report's settings "
                         "(written by an older archself); pass the architecture file: "
                         "archself report ARCH --trace TRACE -o DIR")
    objective = {k: meta["objective"][k] for k in ("actual", "reference", "components")}
    return (meta["report"], str(meta.get("architecture", "?")), objective,
            meta["objective"].get("unit"), float(meta.get("period_s", math.nan)), [])


def _runs(
    results: list[Any],
) -> tuple[list[RunSummary], dict[str, Any], list[dict[str, Any]]]:
    """Each run's summary and series, and the adaptive run's decision records."""
    runs = []
    series = {}
    decisions: list[dict[str, Any]] = []
    for r in results:
        recs = r.trace_decisions()
        updates = tuple(
            {"t_s": d["t"], "action": d["chosen"]["action"], "module": d["chosen"].get("module"),
             "set": d["chosen"].get("set")}
            for d in recs if d.get("chosen") and not d["chosen"].get("to")
        )
        runs.append(RunSummary(r.mode, r.configuration, r.final_configuration,
                               dict(r.metrics), tuple(dict(s) for s in r.switches), updates,
                               tuple(dict(f) for f in r.faults)))
        series[r.mode] = r.series
        if r.mode == "adaptive":
            decisions = recs
    return runs, series, decisions


def _influence(
    modules: list[str], decisions: list[dict[str, Any]]
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """|z| of every module that ever had one, per decision, and the decisions' times."""
    # a trace: the modules in the order of the decision records (the file's order)
    modules = modules + list(dict.fromkeys(n for d in decisions for n in (d.get("z") or {})
                                           if n not in modules))
    names = [n for n in modules
             if any((d.get("z") or {}).get(n) not in (None, 0.0) for d in decisions)]
    z_t = np.array([float(d["t"]) for d in decisions])
    z = {
        n: np.array([abs(v) if (v := (d.get("z") or {}).get(n)) is not None else np.nan
                     for d in decisions], dtype=float)
        for n in names
    }
    return z_t, z
