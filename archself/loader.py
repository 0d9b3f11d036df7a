"""Load architecture files: YAML 1.2 with source positions, then the pydantic model.

The loader reads with ruamel.yaml's round-trip parser (YAML 1.2 scalars: only
``true``/``false`` are booleans, ``1e-3`` is a float), rejects duplicate keys,
caps the file size, the nesting depth and the number of aliases (an alias bomb
is refused while it is being composed, never expanded), and records the
``line:col`` of every key and value. Schema violations are reported at the
position of the offending node with its dotted path and what was expected,
with a "did you mean" hint for misspelt keys.

Examples
--------
>>> from archself.loader import load_text
>>> loaded = load_text("archself: 1\\nname: x\\n", "x.yaml")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
archself.loader.SchemaError: x.yaml:1:1: missing required key 'modules' ...
"""

from __future__ import annotations

import difflib
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from archself.errors import LoadError
from archself.findings import Finding

MAX_FILE_BYTES = 20 * 1024 * 1024
MAX_ALIASES = 64
MAX_DEPTH = 64
MAX_NODES = 5_000_000

Path_ = tuple[str | int, ...]
_PLAIN_KEY = re.compile(r"^[A-Za-z_$][A-Za-z0-9_$-]*$")


class SchemaError(LoadError):
    """The file parsed but does not match the schema; ``findings`` holds every violation."""

    def __init__(self, findings: list[Finding]) -> None:
        self.findings = findings
        f = findings[0]
        super().__init__(f.message, f.file, f.line, f.col, f.path)


@dataclass
class SourceMap:
    """Positions (1-based line, column) of the nodes of a loaded file."""

    file: str
    keys: dict[Path_, tuple[int, int]] = field(default_factory=dict)
    values: dict[Path_, tuple[int, int]] = field(default_factory=dict)

    def locate(self, path: Path_, *, key: bool = True) -> tuple[int | None, int | None]:
        """Position of ``path``: the key (or value), else the nearest enclosing node."""
        p = tuple(path)
        while True:
            table = (self.keys, self.values) if key else (self.values, self.keys)
            for t in table:
                if p in t:
                    return t[p]
            if not p:
                return (None, None)
            p = p[:-1]


@dataclass
class Loaded:
    """An architecture loaded from a file, with the positions of its nodes."""

    arch: Any  # archself.model.Architecture
    source: SourceMap
    data: dict[str, Any]

    @property
    def file(self) -> str:
        return self.source.file


def dotted(path: Path_) -> str:
    """``('edges', 3, 'from')`` → ``edges[3].from``."""
    out = ""
    for p in path:
        if isinstance(p, int):
            out += f"[{p}]"
        elif _PLAIN_KEY.match(str(p)):
            out += ("." if out else "") + str(p)
        else:
            out += "[" + json.dumps(str(p), ensure_ascii=False) + "]"
    return out


# --------------------------------------------------------------------------- YAML
def _yaml():
    from ruamel.yaml import YAML
    from ruamel.yaml.composer import Composer

    class _CappedComposer(Composer):
        aliases = 0

        def return_alias(self, a: Any) -> Any:
            self.aliases += 1
            if self.aliases > MAX_ALIASES:
                from ruamel.yaml.error import MarkedYAMLError

                raise MarkedYAMLError(
                    problem=f"more than {MAX_ALIASES} aliases (refused: possible alias bomb)",
                    problem_mark=getattr(a, "start_mark", None),
                )
            return a

    y = YAML(typ="rt", pure=True)
    y.version = (1, 2)
    y.allow_duplicate_keys = False
    y.max_depth = MAX_DEPTH
    y.Composer = _CappedComposer
    return y


def _parse(text: str, file: str) -> Any:
    from ruamel.yaml.error import MarkedYAMLError, YAMLError

    try:
        return _yaml().load(text)
    except MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else None
        col = mark.column + 1 if mark is not None else None
        problem = (exc.problem or exc.context or "invalid YAML").strip()
        if "\t" in problem or "'\\t'" in problem:
            problem = "tab character: YAML indentation must use spaces"
        elif "duplicate key" in problem:
            problem = problem.replace('found duplicate key "', "duplicate key '").split('"')[0]
            problem += "' (each key may appear once in a mapping)"
        problem = problem.splitlines()[0]
        raise LoadError(f"invalid YAML: {problem}", file, line, col) from None
    except YAMLError as exc:  # unmarked ruamel errors
        raise LoadError(f"invalid YAML: {str(exc).splitlines()[0]}", file) from None
    except RecursionError:
        raise LoadError("invalid YAML: nesting too deep", file) from None


def _plain(node: Any, path: Path_, src: SourceMap, counter: list[int]) -> Any:
    """Convert ruamel round-trip nodes to plain Python, recording positions."""
    from ruamel.yaml.comments import CommentedMap, CommentedSeq
    from ruamel.yaml.scalarbool import ScalarBoolean

    counter[0] += 1
    if counter[0] > MAX_NODES:
        raise LoadError(f"document expands to more than {MAX_NODES} nodes", src.file)
    if isinstance(node, CommentedMap):
        out: dict[Any, Any] = {}
        for k, v in node.items():
            key = k if isinstance(k, str) else _plain(k, path, src, counter)
            p = (*path, key)
            try:
                kl, kc = node.lc.key(k)
                src.keys[p] = (kl + 1, kc + 1)
                vl, vc = node.lc.value(k)
                src.values[p] = (vl + 1, vc + 1)
            except (KeyError, TypeError, AttributeError):
                pass
            out[key] = _plain(v, p, src, counter)
        return out
    if isinstance(node, CommentedSeq):
        items = []
        for i, v in enumerate(node):
            p = (*path, i)
            try:
                line, col = node.lc.item(i)
                src.keys[p] = src.values[p] = (line + 1, col + 1)
            except (KeyError, TypeError, AttributeError):
                pass
            items.append(_plain(v, p, src, counter))
        return items
    if isinstance(node, ScalarBoolean):
        return bool(node)
    if isinstance(node, bool) or node is None:
        return node
    if isinstance(node, int):
        return int(node)
    if isinstance(node, float):
        return float(node)
    if isinstance(node, str):
        return str(node)
    if hasattr(node, "value") and hasattr(node, "tag"):  # TaggedScalar: never constructed
        return str(node.value)
    # dates, sets and other YAML types are not part of the format
    return repr(node)


def read_text(path: str | Path, max_bytes: int = MAX_FILE_BYTES) -> str:
    """Read a file as UTF-8 with a size cap; errors become :class:`LoadError`."""
    p = Path(path)
    file = str(path)
    try:
        size = p.stat().st_size
    except FileNotFoundError:
        raise LoadError("no such file", file) from None
    except OSError as exc:
        raise LoadError(f"cannot read: {exc.strerror}", file) from None
    if p.is_dir():
        raise LoadError("is a directory, expected an architecture file", file)
    if size > max_bytes:
        raise LoadError(f"file is {size} bytes, larger than the {max_bytes}-byte cap", file)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise LoadError(f"cannot read: {exc.strerror}", file) from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise LoadError("not UTF-8 text", file, line, 1) from None


def load_data(text: str, file: str = "<input>") -> tuple[dict[str, Any], SourceMap]:
    """Parse YAML text into plain data and a :class:`SourceMap`."""
    if len(text.encode("utf-8", "surrogatepass")) > MAX_FILE_BYTES:
        raise LoadError(f"document larger than the {MAX_FILE_BYTES}-byte cap", file)
    node = _parse(text, file)
    src = SourceMap(file)
    if node is None:
        raise LoadError(
            "file is empty; expected a mapping with keys archself, name, modules, "
            "configurations, runtime",
            file,
            1,
            1,
        )
    data = _plain(node, (), src, [0])
    if not isinstance(data, dict):
        raise LoadError(
            f"expected a mapping at the top level, got {_kind(data)}", file, 1, 1
        )
    return data, src


# --------------------------------------------------------------------------- schema errors
def _kind(v: Any) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return f"boolean {str(v).lower()}"
    if isinstance(v, (int, float)):
        if isinstance(v, float) and not math.isfinite(v):
            return f"{v!r}".replace("inf", ".inf").replace("nan", ".nan")
        return f"number {v!r}"
    if isinstance(v, str):
        s = v if len(v) <= 40 else v[:37] + "..."
        return f"string {json.dumps(s, ensure_ascii=False)}"
    if isinstance(v, list):
        return "a list"
    if isinstance(v, dict):
        return "a mapping"
    return type(v).__name__


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
        if alts:
            return [r for a in alts for r in resolve(a)]
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


def _message(err: dict[str, Any], value: Any, schema: dict[str, Any], parent: Path_) -> str:
    typ = err["type"]
    ctx = err.get("ctx", {}) or {}
    if typ in _EXPECT:
        return f"expected {_EXPECT[typ]}, got {_kind(value)}"
    if typ == "literal_error":
        exp = ctx.get("expected", "")
        hint = ""
        if isinstance(value, str):
            opts = [o.strip().strip("'") for o in exp.replace(" or ", ", ").split(",")]
            close = difflib.get_close_matches(value, opts, n=1)
            if close:
                hint = f"; did you mean '{close[0]}'?"
        return f"expected {exp}, got {_kind(value)}{hint}"
    if typ in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        sym = {"greater_than": ">", "greater_than_equal": "≥", "less_than": "<",
               "less_than_equal": "≤"}[typ]
        bound = next(iter(ctx.values()), "?")
        return f"expected a number {sym} {bound}, got {_kind(value)}"
    if typ in ("too_short", "too_long"):
        return f"{err['msg'].lower()}"
    if typ == "string_pattern_mismatch":
        return f"expected a name without control characters, got {_kind(value)}"
    if typ == "string_too_short":
        return "expected a non-empty string"
    if typ == "string_too_long":
        return f"expected at most {ctx.get('max_length')} characters"
    if typ == "union_tag_invalid":
        return (
            f"expected {ctx.get('discriminator')} to be one of {ctx.get('expected_tags')}, "
            f"got {_kind(ctx.get('tag'))}"
        )
    if typ == "union_tag_not_found":
        return f"missing required key {ctx.get('discriminator')}"
    if typ == "value_error":
        return str(ctx.get("error", err["msg"])).removeprefix("Value error, ")
    return err["msg"][:1].lower() + err["msg"][1:]


def schema_findings(data: dict[str, Any], exc: Any, src: SourceMap) -> list[Finding]:
    """Turn a pydantic ``ValidationError`` into located findings, one per data path."""
    from archself.schema import architecture_schema

    schema = architecture_schema()
    grouped: dict[tuple[Path_, str | None], list[dict[str, Any]]] = {}
    for err in exc.errors(include_url=False):
        loc = tuple(err["loc"])
        if err["type"] == "extra_forbidden" and loc:
            path, _, _ = _data_path(data, loc[:-1])
            key = (path, str(loc[-1]))
        else:
            path, value, absent = _data_path(data, loc)
            key = (path, value if absent else None)
        grouped.setdefault(key, []).append(err)

    findings: list[Finding] = []
    for (path, absent_key), errs in grouped.items():
        if absent_key is not None:
            err = errs[0]
            if err["type"] == "extra_forbidden":
                allowed = _schema_keys(schema, path)
                close = difflib.get_close_matches(absent_key, sorted(allowed), n=1)
                hint = f"; did you mean '{close[0]}'?" if close else ""
                if not close and allowed:
                    hint = "; expected one of: " + ", ".join(sorted(allowed))
                msg = f"unknown key '{absent_key}'{hint}"
                line, col = src.locate((*path, absent_key))
                findings.append(Finding("error", "schema", msg, dotted((*path, absent_key)),
                                        src.file, line, col))
            else:
                msg = f"missing required key '{absent_key}'"
                line, col = src.locate(path)
                findings.append(Finding("error", "schema", msg, dotted(path), src.file, line, col))
            continue
        value = _value_at(data, path)
        if len(errs) == 1:
            msg = _message(errs[0], value, schema, path)
        else:
            # a union: every member failed. Prefer a member error deeper than a type mismatch.
            exp = sorted({_EXPECT.get(e["type"], "") for e in errs} - {""})
            specific = [e for e in errs if e["type"] not in _EXPECT]
            if isinstance(value, float) and not math.isfinite(value):
                msg = f"expected a finite number, got {_kind(value)}"
            elif specific:
                msg = _message(specific[0], value, schema, path)
            else:
                msg = f"expected {' or '.join(exp)}, got {_kind(value)}"
        line, col = src.locate(path, key=False)
        findings.append(Finding("error", "schema", msg, dotted(path), src.file, line, col))
    findings.sort(key=lambda f: (f.line or 0, f.col or 0))
    return findings


def _value_at(data: Any, path: Path_) -> Any:
    cur = data
    for p in path:
        cur = cur[p]
    return cur


# --------------------------------------------------------------------------- API
def load_text(text: str, file: str = "<input>") -> Loaded:
    """Load an architecture from YAML text.

    Raises
    ------
    LoadError
        On unreadable YAML (with the position of the problem).
    SchemaError
        When the document does not match the schema (every violation in ``findings``).
    """
    from pydantic import ValidationError

    from archself.model import Architecture

    data, src = load_data(text, file)
    try:
        arch = Architecture.model_validate(data)
    except ValidationError as exc:
        raise SchemaError(schema_findings(data, exc, src)) from None
    except RecursionError:
        raise LoadError("document nested too deeply", file) from None
    return Loaded(arch, src, data)


def load_architecture(path: str | Path) -> Loaded:
    """Load and schema-check the architecture file at ``path``.

    Examples
    --------
    >>> from archself.resources import data_dir
    >>> loaded = load_architecture(data_dir("architectures") / "diffdrive.yaml")
    >>> loaded.arch.initial_configuration()
    'a1'
    """
    return load_text(read_text(path), str(path))
