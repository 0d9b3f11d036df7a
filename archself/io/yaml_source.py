"""YAML 1.2 text → plain data, with the source position of every node on demand.

The node graph is composed with ruamel.yaml (its libyaml-backed parser when
``ruamel.yaml.clib`` is installed) and scalars are resolved here by the YAML 1.2
core schema (only ``true``/``false`` are booleans, ``1e-3`` is a float, ``yes`` and
``on`` are strings). Duplicate keys and unknown tags are rejected; the file size,
the nesting depth, the node count and the alias uses are capped (aliases stay
shared in the node graph, so an alias bomb is refused before anything is
expanded). The node graph is kept in a :class:`SourceMap`, so that the
``line:col`` of any key or value is found when a message needs it (nothing is
recorded per node: a 10,000-module file converts in a fraction of a second; plain
scalars are resolved once per distinct text).

Size caps follow one rule: a file must load in about ten seconds on a slow
machine. libyaml through Python composes about 1 MB of YAML a second, so YAML
text is capped at :data:`MAX_YAML_BYTES` (8 MiB); a document that is JSON (YAML
1.2 includes JSON; comment lines are allowed) is parsed by the :mod:`json`
module, about 50 times faster, and capped at :data:`MAX_FILE_BYTES` (64 MiB).
``archself generate`` writes JSON-compatible YAML, so its 10^5-module files load
as JSON; their positions are composed from the text only when a message needs
one. Only regular files are read: a FIFO, a socket or a device is refused before
it is opened for reading (a FIFO would block the reader forever).

:mod:`archself.model.loader` builds the architecture model on top of this module;
:mod:`archself.model.messages` turns schema violations into located findings. The
node graph and its conversion are below, reading a file in :mod:`archself.io.files`
(``read_text`` and its cap are re-exported here).

Examples
--------
>>> data, src = load_data("a:\\n  b: [1, 2.5, yes]\\n", "x.yaml")
>>> data
{'a': {'b': [1, 2.5, 'yes']}}
>>> src.locate(("a", "b", 1), key=False)
(2, 10)
>>> dotted(("edges", 3, "from"))
'edges[3].from'

The YAML 1.2 node graph: composed by ruamel.yaml, scalars resolved by the core schema.

:func:`parse` composes the node graph (libyaml-backed when ``ruamel.yaml.clib`` is
present; aliases stay shared, nothing is expanded) with located errors;
:func:`scalar` resolves a scalar by the YAML 1.2 core schema (only ``true``/``false``
are booleans, ``yes`` is a string; explicit tags honoured); :class:`Converter` turns
the graph into plain Python with the duplicate-key, alias (:data:`MAX_ALIASES`),
depth (:data:`MAX_DEPTH`) and node-count (:data:`MAX_NODES`) checks.

The composer recurses in C once per nesting level: 30,000 nested brackets (60 KB)
overflowed its stack (SIGSEGV), and a list of 900,000 waypoints took 1.33 GB of
nodes before the model refused it. So :func:`parse` first bounds both on the text
and, when that bound is not enough, on the parser's event stream (no recursion, no
node kept): deeper than :data:`MAX_DEPTH` or more than :data:`MAX_COMPOSED` nodes is
a located error before anything is composed.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from typing import Any

from archself.errors import LoadError
from archself.io.files import MAX_FILE_BYTES, read_text

__all__ = [
    "Converter", "MAX_ALIASES", "MAX_COMPOSED", "MAX_DEPTH", "MAX_FILE_BYTES",
    "MAX_INT_DIGITS", "MAX_NODES", "MAX_YAML_BYTES", "Path_", "SourceMap", "describe",
    "dotted", "is_scalar", "load_data", "mark", "parse", "read_text", "scalar",
    "text_position"
]


MAX_ALIASES = 64
MAX_DEPTH = 64
#: Nodes of the converted data (aliases counted at every use).
MAX_NODES = 5_000_000
#: Nodes composed from YAML text (about 490 bytes each with the model: 490 MB for 10^6;
#: the 2.7 million of 900,000 waypoints took 1.33 GB before the model refused them).
MAX_COMPOSED = 500_000
#: Digits of an integer (Python refuses to convert longer ones: ``sys.int_info``).
MAX_INT_DIGITS = 4300
#: Below this many structure indicators (``[{-?:``) the text cannot nest deeper than
#: the composer's stack allows (it overflowed between 20,000 and 30,000 levels) nor
#: hold :data:`MAX_COMPOSED` collections: it is composed without the event pre-scan.
_PRESCAN_FROM = 10_000
#: Characters YAML 1.2 does not allow in a stream (C0 and C1 controls, surrogates, ...).
_UNPRINTABLE = re.compile(
    "[^\x09\x0A\x0D\x20-\x7E\x85\xA0-\uD7FF\uE000-\uFFFD\U00010000-\U0010FFFF]")


def mark(node: Any) -> tuple[int, int]:
    """The 1-based (line, column) where ``node`` starts."""
    m = node.start_mark
    return (m.line + 1, m.column + 1)


def is_scalar(node: Any) -> bool:
    """Whether ``node`` is a scalar node."""
    from ruamel.yaml.nodes import ScalarNode

    return isinstance(node, ScalarNode)


_PLAIN_TAG = "tag:archself,2026:plain"
_PLAIN: Any = None


def _composer():
    """A ruamel.yaml loader that tags no plain scalar implicitly (YAML 1.2)."""
    from ruamel.yaml import YAML
    from ruamel.yaml.nodes import MappingNode, ScalarNode
    from ruamel.yaml.resolver import VersionedResolver

    class _PlainResolver(VersionedResolver):  # type: ignore[misc]
        """Tag nothing implicitly: :func:`_scalar` applies the YAML 1.2 core schema."""

        def __init__(self, version: Any = None, loader: Any = None,
                     loadumper: Any = None) -> None:  # the libyaml composer's or the pure one's
            super().__init__(version, loader, loadumper)

        def resolve(self, kind: Any, value: Any, implicit: Any) -> Any:
            if kind is ScalarNode:
                return _PLAIN if implicit[0] else self.DEFAULT_SCALAR_TAG
            if kind is MappingNode:
                return self.DEFAULT_MAPPING_TAG
            return self.DEFAULT_SEQUENCE_TAG

    global _PLAIN
    if _PLAIN is None:
        from ruamel.yaml.tag import Tag

        _PLAIN = Tag(suffix=_PLAIN_TAG)
    y = YAML(typ="safe", pure=False)  # libyaml-based parser when ruamel.yaml.clib is present
    y.version = (1, 2)
    y.Resolver = _PlainResolver  # plain scalars are resolved here, by the YAML 1.2 core schema
    return y


def text_position(text: str, index: int) -> tuple[int, int]:
    """The 1-based (line, column) of character ``index`` of ``text``.

    Examples
    --------
    >>> text_position("ab\\ncd", 4)
    (2, 2)
    """
    line = text.count("\n", 0, index) + 1
    return line, index - (text.rfind("\n", 0, index) + 1) + 1


def _prescan(text: str, file: str) -> None:
    """Refuse a document nested deeper than :data:`MAX_DEPTH` or of more than
    :data:`MAX_COMPOSED` nodes, located, before it is composed.

    Every collection starts at an indicator ``[``, ``{``, ``-``, ``?`` or ``:``, so
    their count bounds both the depth and the collections; only above
    :data:`_PRESCAN_FROM` are the parser's events counted (a flat pass in C, about a
    third of the time of composing).
    """
    if sum(text.count(c) for c in "[{-?:") < _PRESCAN_FROM and len(text) < MAX_COMPOSED:
        return
    from ruamel.yaml.events import (
        AliasEvent,
        CollectionEndEvent,
        CollectionStartEvent,
        ScalarEvent,
    )

    depth = nodes = 0  # depth: the collections around the event (a node's depth in Converter)
    for ev in _composer().parse(text):
        cls = type(ev)
        if cls is ScalarEvent or cls is AliasEvent or issubclass(cls, CollectionStartEvent):
            nodes += 1
            if depth > MAX_DEPTH:
                m = ev.start_mark
                raise LoadError(f"nesting deeper than {MAX_DEPTH} levels", file,
                                m.line + 1, m.column + 1)
            if cls is not ScalarEvent and cls is not AliasEvent:
                depth += 1
        elif issubclass(cls, CollectionEndEvent):
            depth -= 1
        else:
            continue
        if nodes > MAX_COMPOSED:
            m = ev.start_mark
            raise LoadError(
                f"more than {MAX_COMPOSED:,} YAML nodes (values, lists and mappings; "
                "refused before composing them); write a large document as JSON "
                "(YAML 1.2 includes JSON)", file, m.line + 1, m.column + 1)


def parse(text: str, file: str) -> Any:
    """Compose the YAML 1.2 node graph (aliases stay shared: nothing is expanded).

    The depth and the node count are bounded first (:func:`_prescan`); every error
    is a :class:`LoadError` located at its line and column.
    """
    from ruamel.yaml.error import MarkedYAMLError, YAMLError

    try:
        bad = _UNPRINTABLE.search(text)
        if bad is not None:
            raise LoadError(f"invalid YAML: control character U+{ord(bad.group()):04X} "
                            "(not allowed in YAML text)", file, *text_position(text, bad.start()))
        _prescan(text, file)
        return _composer().compose(text)
    except MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else None
        col = mark.column + 1 if mark is not None else None
        problem = (exc.problem or exc.context or "invalid YAML").strip().splitlines()[0]
        if line is not None and col is not None:
            rows = text.splitlines()
            row = rows[line - 1] if line - 1 < len(rows) else ""
            if "\t" in row[: col] or "\t" in problem:
                problem = "tab character: YAML indentation must use spaces"
                col = row.index("\t") + 1 if "\t" in row else col
        raise LoadError(f"invalid YAML: {problem}", file, line, col) from None
    except YAMLError as exc:  # unmarked ruamel errors
        raise LoadError(f"invalid YAML: {str(exc).splitlines()[0]}", file) from None
    except RecursionError:
        raise LoadError("invalid YAML: nesting too deep", file) from None


_TAG = "tag:yaml.org,2002:"
# YAML 1.2 core schema (https://yaml.org/spec/1.2.2/#1032-tag-resolution)
_NULL = re.compile(r"^(~|null|Null|NULL|)$")
_BOOL = re.compile(r"^(true|True|TRUE|false|False|FALSE)$")
_INT = re.compile(r"^([-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$")
_FLOAT = re.compile(
    r"^([-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?|[-+]?\.(inf|Inf|INF)|\.(nan|NaN|NAN))$"
)


def scalar(node: Any, file: str) -> Any:
    """Resolve a scalar node by the YAML 1.2 core schema (explicit tags honoured)."""
    tag, v = node.tag, node.value
    if tag == _PLAIN_TAG:
        tag = (
            _TAG + "null" if _NULL.match(v) else
            _TAG + "bool" if _BOOL.match(v) else
            _TAG + "int" if _INT.match(v) else
            _TAG + "float" if _FLOAT.match(v) else _TAG + "str"
        )
    if tag == _TAG + "str":
        return v
    if tag == _TAG + "null" and _NULL.match(v):
        return None
    if tag == _TAG + "bool" and _BOOL.match(v):
        return v.lower() == "true"
    if tag == _TAG + "int" and _INT.match(v):
        if len(v) > MAX_INT_DIGITS:
            raise LoadError(f"an integer of {len(v.lstrip('+-')):,} digits is out of range (at "
                            f"most {MAX_INT_DIGITS:,} digits)", file, *mark(node))
        return int(v, 0) if v.startswith(("0o", "0x")) else int(v)
    if tag == _TAG + "float" and v.startswith(("0o", "0x")) and _INT.match(v):
        if len(v) > MAX_INT_DIGITS:
            raise LoadError(f"{v[:20]}... is out of the range of a float", file, *mark(node))
        try:
            return float(int(v, 0))
        except OverflowError:
            raise LoadError(f"{v} is out of the range of a float", file, *mark(node)) from None
    if tag == _TAG + "float" and (_FLOAT.match(v) or _INT.match(v)):
        # .inf, -.inf, .nan (any case) are Python's inf, -inf, nan without the dot
        return float(v.replace(".", "", 1) if v.lower().endswith((".inf", ".nan")) else v)
    raise LoadError(f"unsupported YAML tag {tag!r} for {v!r}", file, *mark(node))


class Converter:
    """Node graph → plain Python, with duplicate-key, alias, depth and node-count checks.

    Positions are not recorded here: :class:`SourceMap` keeps the node graph and
    finds them on demand. Plain scalars are resolved once per distinct text.
    """

    def __init__(self, file: str) -> None:
        from ruamel.yaml.nodes import MappingNode, ScalarNode, SequenceNode
        from ruamel.yaml.resolver import BaseResolver

        self.file = file
        self.seen: set[int] = set()
        self.aliases = 0
        self.nodes = 0
        self.plain: dict[str, Any] = {}
        self._scalar_t, self._map_t, self._seq_t = ScalarNode, MappingNode, SequenceNode
        self._str_tag = BaseResolver.DEFAULT_SCALAR_TAG
        self._map_tag = BaseResolver.DEFAULT_MAPPING_TAG
        self._seq_tag = BaseResolver.DEFAULT_SEQUENCE_TAG

    def _error(self, msg: str, node: Any) -> LoadError:
        return LoadError(msg, self.file, *mark(node))

    def convert(self, node: Any, depth: int = 0) -> Any:
        cls = type(node)
        if depth > MAX_DEPTH:
            raise self._error(f"nesting deeper than {MAX_DEPTH} levels", node)
        self.nodes += 1
        if self.nodes > MAX_NODES:
            raise LoadError(f"document expands to more than {MAX_NODES} nodes", self.file)
        if cls is self._scalar_t or isinstance(node, self._scalar_t):
            ctag = node.ctag
            if ctag is _PLAIN:
                v = node.value
                try:
                    return self.plain[v]
                except KeyError:
                    value = self.plain[v] = scalar(node, self.file)
                    return value
            if ctag is self._str_tag:
                return node.value
            return scalar(node, self.file)
        if id(node) in self.seen:
            self.aliases += 1
            if self.aliases > MAX_ALIASES:
                raise self._error(
                    f"invalid YAML: more than {MAX_ALIASES} alias uses "
                    "(refused: possible alias bomb)", node)
        self.seen.add(id(node))
        if cls is self._map_t or isinstance(node, self._map_t):
            if node.ctag is not self._map_tag and node.tag != _TAG + "map":
                raise self._error(f"unsupported YAML tag {node.tag!r}", node)
            out: dict[Any, Any] = {}
            convert = self.convert
            d = depth + 1
            for knode, vnode in node.value:
                if knode.ctag is not _PLAIN and knode.tag == _TAG + "merge":
                    raise self._error("merge keys '<<' are not supported", knode)
                key = convert(knode, d)
                if isinstance(key, (list, dict)):
                    raise self._error("a mapping key must be a scalar", knode)
                if key in out:
                    raise self._error(
                        f"invalid YAML: duplicate key {key!r} (each key may appear once in a "
                        "mapping)", knode)
                out[key] = convert(vnode, d)
            return out
        if cls is self._seq_t or isinstance(node, self._seq_t):
            if node.ctag is not self._seq_tag and node.tag != _TAG + "seq":
                raise self._error(f"unsupported YAML tag {node.tag!r}", node)
            convert = self.convert
            d = depth + 1
            return [convert(v, d) for v in node.value]
        return scalar(node, self.file)


#: YAML that is not JSON (libyaml through Python: about 1 MB/s on a slow machine).
MAX_YAML_BYTES = 8 * 1024 * 1024

Path_ = tuple[str | int, ...]
_PLAIN_KEY = re.compile(r"^[A-Za-z_$][A-Za-z0-9_$-]*$")


@dataclass
class SourceMap:
    """Positions (1-based line, column) of the nodes of a loaded file.

    A map made by :func:`load_data` holds the composed YAML node graph (``root``),
    or the text of a JSON document to compose when a position is first asked for,
    and finds positions in it on demand, so loading a large file records nothing on
    the happy path. A map of neither locates everything at the document (1, 1).
    """

    file: str
    root: Any = field(default=None, repr=False, compare=False)
    text: str | None = field(default=None, repr=False, compare=False)
    _index: dict[int, dict[Any, tuple[Any, Any]]] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    def locate(self, path: Path_, *, key: bool = True) -> tuple[int | None, int | None]:
        """Position of ``path``: the key (or value), else the nearest enclosing node."""
        if self.root is None and self.text is not None:  # a JSON document: compose on demand
            try:
                self.root = parse(self.text, self.file)
            except LoadError:
                self.text = None
        found = self._walk(tuple(path)) if self.root is not None else []
        if not found:
            return (1, 1)  # the document itself
        kpos, vpos = found[-1]  # the longest prefix of path in the document
        return kpos if key else vpos

    def _walk(self, path: Path_) -> list[tuple[tuple[int, int], tuple[int, int]]]:
        """(key, value) positions of the longest prefix of ``path`` in the node graph."""
        from ruamel.yaml.nodes import MappingNode, SequenceNode

        out: list[tuple[tuple[int, int], tuple[int, int]]] = []
        cur = self.root
        for item in path:
            if isinstance(cur, MappingNode):
                index = self._index.get(id(cur))
                if index is None:
                    index = {}
                    for knode, vnode in cur.value:
                        if not is_scalar(knode):
                            continue
                        try:
                            index.setdefault(scalar(knode, self.file), (knode, vnode))
                        except (LoadError, TypeError):
                            continue
                    self._index[id(cur)] = index
                try:
                    pair = index.get(item)
                except TypeError:  # an unhashable path item
                    pair = None
                if pair is None:
                    break
                out.append((mark(pair[0]), mark(pair[1])))
                cur = pair[1]
            elif (isinstance(cur, SequenceNode) and isinstance(item, int)
                  and not isinstance(item, bool) and 0 <= item < len(cur.value)):
                cur = cur.value[item]
                pos = mark(cur)
                out.append((pos, pos))
            else:
                break
        return out


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


_COMMENT_LINE = re.compile(r"^[ \t]*#[^\n]*", re.M)


class _NotJson(Exception):
    """The document is not plain JSON (a duplicate key, NaN, ...): read it as YAML."""


def _json_pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out = dict(pairs)
    if len(out) != len(pairs):
        raise _NotJson("duplicate key")
    return out


def _json_constant(name: str) -> Any:
    raise _NotJson(name)  # NaN, Infinity: not JSON, and YAML reads them as strings


def _json_int(digits: str) -> int:
    if len(digits) > MAX_INT_DIGITS:
        raise _NotJson("huge integer")  # YAML's reading locates the refusal
    return int(digits)


def _json_document(text: str, file: str) -> Any:
    """The data of ``text`` if it is a JSON object (comment lines allowed), else ``_NotJson``.

    JSON is YAML 1.2 and means the same data there; :mod:`json` parses it at C
    speed. A document that starts like JSON but is over :data:`MAX_YAML_BYTES` and
    not JSON gets the JSON parser's located error (YAML would be refused by size).
    """
    body = _COMMENT_LINE.sub("", text) if "#" in text else text
    if not body.lstrip().startswith("{"):
        raise _NotJson("not an object")
    _json_nodes(text, file)
    try:
        data = json.loads(body, object_pairs_hook=_json_pairs, parse_constant=_json_constant,
                          parse_int=_json_int)
    except json.JSONDecodeError as exc:
        if len(text) > MAX_YAML_BYTES:
            raise LoadError(
                f"invalid JSON: {exc.msg} (a document over the {MAX_YAML_BYTES // 2**20} MiB "
                "cap of YAML must be JSON)", file, exc.lineno, exc.colno) from None
        raise _NotJson(exc.msg) from None
    except RecursionError:
        raise _NotJson("nesting") from None
    if _too_deep(data):
        if len(text) > MAX_YAML_BYTES:
            raise LoadError(f"nesting deeper than {MAX_DEPTH} levels", file, 1, 1)
        raise _NotJson("nesting")  # the YAML reading locates the level past the cap
    return data


def _json_nodes(text: str, file: str) -> None:
    """Refuse, before :func:`json.loads`, a text of more than :data:`MAX_NODES` values.

    Every value but the first follows a ``,`` or opens a ``[``/``{`` (or follows one), so
    their count bounds the values (a comma in a string counts too: it can only
    over-count). 20 million waypoint numbers in 60 MB of JSON took 89 s and 5.1 GB before
    the model refused them; a generated 10^5-module file has 1.7 million.
    """
    if len(text) <= MAX_NODES or text.count(",") + text.count("[") + text.count("{") < MAX_NODES:
        return
    import itertools

    past = next(itertools.islice(re.finditer(r"[,\[{]", text), MAX_NODES, None))
    raise LoadError(f"more than {MAX_NODES:,} JSON values (refused before reading them: "
                    "about 100 bytes each)", file, *text_position(text, past.start()))


def _too_deep(data: Any) -> bool:
    """Whether ``data`` nests lists and mappings deeper than :data:`MAX_DEPTH` (level by
    level, no recursion: 0.4 s for the 27 MB of a generated 10^5-module file)."""
    level, depth = [data], 0  # the depth of the nodes of ``level`` (the root's is 0)
    while level:
        deeper: list[Any] = []
        filled = False
        for v in level:
            items = v.values() if type(v) is dict else v
            if items:
                filled = True
                deeper.extend(x for x in items if type(x) is dict or type(x) is list)
        if filled and depth + 1 > MAX_DEPTH:
            return True
        level, depth = deeper, depth + 1
    return False


def load_data(text: str, file: str = "<input>") -> tuple[dict[str, Any], SourceMap]:
    """Parse YAML (or JSON) text into plain data and a :class:`SourceMap`."""
    size = len(text.encode("utf-8", "surrogatepass")) if len(text) * 4 > MAX_YAML_BYTES else 0
    if size > MAX_FILE_BYTES:
        raise LoadError(f"document larger than the {MAX_FILE_BYTES}-byte cap", file)
    try:
        data = _json_document(text, file)
    except _NotJson:
        pass
    else:
        return data, SourceMap(file, text=text)
    if size > MAX_YAML_BYTES:
        cut = text.encode("utf-8", "surrogatepass")[:MAX_YAML_BYTES].decode("utf-8", "ignore")
        start = cut.rfind("\n") + 1
        line, col = cut.count("\n") + 1, len(cut) - start + 1
        head = text[start:start + 200].split("\n", 1)[0].strip()
        head = head if len(head) <= 30 else head[:27] + "..."
        raise LoadError(
            f"YAML text passes its {MAX_YAML_BYTES // 2**20} MiB cap here, in the line "
            f"'{head}' ({size:,} bytes in "
            f"all; about 1 MB of YAML loads a second): shrink the file, or write it as JSON "
            f"(YAML 1.2 includes JSON; up to {MAX_FILE_BYTES // 2**20} MiB), as `archself "
            "generate` does", file, line, col)
    node = parse(text, file)
    if node is None:
        raise LoadError("file is empty; expected a mapping with keys archself, name, modules, "
                        "configurations, runtime", file, 1, 1)
    data = Converter(file).convert(node)
    if not isinstance(data, dict):
        raise LoadError(f"expected a mapping at the top level, got {describe(data)}", file, 1, 1)
    return data, SourceMap(file, root=node)


def describe(v: Any) -> str:
    """A value as a message shows it: ``number 3``, ``string "x"``, ``a list``, ``null``."""
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
