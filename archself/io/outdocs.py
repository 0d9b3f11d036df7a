"""The printed documents of :mod:`archself.io.jsondata` (:class:`OutDoc` and its kin).

Each command's ``--json``, a run report's ``summary.json`` and the job records: defined
here and reached as ``archself.io.jsondata.<Name>`` (its PEP 562 ``__getattr__``), so a
process that prints none of them (``archself simulate``) does not build their classes
(≈ 0.03 s of start-up, issue 38.4).
"""

from __future__ import annotations

import typing
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, RootModel

from archself import __version__
from archself.io.docbase import ModuleFaultDoc, Num, RunDoc, SwitchDoc, _empty


# ------------------------------------------------------------------ outputs: the job records
class OutDoc(BaseModel):
    """An output document: the keys its fields name, no other."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True, defer_build=True)


class JobDoc(OutDoc):
    """The leading fields of every job record (campaign, calibrate, identify)."""

    architecture: str = Field(description="the file's name: key")
    file: str
    seeds: int = Field(description="seeds per scenario (and configuration)")
    root_seed: int
    executor: str
    elapsed_s: float
    archself_version: str = Field(default_factory=lambda: __version__)


class CampaignDoc(JobDoc):
    """``archself campaign --json``: what the run did (with ``--resume``, ``skipped`` runs
    were already in ``out``); ``errors``, the first failed runs' messages."""

    out: str
    planned: int
    skipped: int
    ran: int
    failed: int
    rows: int
    workers: int
    errors: list[str]


# ------------------------------------------------------------------ outputs: the commands' --json
Number = int | float  # as computed: an int stays an int


# ------------------------------------------------------------------ validate, info
class FindingDoc(OutDoc):
    """One finding, as printed without ``--json``; ``line`` and ``col`` 1-based, null
    without a position."""

    severity: Literal["error", "warning", "info"]
    code: str
    message: str
    path: str
    file: str
    line: int | None
    col: int | None


class VerdictDoc(OutDoc):
    """One configuration of the whole-loop stability table (docs/stability.md)."""

    configuration: str
    verdict: Literal["verified", "marginal", "unstable", "unverified"]
    covered: int = Field(description="stateful modules covered")
    stateful: int
    active: int
    states: int
    max_lambda: Num = Field(description="max |λ| per step")
    marginal: list[str] = Field(description="modes: '|λ| (modules: states)'")
    unstable: list[str]
    why: str = Field(description="why it is unverified ('' otherwise)")
    margin: Num = Field(description="1 − max_lambda; null when unverified")


class ValidateDoc(OutDoc):
    """One PATH of ``validate`` (stdin: ``<stdin>``); ``stability`` empty unless checked."""

    file: str
    ok: bool
    findings: list[FindingDoc]
    stability: list[VerdictDoc]


class ValidateList(RootModel[list[ValidateDoc]]):
    """``archself validate --json``: one item per PATH, whatever their number."""


class _Named(OutDoc):
    name: str


class CountsDoc(OutDoc):
    modules: int
    edges: int
    configurations: int
    actions: int
    scenarios: int


class InfoModule(_Named):
    kind: str
    type: str
    residual: str | None


class InfoConfiguration(_Named):
    initial: bool
    modules: list[str]
    description: str | None


class InfoAction(OutDoc):
    id: str
    module: str
    kind: str
    to: str | None
    set: dict[str, Any] | None
    cost: Number


class InfoScenario(_Named):
    duration_s: Number
    faults: list[str] = Field(description="'<kind> on <module> at <onset> s'")


class InfoRuntime(OutDoc):
    """The candidate selector and its value (the two not selected null), the clock."""

    step_s: Number
    period_s: Number
    selector: Literal["threshold", "top_k", "hysteresis"]
    threshold: Num = None
    top_k: int | None = None
    hysteresis: dict[str, Number] | None = Field(None, description="{on, off}")
    warmup_steps: int
    dwell_s: Number
    objective: dict[str, Any] = Field(description="runtime.objective of the file")


class InfoDoc(OutDoc):
    """``archself info --json``: what the file holds; ``stability`` as in ``validate``."""

    name: str
    description: str | None
    counts: CountsDoc
    modules: list[InfoModule]
    configurations: list[InfoConfiguration]
    actions: list[InfoAction]
    scenarios: list[InfoScenario]
    runtime: InfoRuntime
    stability: list[VerdictDoc] = Field(default_factory=list)


# ------------------------------------------------------------------ simulate, explain, live
class SimulateDoc(OutDoc):
    """``archself simulate --json``: one run, or ``[fixed, adaptive]`` with ``--compare``."""

    runs: list[RunDoc]


class RunRef(OutDoc):
    """The run a trace holds (null: an older or a live log that does not say); the other
    keys of the trace's meta are left out."""

    model_config = ConfigDict(extra="ignore")

    architecture: str | None = None
    scenario: str | None = None
    seed: int | None = None
    mode: str | None = None
    configuration: str | None = None
    final_configuration: str | None = None


class ChoiceDoc(OutDoc):
    """A chosen action: when, which, its |z| and score; ``source`` (ê) null in logs
    written before it; ``equivalent``: the modules the residuals cannot tell apart from
    its module (empty when it was identified)."""

    t: Num
    action: str | None
    module: str | None
    z: Num
    score: Num
    source: Num = None
    equivalent: list[str] = Field(default_factory=list)


class SwitchChoice(ChoiceDoc):
    from_: str | None = Field(alias="from")
    to: str | None


class UpdateChoice(ChoiceDoc):
    set: dict[str, Any] | None


class CycleSegment(OutDoc):
    """A notable cycle in full (a decision record, docs/runtime.md)."""

    kind: Literal["cycle"]
    record: dict[str, Any]


class RepeatSegment(OutDoc):
    """A run of repeated cycles, summarized."""

    kind: Literal["repeat"]
    t_from: Num
    t_to: Num
    cycles: int
    phase: str | None
    configuration: str | None
    candidates: list[str]
    max_abs_z: Num
    max_source: Num = None


class ExplainDoc(OutDoc):
    """``archself explain --json``: the run, the cycles logged, the switches and
    parameter updates, the log's segments."""

    run: RunRef
    cycles: int
    switches: list[SwitchChoice]
    updates: list[UpdateChoice]
    segments: list[typing.Annotated[CycleSegment | RepeatSegment, Field(discriminator="kind")]]


class UpdateDoc(OutDoc):
    t_s: Number
    action: str
    module: str
    set: dict[str, Any]


class LiveDoc(OutDoc):
    """``archself live --json``: what the loop did on the plant."""

    architecture: str
    measurements: int
    cycles: int
    configuration: str
    final_configuration: str
    switches: list[SwitchDoc]
    updates: list[UpdateDoc]


class Ros2Doc(LiveDoc):
    """``archself ros2 --json``: the keys of ``live`` and ``ros2``, the bridge's counters
    and timings (docs/ros2.md)."""

    ros2: dict[str, Any] = Field(description="cycles, ticks, messages, cycle_ms, act_ms, "
                                 "refused, skipped, lifecycle_nodes, wall_s, cpu_s, "
                                 "cpu_percent, messages_per_s, plant")


# ------------------------------------------------------------------ campaign-report
class RateDoc(OutDoc):
    """k of n, with its 95 % Wilson interval (``rate``, ``lo``, ``hi`` null when n = 0)."""

    k: int
    n: int
    rate: Num
    lo: Num
    hi: Num


class DistributionDoc(OutDoc):
    """A distribution (null but ``n`` when empty)."""

    n: int
    mean: Num
    p10: Num
    median: Num
    p90: Num
    max: Num


class CountDoc(OutDoc):
    value: str
    n: int


class ScenarioDoc(OutDoc):
    """One scenario: ``detected`` and ``delay_s`` null when fault-free,
    ``adaptive_better_rms`` null without fixed runs to pair with; ``errors`` per error
    metric, fixed and adaptive."""

    scenario: str
    faulted: bool
    runs: dict[Literal["fixed", "adaptive"], int]
    correct: RateDoc
    false_switch: RateDoc
    false_switches_per_run: Num
    final_configurations: list[CountDoc]
    paths: list[CountDoc]
    detected: RateDoc | None
    delay_s: DistributionDoc | None
    errors: dict[str, dict[Literal["fixed", "adaptive"], DistributionDoc]]
    adaptive_better_rms: RateDoc | None


class PointDoc(OutDoc):
    """One value of a swept column over its adaptive runs."""

    value: Number
    runs: int
    correct: RateDoc
    detected: RateDoc
    delay_s: DistributionDoc
    false_switch: RateDoc
    false_switch_basis: str
    rms_error: DistributionDoc


class SweepDoc(OutDoc):
    path: str
    points: list[PointDoc]


class CurveDoc(OutDoc):
    scenario: str
    points: list[PointDoc]


class TauDoc(SweepDoc):
    """The τ sweep: ``points`` over all adaptive runs, one curve per faulted scenario."""

    curves: list[CurveDoc]


class CampaignReportDoc(OutDoc):
    """``archself campaign-report --json`` and ``DIR/summary.json``; ``tau`` null when no
    τ column was swept."""

    archself_version: str = Field(default_factory=lambda: __version__)
    meta: dict[str, Any] = Field(description="the campaign's metadata (below)")
    runs: int
    failed: int
    unit: str | None
    expect: dict[str, str]
    scenarios: list[ScenarioDoc]
    tau: TauDoc | None
    sweeps: list[SweepDoc]
    errors: list[str]


# ------------------------------------------------------------------ the run report
class ReportRunDoc(OutDoc):
    """One run of a run report: its configurations, error metrics (in ``unit``), switches
    and parameter updates."""

    mode: str
    configuration: str
    final_configuration: str
    metrics: dict[str, Num]
    switches: list[dict[str, Any]] = Field(description="a list of switches (as in a trace)")
    parameter_updates: list[dict[str, Any]] = Field(description="a list of parameter updates")
    faults: list[ModuleFaultDoc] = Field(
        [], exclude_if=_empty, description="the run's module faults (as a run's JSON "
        "gives them); left out when there were none")


class ReportRowDoc(OutDoc):
    """One row of a run report's decision log: a cycle, or consecutive cycles in the same
    situation folded into one."""

    t_from: Num
    t_to: Num
    cycles: int
    configuration: str | None
    phase: str | None
    candidates: list[list[Any]] = Field(description="a list of [module, z]")
    outcome: str = Field(description="switch, update, rejected, warm-up, warm-up over, "
                         "note or no candidate")
    detail: str


class RunReportSummary(OutDoc):
    """``summary.json`` of a run report (``archself report``, ``simulate --report``): plain
    JSON, floats rounded to 6 significant digits, keys sorted; the same run gives the same
    bytes."""

    archself_version: str
    architecture: str
    scenario: str
    seed: int
    unit: str | None
    faults: list[dict[str, Any]] = Field(description="a list of the scenario's faults")
    selector: str = Field(description="the candidate selector, as the report states it")
    warmup_s: Num
    min_confidence: Num
    runs: list[ReportRunDoc]
    decision_log: list[ReportRowDoc]
