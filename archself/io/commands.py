"""What the commands print with ``--json``: one pydantic model per command.

Each command builds its output with :func:`~archself.io.jsondata.document` (``complete``:
a value that does not apply is its field's default, ``null`` or ``[]``, never a missing
key) and prints the model's JSON; docs/json.md shows each model's JSON Schema
(tools/json_docs.py) and tests/test_json_shapes.py validates every command's output with
its model. The job records (``campaign``, ``calibrate``, ``identify``) are in
:mod:`archself.io.jobs`; the run of ``simulate`` is :class:`~archself.io.jsondata.RunDoc`.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, RootModel, model_validator

from archself import __version__
from archself.io.jobs import OutDoc
from archself.io.jsondata import RunDoc, SwitchDoc

__all__ = ["CampaignReportDoc", "ExplainDoc", "InfoDoc", "LiveDoc", "Ros2Doc", "SimulateDoc",
           "ValidateDoc", "ValidateList"]

Number = int | float  # as computed: an int stays an int
Maybe = Number | None  # a number, or null when it does not apply (or is not finite)


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
    max_lambda: Maybe = Field(description="max |λ| per step")
    marginal: list[str] = Field(description="modes: '|λ| (modules: states)'")
    unstable: list[str]
    why: str = Field(description="why it is unverified ('' otherwise)")
    margin: Maybe = Field(None, description="1 − max_lambda; null when unverified")

    @model_validator(mode="after")
    def _margin(self) -> VerdictDoc:
        if self.margin is None and self.max_lambda is not None:
            self.margin = 1.0 - self.max_lambda
        return self


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
    threshold: Maybe = None
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

    t: Number
    action: str
    module: str
    z: Maybe
    score: Maybe
    source: Maybe = None
    equivalent: list[str] = Field(default_factory=list)


class SwitchChoice(ChoiceDoc):
    from_: str = Field(alias="from")
    to: str


class UpdateChoice(ChoiceDoc):
    set: dict[str, Any]


class CycleSegment(OutDoc):
    """A notable cycle in full (a decision record, docs/runtime.md)."""

    kind: Literal["cycle"]
    record: dict[str, Any]


class RepeatSegment(OutDoc):
    """A run of repeated cycles, summarized."""

    kind: Literal["repeat"]
    t_from: Number
    t_to: Number
    cycles: int
    phase: str
    configuration: str
    candidates: list[str]
    max_abs_z: Maybe
    max_source: Maybe = None


class ExplainDoc(OutDoc):
    """``archself explain --json``: the run, the cycles logged, the switches and
    parameter updates, the log's segments."""

    run: RunRef
    cycles: int
    switches: list[SwitchChoice]
    updates: list[UpdateChoice]
    segments: list[Annotated[CycleSegment | RepeatSegment, Field(discriminator="kind")]]


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
    rate: Maybe
    lo: Maybe
    hi: Maybe


class DistributionDoc(OutDoc):
    """A distribution (null but ``n`` when empty)."""

    n: int
    mean: Maybe
    p10: Maybe
    median: Maybe
    p90: Maybe
    max: Maybe


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
    false_switches_per_run: Maybe
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
