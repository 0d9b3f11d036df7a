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
  Defined in :mod:`archself.io.outdocs` and reached here by name (PEP 562): a process
  that prints none of them does not build them.

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
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError
from pydantic.functional_validators import model_validator

from archself.errors import ArchselfError
from archself.io.docbase import Num, RunDoc, _Doc, json_kind
from archself.io.yaml_source import MAX_INT_DIGITS

if TYPE_CHECKING:  # pragma: no cover - built on first use (``__getattr__`` below)
    from archself.io.outdocs import (
        CampaignDoc,
        CampaignReportDoc,
        ExplainDoc,
        InfoDoc,
        JobDoc,
        LiveDoc,
        OutDoc,
        Ros2Doc,
        RunReportSummary,
        SimulateDoc,
        ValidateDoc,
        ValidateList,
    )

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
Modules = typing.Annotated[dict[str, Num] | None, Field(description="an object of modules")]
Names = typing.Annotated[list[str] | None, Field(description="a list of module names")]


def _none(v: Any) -> bool:
    return v is None


def _empty(v: Any) -> bool:
    return not v


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


# ------------------------------------------------------------------ outputs (PEP 562)
def __getattr__(name: str) -> Any:
    """The printed documents (:class:`OutDoc` and its kin) from :mod:`archself.io.outdocs`:
    built on the first use of one, so a process that prints none (a plain ``simulate``)
    does not build them."""
    if name.startswith("__"):
        raise AttributeError(name)
    from archself.io import outdocs  # start-up: ≈ 0.03 s of class building and RootModel

    try:
        return getattr(outdocs, name)
    except AttributeError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None


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
