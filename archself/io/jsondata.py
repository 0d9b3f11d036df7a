"""JSON data: the one cleaner, the reader, and every JSON document archself writes as a model.

:func:`jsonable` cleans what archself writes: numpy scalars and arrays become Python
numbers and lists, dataclass objects dicts of their fields, tuples and sets lists, mapping
keys strings, and non-finite floats ``None`` (JSON has no NaN). :func:`loads` reads JSON
with the loader's limits.

Every JSON document archself writes is a pydantic model here, and a writer builds its data
with :func:`document` (cleaned, validated, dumped in the model's field order):

- read back (:class:`_Doc`: JSON types only, no coercion, other keys allowed, a field
  added later optional): a trace (:class:`TraceDocument`: its ``meta``,
  :class:`TraceMeta` = :class:`RunContext` + :class:`RunDoc`, and its decision log,
  :data:`DecisionLog` of :class:`DecisionRecordDoc`), a Parquet trace's head
  (:class:`ParquetHead`), a calibration's saved runs (:class:`SavedRunsMeta`), a
  campaign's metadata (:class:`CampaignMeta`);
- printed (:class:`OutDoc`: the keys its fields name, no other): each command's
  ``--json`` (:class:`ValidateList`, :class:`InfoDoc`, :class:`SimulateDoc`,
  :class:`ExplainDoc`, :class:`LiveDoc`, :class:`Ros2Doc`, :class:`CampaignReportDoc`,
  a campaign report's ``summary.json`` too), a run report's ``summary.json``
  (:class:`RunReportSummary`) and the job records of ``campaign``, ``calibrate`` and
  ``identify``, which lead with the seven fields of :class:`JobDoc`
  (:class:`CampaignDoc`; ``calibration.result.CalibrationDoc``,
  ``calibration.identify_results.IdentificationDoc``).

:func:`problem` validates a document read back: the first violation as one line,
``meta.seed: expected an integer, got a string``, with its dotted path and what was
expected (a field's ``description``, a model's ``title`` or the field's type). The readers
keep the plain data, so what is written back or rendered is byte-identical.
docs/json.md shows the models' JSON Schemas (tools/json_docs.py). Nothing here imports
numpy, so ``archself explain`` stays free of it.

Examples
--------
>>> problem(TraceDocument, {"meta": {"scenario": "s", "seed": "x"}, "series": {}})
'meta.seed: expected an integer, got a string'
>>> problem(DecisionLog, [{"z": {"a": 0.5}, "chosen": None}]) is None
True
>>> problem(DecisionLog, [{"z": {"a": "x"}}], root="decisions")
'decisions[0].z.a: expected a number, got a string'
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from collections.abc import Mapping
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, RootModel, TypeAdapter, ValidationError
from pydantic.functional_validators import PlainValidator, model_validator
from pydantic.json_schema import WithJsonSchema

from archself import __version__
from archself.errors import ArchselfError
from archself.io.yaml_source import MAX_INT_DIGITS

__all__ = ["CampaignDoc", "CampaignMeta", "CampaignReportDoc", "ChosenDoc", "DecisionLog",
           "DecisionRecordDoc", "EvaluationDoc", "ExplainDoc", "InfoDoc", "JobDoc",
           "JsonLimitError", "LiveDoc", "OutDoc", "ParquetHead", "Ros2Doc", "RunContext",
           "RunDoc", "RunReportSummary", "SavedRunsMeta", "SimulateDoc", "TraceDocument",
           "TraceMeta", "ValidateDoc", "ValidateList", "document", "json_kind", "jsonable",
           "loads", "problem"]


class JsonLimitError(ValueError):
    """A JSON text past what archself reads: nested too deeply, or an integer of more
    digits than Python converts (``yaml_nodes.MAX_INT_DIGITS``); ``str`` says which."""


def _int(digits: str) -> int:
    if len(digits) > MAX_INT_DIGITS:
        raise JsonLimitError(f"an integer of {len(digits.lstrip('-')):,} digits (at most "
                             f"{MAX_INT_DIGITS:,})")
    return int(digits)


def loads(text: str | bytes, **kw: Any) -> Any:
    """:func:`json.loads` with the reading limits of architecture files: an integer of
    more than 4,300 digits or nesting past Python's recursion limit is a
    :class:`JsonLimitError` (a ``ValueError``) that says which, never a bare
    ``ValueError`` or ``RecursionError``. For traces, results and runs files.

    Examples
    --------
    >>> loads('{"a": [1, 2.5]}')
    {'a': [1, 2.5]}
    >>> loads("[" * 100_000 + "]" * 100_000)
    Traceback (most recent call last):
    ...
    archself.io.jsondata.JsonLimitError: nested too deeply
    """
    import json

    try:
        return json.loads(text, parse_int=_int, **kw)
    except RecursionError:
        raise JsonLimitError("nested too deeply") from None


def json_kind(x: Any) -> str:
    """What a JSON value is, for a message: ``an object``, ``a list``, ``a string``, ``null``.

    Examples
    --------
    >>> json_kind({}), json_kind(None), json_kind(1.5)
    ('an object', 'null', 'float')
    """
    return {dict: "an object", list: "a list", str: "a string", type(None): "null"}.get(
        type(x), type(x).__name__)


def jsonable(x: Any) -> Any:
    """``x`` as plain JSON data (dict, list, str, int, float, bool, None).

    Mappings become dicts with string keys, dataclass objects dicts of their fields;
    lists and tuples lists; sets lists sorted by their text; numpy arrays and scalars
    (anything with ``tolist``) their Python values; other numbers (``__float__``)
    floats; non-finite floats ``None``; anything else its ``str``.

    Examples
    --------
    >>> import numpy as np
    >>> jsonable({"a": np.float64(1.5), "b": [np.nan, 2], "c": (1, 2), 3: {"y", "x"}})
    {'a': 1.5, 'b': [None, 2], 'c': [1, 2], '3': ['x', 'y']}
    >>> jsonable([np.array([1.0, np.inf]), np.int64(4), np.bool_(True)])
    [[1.0, None], 4, True]
    """
    tp = type(x)
    if tp is float:
        return x if math.isfinite(x) else None
    if x is None or tp is str or tp is int or tp is bool:
        return x
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (set, frozenset)):
        return [jsonable(v) for v in sorted(x, key=str)]
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return {f.name: jsonable(getattr(x, f.name)) for f in dataclasses.fields(x)}
    if isinstance(x, (bool, str)):
        return x
    if hasattr(x, "tolist") and not isinstance(x, (int, float)):
        return jsonable(x.tolist())
    if isinstance(x, int):
        return int(x)
    if isinstance(x, float) or hasattr(x, "__float__"):
        v = float(x)
        return v if math.isfinite(v) else None
    return str(x)


# ------------------------------------------------------------------ the documents
def _number(v: Any) -> Any:
    if v is None or type(v) is float or type(v) is int:
        return v
    raise ValueError(f"expected a number, got {json_kind(v)}")


#: A number as it is (an int stays an int), or null (NaN as :func:`jsonable` writes it).
Num = typing.Annotated[Any, PlainValidator(_number),
                       WithJsonSchema({"anyOf": [{"type": "number"}, {"type": "null"}]})]
Modules = typing.Annotated[dict[str, Num] | None, Field(description="an object of modules")]
Names = typing.Annotated[list[str] | None, Field(description="a list of module names")]


def _none(v: Any) -> bool:
    return v is None


def _empty(v: Any) -> bool:
    return not v


class _Doc(BaseModel):
    """A JSON document archself writes and reads back: JSON types only (no coercion),
    other keys allowed; written in the order of its fields (:func:`document`)."""

    model_config = ConfigDict(strict=True, extra="allow", populate_by_name=True, defer_build=True)


# ------------------------------------------------------------------ the decision log
class EvaluationDoc(_Doc):
    """One action of a cycle's Plan stage (``ActionEvaluation``); ``utility`` (qualities),
    ``mean``, ``spread``, ``draws``, ``rule`` (``runtime.risk``) and ``learned``
    (``runtime.learning``) only when set."""

    model_config = ConfigDict(title="an object with an action")
    action: Any
    module: str | None = None
    kind: str | None = None
    to: str | None = None
    z: Num = None
    delta: Num = None
    cost: Num = None
    score: Num = None
    stability: dict[str, Any] | None = None
    rejected: str | None = None
    detail: str | None = None
    utility: dict[str, Any] | None = Field(None, exclude_if=_none)
    mean: Num = Field(None, exclude_if=_none)
    spread: Num = Field(None, exclude_if=_none)
    draws: int | None = Field(None, exclude_if=_none)
    rule: str | None = Field(None, exclude_if=_none)
    learned: dict[str, Any] | None = Field(None, exclude_if=_none)


class ChosenDoc(_Doc):
    """The action a cycle chose: ``set`` for a parameter update, ``from`` and ``to`` for a
    switch."""

    model_config = ConfigDict(title="an object with an action, or null")
    action: Any
    kind: str | None = None
    module: str | None = None
    z: Num = None
    source: Num = None
    delta: Num = None
    score: Num = None
    set: dict[str, Any] | None = Field(None, exclude_if=_none)
    from_: str | None = Field(None, alias="from", exclude_if=_none)
    to: str | None = Field(None, exclude_if=_none)


class DecisionRecordDoc(_Doc):
    """One MAPE-K cycle (``DecisionRecord``): ``source`` only with a source estimate,
    ``equivalent`` and ``compensated`` only when not empty. A field added later is
    optional (``exclude_if`` when unset), so older logs still read."""

    model_config = ConfigDict(title="a decision record (an object)")
    cycle: Num = None
    t: Num = None
    configuration: str | None = None
    phase: str | None = None
    j_obs: Num = None
    j_ref: Num = None
    r_global: Num = None
    r: Modules = None
    z: Modules = None
    source: Modules = Field(None, exclude_if=_none)
    equivalent: list[list[str]] | None = Field(
        None, description="a list of lists of module names", exclude_if=_empty)
    localization: str | None = None
    candidates: Names = None
    selector: str | None = None
    kappa: dict[str, Any] | None = Field(None, description="an object of modules")
    evaluations: list[EvaluationDoc] | None = None
    chosen: ChosenDoc | None = None
    note: str | None = None
    compensated: Names = Field(None, exclude_if=_empty)


DecisionLog = typing.Annotated[list[DecisionRecordDoc],
                               Field(description="a list of decision records")]


# ------------------------------------------------------------------ a trace
class SwitchDoc(_Doc):
    """One switch of the architecture: when, from and to which configuration, by which
    action of which module."""

    t_s: float
    from_: str | None = Field(None, alias="from")
    to: str | None = None
    action: str | None = None
    module: str | None = None


class RunDoc(_Doc):
    """One run (``archself simulate --json``'s ``runs``; the run part of a trace's ``meta``).
    ``metrics`` in ``unit``, null when not finite."""

    scenario: str
    seed: int
    mode: str
    configuration: str
    final_configuration: str
    unit: str | None = None
    metrics: dict[str, Num]
    switches: list[SwitchDoc] | None = None


class ObjectiveDoc(_Doc):
    actual: str
    reference: str
    components: list[typing.Annotated[int, Field(ge=0)]] = Field(
        description="a list of indices")


class FaultDoc(_Doc):
    module: str | None = None
    kind: str | None = None
    onset_s: float


class HysteresisDoc(_Doc):
    model_config = ConfigDict(title="an object {on, off}")
    on: float
    off: float


class ReportDoc(_Doc):
    """What the run report needs beyond the series (``archself report --trace``)."""

    scenario_description: str | None = None
    faults: list[FaultDoc] | None = None
    acceptable: Num = None
    threshold: Num = None
    top_k: Num = None
    hysteresis: HysteresisDoc | None = None
    warmup_s: Num = None
    min_confidence: Num = None

    @model_validator(mode="after")
    def _selector(self) -> ReportDoc:
        if self.hysteresis is None and self.top_k is None and self.threshold is None:
            raise ValueError("expected a threshold, top_k or hysteresis")
        return self


class RunContext(_Doc):
    """What a trace's ``meta`` holds of the file: its clock, objective, residual signals,
    the series' element names and the run report's context (``sim.run.run_meta``)."""

    architecture: str | None = None
    step_s: Num = None
    period_s: Num = None
    duration_s: Num = None
    objective: ObjectiveDoc | None = None
    residuals: dict[str, str] | None = Field(None, description="an object of modules")
    elements: dict[str, list[str]] | None = Field(None, description="an object of series")
    report: ReportDoc | None = None


class TraceMeta(RunDoc, RunContext):
    """A trace's ``meta``: the file's context, the run and the configuration names
    (``RunResult.trace_meta()``)."""

    configurations: list[str] | None = Field(None, description="a list of names")
    knowledge: dict[str, Any] | None = Field(
        None, exclude_if=_none,
        description="what the loop learned (runtime.learning's outcome table, "
                    "runtime.online's updates): `--knowledge TRACE` reads it")


class TraceDocument(_Doc):
    """A trace ``{meta, series, decisions}`` (a Parquet trace: ``series`` are columns)."""

    meta: TraceMeta
    series: dict[str, list[Any]] = Field(description="an object of series (one value per step)")
    decisions: DecisionLog


class ParquetHead(_Doc):
    """The ``archself.trace`` metadata of a Parquet trace (its decision log is a key of
    its own): the format, ``meta``, and each series' width (0: one column)."""

    format: int = 0
    meta: TraceMeta
    series: list[typing.Annotated[tuple[str, int], Field(strict=False)]]  # JSON: no tuples


# ------------------------------------------------------------------ saved runs, campaigns
class SavedRun(_Doc):
    model_config = ConfigDict(title="a saved run")
    scenario: str
    configuration: str
    replicate: int
    seed: int
    error: str | None
    phase: Literal["calibration", "verify"]


class SavedRunsMeta(_Doc):
    """The ``meta`` of ``calibrate --save-runs`` (an ``.npz``): the runs and their origin."""

    format: int | None = None
    architecture: str | None = None
    digest: str | None = Field(None, description="the file's identity without its bands")
    seeds: int
    verify_seeds: int
    root_seed: int
    scenarios: list[str]
    configurations: list[str]
    executor: str
    elapsed_s: float
    verify_elapsed_s: float
    runs: list[SavedRun]


class CampaignMeta(_Doc):
    """The ``archself.campaign`` metadata of a campaign's results (Parquet)."""

    format: int | None = None
    architecture: str | None = None
    file: str | None = None
    sha256: str | None = Field(None, description="the file's SHA-256 (--resume checks it)")
    root_seed: int | None = None
    sweeps: list[str] = Field(default_factory=list, description="a list of parameter paths")
    fault_free: list[str] = Field(default_factory=list, description="a list of scenarios")
    thresholds: list[str] = Field(default_factory=list, description="a list of names")
    steps: int | None = Field(None, description="the steps the campaign simulates")
    lane_types: bool | None = Field(None, description="every module type runs in lanes")


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


# ------------------------------------------------------------------ validation
@functools.cache
def _adapter(tp: Any) -> TypeAdapter[Any]:
    return TypeAdapter(tp)


def _unwrap(tp: Any) -> tuple[Any, Any]:
    """``(type, FieldInfo or None)`` without ``Annotated`` and ``| None``."""
    info = None
    while True:
        origin = typing.get_origin(tp)
        if origin is typing.Annotated:
            tp, *meta = typing.get_args(tp)
            info = next((m for m in meta if getattr(m, "description", None)), info)
        elif origin in (typing.Union, types.UnionType):
            tp = next(a for a in typing.get_args(tp) if a is not type(None))
        else:
            return tp, info


def _expected(tp: Any, loc: tuple[Any, ...]) -> str:
    """What the document's type ``tp`` expects at ``loc`` (a phrase: ``an integer``)."""
    tp, info = _unwrap(tp)
    for item in loc:
        if isinstance(tp, type) and issubclass(tp, BaseModel) and item in tp.model_fields:
            field = tp.model_fields[item]
            tp, info = _unwrap(field.rebuild_annotation())
            info = field if field.description else info
        elif typing.get_origin(tp) in (list, dict, tuple):
            args = typing.get_args(tp)
            tp, info = _unwrap(args[item] if typing.get_origin(tp) is tuple else args[-1])
            info = info if info is not None and info.description else None
    if info is not None and info.description:
        return str(info.description)
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return str(tp.model_config.get("title") or "an object")
    origin = typing.get_origin(tp)
    if origin in (list, dict, tuple):
        return "an object" if origin is dict else "a list"
    if origin is Literal:
        return "one of " + ", ".join(map(str, typing.get_args(tp)))
    return {int: "an integer", float: "a number", str: "a string", bool: "true or false"}.get(
        tp, "a value")


def problem(tp: Any, data: Any, root: str = "") -> str | None:
    """The first way ``data`` departs from the document type ``tp`` (one line), or None.

    ``tp`` is a model or a type such as :data:`DecisionLog`; the line is ``dotted.path:
    expected …, got …``, the path from ``root`` (``decisions`` for a log:
    ``decisions[3].z``).
    """
    try:
        _adapter(tp).validate_python(data)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        loc = tuple(err["loc"])
        path = (root + "".join(f"[{p}]" if isinstance(p, int) else f".{p}"
                               for p in loc)).lstrip(".") or "document"
        if err["type"] == "value_error":
            return f"{path}: {str(err['msg']).removeprefix('Value error, ')}"
        got = "nothing" if err["type"] == "missing" else json_kind(err["input"])
        if err["type"] in ("greater_than_equal", "literal_error"):
            got = repr(err["input"])
        bound = f" ≥ {err['ctx']['ge']}" if err["type"] == "greater_than_equal" else ""
        return f"{path}: expected {_expected(tp, loc)}{bound}, got {got}"
    return None


def document(tp: Any, data: Any, root: str = "", *, complete: bool = False,
             **fields: Any) -> Any:
    """``data`` as plain JSON data of the document type ``tp``, as archself writes it.

    ``data`` (for a model, an object whose attributes it takes; ``fields`` replace
    some) is cleaned
    (:func:`jsonable`: dataclass objects, numpy values, NaN → null), validated by ``tp``
    and dumped in the order of its fields, without the keys a field
    excludes (``exclude_if``) or ``data`` lacks (an older log written back stays as it
    was; ``complete``: those take their defaults, as a command's output); keys the model
    does not name follow its fields.

    Raises
    ------
    ArchselfError
        ``error: the document would not read back: path: expected …`` (a writer's bug).

    Examples
    --------
    >>> document(ChosenDoc, {"to": "b", "action": "x", "z": float("nan"), "from": "a"})
    {'action': 'x', 'z': None, 'from': 'a', 'to': 'b'}
    """

    if isinstance(tp, type) and issubclass(tp, BaseModel) and not isinstance(data, Mapping | list):
        data = {k: getattr(data, k) for k in tp.model_fields if hasattr(data, k)}
    data = {**data, **fields} if fields else data
    clean = jsonable(data) if complete else _writer(tp)(data)
    adapter = _adapter(tp)
    try:
        obj = adapter.validate_python(clean)
    except ValidationError:
        raise ArchselfError("error: the document would not read back: "
                            f"{problem(tp, clean, root)}") from None
    if not complete:  # already in the model's order: what the dump below would give
        return clean
    return adapter.dump_python(obj, mode="json", by_alias=True, exclude_unset=False)


@functools.cache
def _writer(tp: Any) -> Any:
    """A function that writes a value of the document type ``tp`` as :func:`document` does
    without ``complete``, in one pass: a model's fields in its order (the keys the value
    lacks and those a field excludes left out, other keys after them), a ``float`` field's
    integer as a float, anything else :func:`jsonable` (the dump of the validated model
    gave the same data at three times the cost: the decision log of a run of 800 cycles).
    """
    tp, _ = _unwrap(tp)
    origin = typing.get_origin(tp)
    if origin is list and isinstance(_unwrap(typing.get_args(tp)[0])[0], type):
        item = _writer(typing.get_args(tp)[0])
        return lambda v: [item(x) for x in v] if isinstance(v, list | tuple) else jsonable(v)
    if tp is float:
        return lambda v: float(v) if type(v) is int else jsonable(v)
    if not (isinstance(tp, type) and issubclass(tp, BaseModel)):
        return jsonable
    plan = [(name, f.alias or name, f.exclude_if, _writer(f.rebuild_annotation()))
            for name, f in tp.model_fields.items()]
    named = {k for name, alias, _, _ in plan for k in (name, alias)}

    def write(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            v = {f.name: getattr(v, f.name) for f in dataclasses.fields(v)}
        if not isinstance(v, Mapping):
            return jsonable(v)
        out = {}
        for name, alias, exclude, put in plan:
            x = v[alias] if alias in v else v[name] if name in v else _MISSING
            if x is not _MISSING:
                x = put(x)
                if exclude is None or not exclude(x):
                    out[alias] = x
        out.update((str(k), jsonable(x)) for k, x in v.items() if k not in named)
        return out

    return write


_MISSING = object()
