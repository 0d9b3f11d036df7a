"""The JSON documents' common ground: shared by :mod:`archself.io.jsondata` (read back)
and :mod:`archself.io.outdocs` (printed), which reach it here so that neither imports the
other at module level (jsondata builds the printed ones on first use).

Each name here is also ``archself.io.jsondata.<name>``.
"""

from __future__ import annotations

import typing
from typing import Any

from pydantic import BaseModel, ConfigDict, Field
from pydantic.functional_validators import PlainValidator
from pydantic.json_schema import WithJsonSchema

__all__ = ["ModuleFaultDoc", "Num", "RunDoc", "SwitchDoc", "json_kind"]


def json_kind(x: Any) -> str:
    """What a JSON value is, for a message: ``an object``, ``a list``, ``a string``, ``null``.

    Examples
    --------
    >>> json_kind({}), json_kind(None), json_kind(1.5)
    ('an object', 'null', 'float')
    """
    return {dict: "an object", list: "a list", str: "a string", type(None): "null"}.get(
        type(x), type(x).__name__)


def _number(v: Any) -> Any:
    if v is None or type(v) is float or type(v) is int:
        return v
    raise ValueError(f"expected a number, got {json_kind(v)}")


#: A number as it is (an int stays an int), or null (NaN as
#: :func:`archself.io.jsondata.jsonable` writes it).
Num = typing.Annotated[Any, PlainValidator(_number),
                       WithJsonSchema({"anyOf": [{"type": "number"}, {"type": "null"}]})]


class _Doc(BaseModel):
    """A JSON document archself writes and reads back: JSON types only (no coercion),
    other keys allowed; written in the order of its fields
    (:func:`archself.io.jsondata.document`)."""

    model_config = ConfigDict(strict=True, extra="allow", populate_by_name=True, defer_build=True)


class SwitchDoc(_Doc):
    """One switch of the architecture: when, from and to which configuration, by which
    action of which module."""

    t_s: float
    from_: str | None = Field(None, alias="from")
    to: str | None = None
    action: str | None = None
    module: str | None = None


class ModuleFaultDoc(_Doc):
    """A module unavailable while active, for one reason: when first and last, for how
    many steps (one of :attr:`archself.sim.result.RunResult.faults`)."""

    module: str
    reason: str = Field(description="why, without a running count: 'raised RuntimeError', "
                        "'non-finite output', 'silent', 'stale <signal>', 'lost input <signal>'")
    first_s: float
    last_s: float
    steps: int


def _empty(v: Any) -> bool:
    return not v


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
    faults: list[ModuleFaultDoc] = Field(
        [], exclude_if=_empty,
        description="the modules that were unavailable while active, in the order first "
                    "seen; left out when there were none (and in a trace written before "
                    "runs reported them): read a missing key as []")
