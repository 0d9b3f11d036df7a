"""Sweeps: addressing a value in an architecture's data and varying it.

A PATH names one value of the plain data of an architecture file with dots and
indices, the same notation the loader uses in its messages
(:func:`archself.model.loader.dotted`): ``runtime.threshold``,
``scenarios.imu_drift.faults[0].magnitude``, ``modules.gps.params.noise_m.value``.
Keys that are not plain identifiers are written as JSON strings in brackets:
``modules["left wheel"].params.side.value``.

A sweep is ``PATH=START:STOP:NUM`` (``numpy.linspace(START, STOP, NUM)``) or
``PATH=V1,V2,...`` (an explicit list). The values are applied to the plain data
and the result is validated again through the model (and the semantic checks),
so a value outside what the file allows is a one-line error, not a crash in a
worker.

Examples
--------
>>> parse_path('scenarios.imu_drift.faults[0].magnitude')
('scenarios', 'imu_drift', 'faults', 0, 'magnitude')
>>> s = parse_sweep("runtime.threshold=0.4:0.6:3")
>>> s.path, s.values
('runtime.threshold', (0.4, 0.5, 0.6))
>>> data = {"runtime": {"threshold": 0.55}}
>>> set_path(data, parse_path("runtime.threshold"), 0.7)["runtime"]["threshold"]
0.7
>>> data["runtime"]["threshold"]   # the input is not modified
0.55
"""

from __future__ import annotations

import copy
import itertools
import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from archself.errors import ArchselfError
from archself.model.architecture import Architecture
from archself.model.loader import dotted
from archself.model.messages import schema_findings

__all__ = [
    "CampaignError",
    "Sweep",
    "apply_values",
    "get_path",
    "parse_path",
    "parse_sweep",
    "set_path",
    "sweep_points",
]

Path_ = tuple[str | int, ...]

#: A sweep has at most this many values (the product of sweeps is capped by the driver).
MAX_VALUES = 10_000


class CampaignError(ArchselfError):
    """A campaign was asked for something impossible (bad PATH, sweep, results file)."""


_KEY = re.compile(r"[A-Za-z_$][A-Za-z0-9_$-]*")
_INDEX = re.compile(r"\[(-?\d+)\]")
_QUOTED = re.compile(r'\[("(?:[^"\\]|\\.)*")\]')


def parse_path(text: str) -> Path_:
    """Split a PATH into keys (str) and list indices (int).

    Raises
    ------
    CampaignError
        If the PATH is empty or malformed.

    Examples
    --------
    >>> parse_path('modules["left wheel"].params.side.value')
    ('modules', 'left wheel', 'params', 'side', 'value')
    """
    s = text.strip()
    if not s:
        raise CampaignError("sweep PATH is empty")
    out: list[str | int] = []
    i = 0
    expect_key = True  # at the start or after a dot
    while i < len(s):
        if s[i] == ".":
            if expect_key:
                raise CampaignError(f"sweep PATH {text!r}: empty key at position {i + 1}")
            expect_key = True
            i += 1
            continue
        if s[i] == "[":
            if expect_key and out:
                raise CampaignError(f"sweep PATH {text!r}: '[' right after '.' at position {i + 1}")
            m = _INDEX.match(s, i)
            if m:
                if not out:
                    raise CampaignError(f"sweep PATH {text!r}: must start with a key")
                out.append(int(m.group(1)))
            else:
                m = _QUOTED.match(s, i)
                if not m:
                    raise CampaignError(
                        f'sweep PATH {text!r}: expected [N] or ["key"] at position {i + 1}'
                    )
                out.append(json.loads(m.group(1)))
            i = m.end()
            expect_key = False
            continue
        if not expect_key:
            raise CampaignError(f"sweep PATH {text!r}: expected '.' or '[' at position {i + 1}")
        m = _KEY.match(s, i)
        if not m:
            raise CampaignError(f"sweep PATH {text!r}: bad key at position {i + 1}")
        out.append(m.group(0))
        i = m.end()
        expect_key = False
    if expect_key:
        raise CampaignError(f"sweep PATH {text!r}: ends with '.'")
    return tuple(out)


def _where(path: Path_, k: int) -> str:
    return dotted(path[: k + 1]) or "<root>"


def get_path(data: Any, path: Path_) -> Any:
    """The value at ``path`` in plain data (dicts and lists).

    Raises
    ------
    CampaignError
        If a key or index does not exist (with the closest known keys).
    """
    cur = data
    for k, p in enumerate(path):
        cur = _step(cur, p, path, k)
    return cur


def _step(cur: Any, p: str | int, path: Path_, k: int) -> Any:
    if isinstance(p, int):
        if not isinstance(cur, list):
            raise CampaignError(f"sweep PATH {_where(path, k)}: not a list")
        if not -len(cur) <= p < len(cur):
            raise CampaignError(
                f"sweep PATH {_where(path, k)}: index out of range "
                f"(the list has {len(cur)} item{'s' * (len(cur) != 1)})"
            )
        return cur[p]
    if not isinstance(cur, dict):
        raise CampaignError(f"sweep PATH {_where(path, k)}: not a mapping")
    if p not in cur:
        raise CampaignError(f"sweep PATH {_where(path, k)}: no such key{_hint(p, cur)}")
    return cur[p]


def _hint(key: str, mapping: dict[str, Any]) -> str:
    import difflib

    close = difflib.get_close_matches(key, [str(x) for x in mapping], n=1)
    if close:
        return f"; did you mean {close[0]!r}?"
    known = ", ".join(str(x) for x in list(mapping)[:8])
    return f"; known: {known}" if known else ""


def set_path(data: Any, path: Path_, value: Any) -> Any:
    """A deep copy of ``data`` with the value at ``path`` replaced by ``value``.

    Every key but the last must exist; the last key of a mapping may be new (the
    model then decides whether it is allowed). An integer value replaces an
    integer with an integral number as ``int``.

    Raises
    ------
    CampaignError
        If the PATH does not lead into the data.
    """
    if not path:
        raise CampaignError("sweep PATH is empty")
    out = copy.deepcopy(data)
    parent = get_path(out, path[:-1])
    last = path[-1]
    if isinstance(last, str) and isinstance(parent, dict):
        old = parent.get(last)  # a new key: the model decides
    else:
        old = _step(parent, last, path, len(path) - 1)
    parent[last] = _coerce(old, value)
    return out


def _coerce(old: Any, value: Any) -> Any:
    if isinstance(old, list | dict):
        raise CampaignError("sweep PATH must lead to a single value, not a list or mapping")
    if isinstance(old, int) and not isinstance(old, bool) and isinstance(value, float):
        if math.isfinite(value) and value == int(value) and abs(value) < 2**53:
            return int(value)
    return value


@dataclass(frozen=True)
class Sweep:
    """One swept value: its PATH (text and parsed) and the values it takes."""

    path: str
    keys: Path_
    values: tuple[float, ...]


def _number(text: str, what: str, spec: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise CampaignError(f"sweep {spec!r}: {what} {text!r} is not a number") from None
    if not math.isfinite(v):
        raise CampaignError(f"sweep {spec!r}: {what} must be finite")
    return v


def parse_sweep(spec: str) -> Sweep:
    """Parse ``PATH=START:STOP:NUM`` or ``PATH=V1,V2,...``.

    Raises
    ------
    CampaignError
        On a malformed specification.

    Examples
    --------
    >>> parse_sweep("scenarios.imu_drift.faults[0].magnitude=1e-4,7e-4").values
    (0.0001, 0.0007)
    """
    if "=" not in spec:
        raise CampaignError(f"sweep {spec!r}: expected PATH=START:STOP:NUM or PATH=V1,V2,...")
    path_text, _, rng = spec.partition("=")
    path_text = path_text.strip()
    keys = parse_path(path_text)
    rng = rng.strip()
    if ":" in rng:
        parts = rng.split(":")
        if len(parts) != 3:
            raise CampaignError(f"sweep {spec!r}: expected START:STOP:NUM")
        start = _number(parts[0], "START", spec)
        stop = _number(parts[1], "STOP", spec)
        try:
            num = int(parts[2])
        except ValueError:
            raise CampaignError(f"sweep {spec!r}: NUM {parts[2]!r} is not an integer") from None
        if num < 1:
            raise CampaignError(f"sweep {spec!r}: NUM must be at least 1")
        if num > MAX_VALUES:
            raise CampaignError(
                f"sweep {spec!r}: NUM {num:,} is more than the {MAX_VALUES:,} values a sweep "
                "may have"
            )
        if num == 1:
            values: tuple[float, ...] = (start,)
        else:
            step = (stop - start) / (num - 1)
            # rounded to 12 significant digits: 0.4:0.6:3 gives 0.5, not 0.49999999999999994
            values = tuple(float(f"{start + i * step:.12g}") for i in range(num))
    else:
        items = [x for x in rng.split(",") if x.strip()]
        if not items:
            raise CampaignError(f"sweep {spec!r}: no values")
        if len(items) > MAX_VALUES:
            raise CampaignError(f"sweep {spec!r}: more than {MAX_VALUES:,} values")
        values = tuple(_number(x.strip(), "value", spec) for x in items)
    if len(set(values)) != len(values):
        raise CampaignError(f"sweep {spec!r}: repeated values")
    return Sweep(path_text, keys, values)


def sweep_points(sweeps: Sequence[Sweep]) -> list[tuple[float, ...]]:
    """The product of the sweeps' values, in order (one empty point without sweeps)."""
    paths = [s.path for s in sweeps]
    if len(set(paths)) != len(paths):
        raise CampaignError("the same sweep PATH is given twice")
    return list(itertools.product(*(s.values for s in sweeps)))


def apply_values(
    data: dict[str, Any], sweeps: Sequence[Sweep], point: Sequence[float], file: str = "<campaign>",
    source: Any = None,
) -> Any:
    """Apply one sweep point to the plain data and validate the result through the model.

    ``source`` (the :class:`archself.io.yaml_source.SourceMap` of ``data``) locates a
    refused value in the file, as ``validate`` would.

    Returns
    -------
    archself.model.architecture.Architecture

    Raises
    ------
    CampaignError
        If a PATH does not lead into the data or the value is not allowed there.
    """
    from pydantic import ValidationError

    out = data
    for s, v in zip(sweeps, point, strict=True):
        out = set_path(out, s.keys, v)
    try:
        return Architecture.model_validate(out)
    except ValidationError as exc:
        err = exc.errors()[0]

        for s in sweeps:  # a new last key that the model refuses: most likely a typo
            parent = get_path(data, s.keys[:-1])
            last = s.keys[-1]
            fields = _model_keys(s.keys[:-1])
            if isinstance(parent, dict) and last not in parent and last not in fields:
                known = [*parent, *(k for k in fields if k not in parent)]
                raise CampaignError(
                    f"{file}: sweep PATH {s.path}: no such key"
                    f"{_hint(str(last), dict.fromkeys(known))}"
                ) from None

        setting = ", ".join(f"{s.path}={v:g}" for s, v in zip(sweeps, point, strict=True))
        if source is not None:  # located and worded as the loader's (not a union member's)

            found = schema_findings(out, exc, source)
            if found:
                raise CampaignError(f"{setting}: {found[0]}") from None
        where = dotted(tuple(err.get("loc", ()))) or "<root>"
        raise CampaignError(
            f"{file}: {setting}: {where}: {err.get('msg', 'invalid value')}"
        ) from None


def _model_keys(keys: Path_) -> list[str]:
    """The field names of the model class the data at ``keys`` validates to ([] if none).

    Walks :class:`archself.model.architecture.Architecture`'s annotations: a model's field, a dict's
    value type for a key, a list's item type for an index.
    """
    import typing

    from pydantic import BaseModel

    def models(tp: Any) -> list[Any]:
        """The classes a field's annotation may hold (Optional, Union, Annotated unwrapped)."""
        origin = typing.get_origin(tp)
        if origin is None:
            return [tp]
        if origin in (dict, list) or str(origin).endswith("Mapping") or origin is tuple:
            return [tp]
        return [m for a in typing.get_args(tp) for m in models(a)]

    current: list[Any] = [Architecture]
    for k in keys:
        nxt: list[Any] = []
        for tp in current:
            origin = typing.get_origin(tp)
            if isinstance(k, int):
                if origin in (list, tuple):
                    nxt += models(typing.get_args(tp)[0])
            elif origin is dict:
                nxt += models(typing.get_args(tp)[1])
            elif isinstance(tp, type) and issubclass(tp, BaseModel):
                alias = {f.alias or n: f for n, f in tp.model_fields.items()}
                field = alias.get(k)
                if field is not None:
                    nxt += models(field.annotation)
        current = nxt
    out: list[str] = []
    for tp in current:
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            out += [f.alias or n for n, f in tp.model_fields.items()]
    return out
