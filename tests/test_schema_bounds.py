"""The schema's bounds say what the field descriptions say (issue 40).

Editors and check-jsonschema read ``minimum``/``maximum``/``exclusive*`` of
``schemas/architecture.schema.json``; a person reads the description. Every numeric
field whose description states a bound of its own value — ``≥ x``, ``> x``, ``≤ x``,
``< x`` standing alone (after a comma or an opening bracket, not after a formula),
"non-negative", "positive", "in [a, b]" — must carry that bound in the schema.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterator
from typing import Any

import pytest

from archself.model.schema import architecture_schema

from conftest import ROOT

_NUM = r"(-?\d+(?:\.\d+)?(?:e-?\d+)?)"
#: A bound of the field itself: the relation opens a clause, its right side is a number.
_REL = re.compile(r"(?:^|[,(;:]\s*)([≥≤<>])\s*" + _NUM + r"\s*(?=[(),;.]|$)")
_RANGE = re.compile(r"\bin ([\[(])" + _NUM + r",\s*" + _NUM + r"([\])])")
_WORDS = {"non-negative": ("minimum", 0.0), "positive": ("exclusiveMinimum", 0.0)}


def _numeric(node: dict[str, Any]) -> dict[str, Any] | None:
    """The number branch of a field (itself, or its anyOf alternative), or None."""
    for alt in (node, *node.get("anyOf", ())):
        if alt.get("type") in ("number", "integer"):
            return alt
    return None


def _fields(schema: dict[str, Any]) -> Iterator[tuple[str, str, dict[str, Any]]]:
    for name, model in schema.get("$defs", {}).items():
        for field, node in model.get("properties", {}).items():
            number = _numeric(node)
            if number is not None and node.get("description"):
                yield f"{name}.{field}", node["description"], number


def stated_bounds(text: str) -> list[tuple[str, float]]:
    """``(schema keyword, value)`` of every bound ``text`` states of its field.

    Examples
    --------
    >>> stated_bounds("Influence ω_ji of m_j on m_i, ≥ 0 (Eq. 13).")
    [('minimum', 0.0)]
    >>> stated_bounds("Probability in [0, 1).")
    [('minimum', 0.0), ('exclusiveMaximum', 1.0)]
    >>> stated_bounds("C(a, θ, e) ≤ 0: a formula, not a bound of the field")
    []
    """
    out: list[tuple[str, float]] = []
    keyword = {"≥": "minimum", ">": "exclusiveMinimum", "≤": "maximum", "<": "exclusiveMaximum"}
    for rel, value in _REL.findall(text):
        out.append((keyword[rel], float(value)))
    for lo_b, lo, hi, hi_b in _RANGE.findall(text):
        out.append(("minimum" if lo_b == "[" else "exclusiveMinimum", float(lo)))
        out.append(("maximum" if hi_b == "]" else "exclusiveMaximum", float(hi)))
    for word, bound in _WORDS.items():
        if re.search(rf"(?<![\w-]){word}\b", text):
            out.append(bound)
    return out


def _holds(number: dict[str, Any], keyword: str, value: float) -> bool:
    """The schema states ``keyword value`` or a tighter bound of the same side."""
    lo = keyword in ("minimum", "exclusiveMinimum")
    strict = keyword.startswith("exclusive")
    for key in (("minimum", "exclusiveMinimum") if lo else ("maximum", "exclusiveMaximum")):
        have = number.get(key)
        if have is None:
            continue
        tighter = have > value if lo else have < value
        same = math.isclose(have, value) and (key.startswith("exclusive") or not strict)
        if tighter or same:
            return True
    return False


def test_the_bound_reader_finds_what_a_description_states() -> None:
    assert stated_bounds("Nominal noise level (≥ 1e-12).") == [("minimum", 1e-12)]
    assert stated_bounds("A positive time.") == [("exclusiveMinimum", 0.0)]
    assert stated_bounds("A non-negative count.") == [("minimum", 0.0)]
    assert stated_bounds("r_i of the module > this.") == []


def test_every_stated_bound_is_in_the_schema() -> None:
    wrong = []
    checked = 0
    for where, text, number in _fields(architecture_schema(installed=False)):
        for keyword, value in stated_bounds(text):
            checked += 1
            if not _holds(number, keyword, value):
                got = {k: number[k] for k in ("minimum", "maximum", "exclusiveMinimum",
                                             "exclusiveMaximum") if k in number}
                wrong.append(f"{where}: says {keyword} {value:g}, the schema has {got}")
    assert checked >= 2, "no field states a bound: the reader found nothing to compare"
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("weight", [-0.2, -1e-9])
def test_checked_in_schema_refuses_a_negative_weight(weight) -> None:
    schema = json.loads((ROOT / "schemas" / "architecture.schema.json").read_text("utf-8"))
    edge = schema["$defs"]["Edge"]["properties"]["weight"]
    assert edge["minimum"] == 0 and not _holds({"minimum": weight}, "minimum", 0.0)
