"""The YAML 1.2 node graph: composed by ruamel.yaml, scalars resolved by the core schema.

:func:`parse` composes the node graph (libyaml-backed when ``ruamel.yaml.clib`` is
present; aliases stay shared, nothing is expanded) with located errors;
:func:`scalar` resolves a scalar by the YAML 1.2 core schema (only ``true``/``false``
are booleans, ``yes`` is a string; explicit tags honoured); :class:`Converter` turns
the graph into plain Python with the duplicate-key, alias (:data:`MAX_ALIASES`),
depth (:data:`MAX_DEPTH`) and node-count (:data:`MAX_NODES`) checks.
:mod:`archself.io.yaml_source` builds on it.

The composer recurses in C once per nesting level: 30,000 nested brackets (60 KB)
overflowed its stack (SIGSEGV), and a list of 900,000 waypoints took 1.33 GB of
nodes before the model refused it. So :func:`parse` first bounds both on the text
and, when that bound is not enough, on the parser's event stream (no recursion, no
node kept): deeper than :data:`MAX_DEPTH` or more than :data:`MAX_COMPOSED` nodes is
a located error before anything is composed.
"""

from __future__ import annotations

import re
from typing import Any

from archself.errors import LoadError

__all__ = ["MAX_ALIASES", "MAX_COMPOSED", "MAX_DEPTH", "MAX_INT_DIGITS", "MAX_NODES",
           "Converter", "is_scalar", "mark", "parse", "scalar", "text_position"]

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
