"""Schema violations as located findings: a pydantic error → ``file:line:col: path: message``.

Each violation is reported at the position of the offending node (found in the
:class:`~archself.io.yaml_source.SourceMap`), with its dotted path and what was
expected; a misspelt key gets a "did you mean" hint from the schema's property
names, a misspelt literal one from the allowed values. Errors of one data path
(the members of a union) are folded into one finding.

Examples
--------
>>> from archself.model.loader import SchemaError, load_text
>>> try:
...     load_text("archself: 1\\nname: x\\nmodules: 3\\n", "x.yaml")
... except SchemaError as err:
...     print(next(f for f in err.findings if f.path == "modules"))
x.yaml:3:10: error: modules: expected a mapping, got number 3
"""

from __future__ import annotations

import difflib
import functools
import math
from typing import Any

from archself.findings import Finding
from archself.io.yaml_source import Path_, SourceMap, describe, dotted

__all__ = ["schema_findings"]


def _data_path(data: Any, loc: tuple[Any, ...]) -> tuple[Path_, Any, bool]:
    """Follow a pydantic error location through the data, skipping union member tags.

    Returns the data path, the value found there and whether the last loc item
    was a key absent from the data (a missing or an unknown key).
    """
    path: list[str | int] = []
    cur = data
    for i, item in enumerate(loc):
        last = i == len(loc) - 1
        if isinstance(cur, dict) and item in cur:
            path.append(item)
            cur = cur[item]
        elif isinstance(cur, list) and isinstance(item, int) and 0 <= item < len(cur):
            path.append(item)
            cur = cur[item]
        elif last and isinstance(cur, dict) and isinstance(item, str):
            return tuple(path), item, True
        # else: a union member name or a tag: not part of the data
    return tuple(path), cur, False


def _schema_keys(schema: dict[str, Any], path: Path_) -> set[str]:
    """Property names the schema allows for the mapping at ``path``."""
    defs = schema.get("$defs", {})

    def resolve(s: dict[str, Any]) -> list[dict[str, Any]]:
        if "$ref" in s:
            return resolve(defs[s["$ref"].split("/")[-1]])
        alts = s.get("anyOf") or s.get("oneOf")
        if alts:  # a union, or a model with alternative constraints beside its properties
            return [s, *(r for a in alts for r in resolve(a))]
        return [s]

    nodes = resolve(schema)
    for item in path:
        nxt: list[dict[str, Any]] = []
        for s in nodes:
            if isinstance(item, int):
                if "items" in s:
                    nxt += resolve(s["items"])
            else:
                if item in s.get("properties", {}):
                    nxt += resolve(s["properties"][item])
                elif isinstance(s.get("additionalProperties"), dict):
                    nxt += resolve(s["additionalProperties"])
                for sub in s.get("patternProperties", {}).values():
                    nxt += resolve(sub)
        nodes = nxt
    return {k for s in nodes for k in s.get("properties", {})}


_EXPECT = {
    "float_type": "a number",
    "float_parsing": "a number",
    "int_type": "an integer",
    "int_parsing": "an integer",
    "int_from_float": "an integer",
    "string_type": "a string",
    "bool_type": "true or false",
    "bool_parsing": "true or false",
    "list_type": "a list",
    "tuple_type": "a list",
    "dict_type": "a mapping",
    "model_type": "a mapping",
    "model_attributes_type": "a mapping",
    "finite_number": "a finite number",
}

_COMPARE = {"greater_than": ">", "greater_than_equal": "≥", "less_than": "<",
            "less_than_equal": "≤"}


@functools.cache
def _bound_reasons() -> dict[float, str]:
    from archself.model import architecture as model

    return {
        model.MAX_MAGNITUDE: " (no number of a file is larger: docs/format.md, Ranges)",
        model.MAX_TIME_S: " (the longest time a file states, about 116 days)",
        model.MIN_STEP_S: " (the shortest step or period, 1 µs)",
        model.MAX_STEP_S: " (the longest step, 1 h)",
        model.MIN_SCALE: " (the smallest scale a residual is divided by)",
    }


def _message(err: dict[str, Any], value: Any) -> str:
    typ = err["type"]
    ctx = err.get("ctx", {}) or {}
    if typ in _EXPECT:
        return f"expected {_EXPECT[typ]}, got {describe(value)}"
    if typ == "literal_error":
        exp = ctx.get("expected", "")
        hint = ""
        if isinstance(value, str):
            opts = [o.strip().strip("'") for o in exp.replace(" or ", ", ").split(",")]
            close = difflib.get_close_matches(value, opts, n=1)
            if close:
                hint = f"; did you mean '{close[0]}'?"
        return f"expected {exp}, got {describe(value)}{hint}"
    if typ in _COMPARE:
        bound = next(iter(ctx.values()), "?")
        why = ""
        if isinstance(bound, float) and not bound.is_integer() or (
                isinstance(bound, (int, float)) and abs(bound) >= 1e5):
            why = _bound_reasons().get(float(bound), "")
            bound = f"{bound:g}"
        return f"expected a number {_COMPARE[typ]} {bound}{why}, got {describe(value)}"
    if typ in ("too_short", "too_long"):
        return str(err["msg"]).lower()
    if typ == "string_pattern_mismatch":
        return f"expected a name without control characters, got {describe(value)}"
    if typ == "string_too_short":
        return "expected a non-empty string"
    if typ == "string_too_long":
        return f"expected at most {ctx.get('max_length')} characters"
    if typ == "union_tag_invalid":
        return (
            f"expected {ctx.get('discriminator')} to be one of {ctx.get('expected_tags')}, "
            f"got {describe(ctx.get('tag'))}"
        )
    if typ == "union_tag_not_found":
        return f"missing required key {ctx.get('discriminator')}"
    if typ == "value_error":
        return str(ctx.get("error", err["msg"])).removeprefix("Value error, ")
    return err["msg"][:1].lower() + err["msg"][1:]


def schema_findings(data: dict[str, Any], exc: Any, src: SourceMap) -> list[Finding]:
    """Turn a pydantic ``ValidationError`` into located findings, one per data path."""
    from archself.model.schema import architecture_schema

    schema = architecture_schema(installed=False)
    grouped: dict[tuple[Path_, Any], list[dict[str, Any]]] = {}
    for err in _deepest_union_branches(data, exc.errors(include_url=False)):
        loc = tuple(err["loc"])
        key: tuple[Path_, Any]
        if err["type"] == "extra_forbidden" and loc:
            path, _, _ = _data_path(data, loc[:-1])
            key = (path, str(loc[-1]))
        else:
            path, value, absent = _data_path(data, loc)
            key = (path, value if absent else None)
        grouped.setdefault(key, []).append(err)

    findings: list[Finding] = []
    for (path, absent_key), errs in grouped.items():
        where, at_key = path, True  # located at the key, except a wrong value
        if absent_key is not None and errs[0]["type"] == "extra_forbidden":
            allowed = sorted(_schema_keys(schema, path))
            close = difflib.get_close_matches(absent_key, allowed, n=1)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            if not close and allowed:
                hint = "; expected one of: " + ", ".join(allowed)
            msg = f"unknown key '{absent_key}'{hint}"
            where = (*path, absent_key)
        elif absent_key is not None:
            msg = f"missing required key '{absent_key}'"
        else:
            msg, at_key = _value_message(data, path, errs), False
        line, col = src.locate(where, key=at_key)
        findings.append(Finding("error", "schema", msg, dotted(where), src.file, line, col))
    findings.sort(key=lambda f: (f.line or 0, f.col or 0))
    return findings


def _value_message(data: Any, path: Path_, errs: list[dict[str, Any]]) -> str:
    """The message of the errors of one value (the members of a union folded into one)."""
    _, value, _ = _data_path(data, path)
    if len(errs) == 1:
        return _message(errs[0], value)
    # a union: every member failed. Prefer a member error deeper than a type mismatch.
    specific = [e for e in errs if e["type"] not in _EXPECT]
    if isinstance(value, float) and not math.isfinite(value):
        return f"expected a finite number, got {describe(value)}"
    if specific:
        return _message(specific[0], value)
    exp = sorted({_EXPECT[e["type"]] for e in errs})
    return f"expected {' or '.join(exp)}, got {describe(value)}"


def _union_tag_index(data: Any, loc: tuple[Any, ...]) -> int | None:
    """Index in ``loc`` of the first union-member tag (a loc item that is not in the data)."""
    node = data
    for i, item in enumerate(loc):
        if isinstance(node, dict) and item in node:
            node = node[item]
        elif isinstance(item, int) and isinstance(node, list) and 0 <= item < len(node):
            node = node[item]
        elif isinstance(item, str):
            return i
        else:
            return None
    return None


def _deepest_union_branches(data: Any, errors: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Keep, for each union that failed, only the member(s) that got deepest into the value.

    When every member of a union fails, pydantic reports each member's errors: for a
    list of points with one NaN that is "not a number" for the scalar members, "not a
    number" for each point under ``list[float]`` and "not finite" for the one bad
    coordinate under ``list[list[float]]``. The member whose error lies deepest is the
    one the value was meant to be; its errors alone are reported.
    """
    tagged = []
    for e in errors:
        loc = tuple(e["loc"])
        tagged.append((e, loc, _union_tag_index(data, loc)))
    best: dict[tuple[Any, ...], int] = {}
    for _, loc, i in tagged:
        if i is not None:
            best[loc[:i]] = max(best.get(loc[:i], 0), len(loc) - i - 1)
    keep_branch: dict[tuple[Any, ...], set[Any]] = {}
    for _, loc, i in tagged:
        if i is not None and len(loc) - i - 1 == best[loc[:i]]:
            keep_branch.setdefault(loc[:i], set()).add(loc[i])
    return [e for e, loc, i in tagged
            if i is None or best[loc[:i]] == 0 or loc[i] in keep_branch[loc[:i]]]
