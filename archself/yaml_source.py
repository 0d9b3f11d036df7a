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

:mod:`archself.loader` builds the architecture model on top of this module;
:mod:`archself.schema_messages` turns schema violations into located findings.

Examples
--------
>>> data, src = load_data("a:\\n  b: [1, 2.5, yes]\\n", "x.yaml")
>>> data
{'a': {'b': [1, 2.5, 'yes']}}
>>> src.locate(("a", "b", 1), key=False)
(2, 10)
>>> dotted(("edges", 3, "from"))
'edges[3].from'
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from archself.errors import LoadError

__all__ = ["MAX_ALIASES", "MAX_DEPTH", "MAX_FILE_BYTES", "MAX_NODES", "MAX_YAML_BYTES", "Path_",
           "SourceMap", "describe", "dotted", "load_data", "read_text"]

#: Any document (JSON text, which the json module parses at tens of MB/s).
MAX_FILE_BYTES = 64 * 1024 * 1024
#: YAML that is not JSON (libyaml through Python: about 1 MB/s on a slow machine).
MAX_YAML_BYTES = 8 * 1024 * 1024
MAX_ALIASES = 64
MAX_DEPTH = 64
MAX_NODES = 5_000_000

Path_ = tuple[str | int, ...]
_PLAIN_KEY = re.compile(r"^[A-Za-z_$][A-Za-z0-9_$-]*$")


@dataclass
class SourceMap:
    """Positions (1-based line, column) of the nodes of a loaded file.

    ``keys`` and ``values`` map a data path to the position of a mapping key (or
    sequence item) and of its value. A map made by :func:`load_data` holds the
    composed YAML node graph instead and finds positions in it on demand, so
    loading a large file records nothing on the happy path; explicit entries in
    ``keys``/``values`` take precedence.
    """

    file: str
    keys: dict[Path_, tuple[int, int]] = field(default_factory=dict)
    values: dict[Path_, tuple[int, int]] = field(default_factory=dict)
    root: Any = field(default=None, repr=False, compare=False)
    text: str | None = field(default=None, repr=False, compare=False)
    _index: dict[int, dict[Any, tuple[Any, Any]]] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    def locate(self, path: Path_, *, key: bool = True) -> tuple[int | None, int | None]:
        """Position of ``path``: the key (or value), else the nearest enclosing node."""
        p = tuple(path)
        if self.root is None and self.text is not None:  # a JSON document: compose on demand
            try:
                self.root = _parse(self.text, self.file)
            except LoadError:
                self.text = None
        found = self._walk(p) if self.root is not None else []
        while True:
            table = (self.keys, self.values) if key else (self.values, self.keys)
            for t in table:
                if p in t:
                    return t[p]
            if p and len(p) <= len(found):
                kpos, vpos = found[len(p) - 1]
                return kpos if key else vpos
            if not p:
                return (1, 1)  # the document itself
            p = p[:-1]

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
                        if not _is_scalar(knode):
                            continue
                        try:
                            index.setdefault(_scalar(knode, self.file), (knode, vnode))
                        except (LoadError, TypeError):
                            continue
                    self._index[id(cur)] = index
                try:
                    pair = index.get(item)
                except TypeError:  # an unhashable path item
                    pair = None
                if pair is None:
                    break
                out.append((_mark(pair[0]), _mark(pair[1])))
                cur = pair[1]
            elif (isinstance(cur, SequenceNode) and isinstance(item, int)
                  and not isinstance(item, bool) and 0 <= item < len(cur.value)):
                cur = cur.value[item]
                pos = _mark(cur)
                out.append((pos, pos))
            else:
                break
        return out


def _mark(node: Any) -> tuple[int, int]:
    m = node.start_mark
    return (m.line + 1, m.column + 1)


def _is_scalar(node: Any) -> bool:
    from ruamel.yaml.nodes import ScalarNode

    return isinstance(node, ScalarNode)



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


_PLAIN_TAG = "tag:archself,2026:plain"
_PLAIN: Any = None


def _composer():
    from ruamel.yaml import YAML
    from ruamel.yaml.nodes import MappingNode, ScalarNode
    from ruamel.yaml.resolver import BaseResolver

    class _PlainResolver(BaseResolver):  # type: ignore[misc]
        """Tag nothing implicitly: :func:`_scalar` applies the YAML 1.2 core schema."""

        def __init__(self, version: Any = None, loadumper: Any = None) -> None:
            super().__init__(loadumper)

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


def _parse(text: str, file: str) -> Any:
    """Compose the YAML 1.2 node graph (aliases stay shared: nothing is expanded)."""
    from ruamel.yaml.error import MarkedYAMLError, YAMLError

    try:
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


def _scalar(node: Any, file: str) -> Any:
    """Resolve a scalar node by the YAML 1.2 core schema (explicit tags honoured)."""
    tag, v = node.tag, node.value
    if tag == _TAG + "str":
        return v
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
        if v.startswith("0o"):
            return int(v[2:], 8)
        if v.startswith("0x"):
            return int(v[2:], 16)
        return int(v)
    if tag == _TAG + "float" and (_FLOAT.match(v) or _INT.match(v)):
        low = v.lower().lstrip("+")
        if low in (".inf", "-.inf"):
            return float("-inf") if low.startswith("-") else float("inf")
        if low == ".nan":
            return float("nan")
        return float(v)
    m = node.start_mark
    raise LoadError(f"unsupported YAML tag {tag!r} for {v!r}", file, m.line + 1, m.column + 1)


class _Converter:
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
        return LoadError(msg, self.file, *_mark(node))

    def convert(self, node: Any, depth: int = 0) -> Any:
        cls = type(node)
        if depth > MAX_DEPTH:
            raise self._error(f"nesting deeper than {MAX_DEPTH} levels", node)
        if cls is self._scalar_t or isinstance(node, self._scalar_t):
            self.nodes += 1
            if self.nodes > MAX_NODES:
                raise LoadError(f"document expands to more than {MAX_NODES} nodes", self.file)
            ctag = node.ctag
            if ctag is _PLAIN:
                v = node.value
                try:
                    return self.plain[v]
                except KeyError:
                    value = self.plain[v] = _scalar(node, self.file)
                    return value
            if ctag is self._str_tag:
                return node.value
            return _scalar(node, self.file)
        self.nodes += 1
        if self.nodes > MAX_NODES:
            raise LoadError(f"document expands to more than {MAX_NODES} nodes", self.file)
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
        return _scalar(node, self.file)


def read_text(path: str | Path, max_bytes: int = MAX_FILE_BYTES) -> str:
    """Read a regular file as UTF-8 with a size cap; errors become :class:`LoadError`.

    A FIFO, a socket or a device is refused before it is opened for reading (a
    FIFO without a writer would block forever, ``/dev/zero`` never ends); the
    file is opened non-blocking and checked again on the open descriptor, so a
    path swapped for a FIFO in between is refused too.
    """
    import os
    import stat

    file = str(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise LoadError("no such file", file) from None
    except OSError as exc:
        raise LoadError(f"cannot read: {exc.strerror}", file) from None
    if stat.S_ISDIR(st.st_mode):
        raise LoadError("is a directory, expected an architecture file", file)
    if not stat.S_ISREG(st.st_mode):
        raise LoadError(f"is {_file_kind(st.st_mode)}, expected a regular file", file)
    if st.st_size > max_bytes:
        raise LoadError(f"file is {st.st_size} bytes, larger than the {max_bytes}-byte cap", file)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    except OSError as exc:
        raise LoadError(f"cannot read: {exc.strerror}", file) from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise LoadError(f"is {_file_kind(mode)}, expected a regular file", file)
        with os.fdopen(fd, "rb", closefd=False) as fh:
            raw = fh.read(max_bytes + 1)  # the file may have grown since stat()
    except OSError as exc:
        raise LoadError(f"cannot read: {exc.strerror}", file) from None
    finally:
        os.close(fd)
    if len(raw) > max_bytes:
        raise LoadError(f"input is larger than the {max_bytes}-byte cap", file)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise LoadError("not UTF-8 text", file, line, 1) from None


def _file_kind(mode: int) -> str:
    import stat

    for test, kind in ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISDIR, "a directory")):
        if test(mode):
            return kind
    return "not a regular file"


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


def _json_document(text: str, file: str) -> Any:
    """The data of ``text`` if it is a JSON object (comment lines allowed), else ``_NotJson``.

    JSON is YAML 1.2 and means the same data there; :mod:`json` parses it at C
    speed. A document that starts like JSON but is over :data:`MAX_YAML_BYTES` and
    not JSON gets the JSON parser's located error (YAML would be refused by size).
    """
    import json

    body = _COMMENT_LINE.sub("", text) if "#" in text else text
    if not body.lstrip().startswith("{"):
        raise _NotJson("not an object")
    try:
        return json.loads(body, object_pairs_hook=_json_pairs, parse_constant=_json_constant)
    except json.JSONDecodeError as exc:
        if len(text) > MAX_YAML_BYTES:
            raise LoadError(
                f"invalid JSON: {exc.msg} (a document over the {MAX_YAML_BYTES // 2**20} MiB "
                "cap of YAML must be JSON)", file, exc.lineno, exc.colno) from None
        raise _NotJson(exc.msg) from None
    except RecursionError:
        raise _NotJson("nesting") from None


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
        line = cut.count("\n") + 1
        col = len(cut) - (cut.rfind("\n") + 1) + 1
        start = cut.rfind("\n") + 1
        head = text[start:start + 200].split("\n", 1)[0].strip()
        head = head if len(head) <= 30 else head[:27] + "..."
        raise LoadError(
            f"YAML text passes its {MAX_YAML_BYTES // 2**20} MiB cap here, in the line "
            f"'{head}' ({size:,} bytes in "
            f"all; about 1 MB of YAML loads a second): shrink the file, or write it as JSON "
            f"(YAML 1.2 includes JSON; up to {MAX_FILE_BYTES // 2**20} MiB), as `archself "
            "generate` does", file, line, col)
    node = _parse(text, file)
    src = SourceMap(file, root=node)
    if node is None:
        raise LoadError(
            "file is empty; expected a mapping with keys archself, name, modules, "
            "configurations, runtime",
            file,
            1,
            1,
        )
    data = _Converter(file).convert(node)
    if not isinstance(data, dict):
        raise LoadError(
            f"expected a mapping at the top level, got {describe(data)}", file, 1, 1
        )
    return data, src


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
