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
node graph and its conversion are in :mod:`archself.io.yaml_nodes`, reading a file in
:mod:`archself.io.file_text` (``read_text`` and its cap are re-exported here).

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
from typing import Any

from archself.errors import LoadError
from archself.io.file_text import MAX_FILE_BYTES, read_text
from archself.io.yaml_nodes import (
    MAX_DEPTH,
    MAX_INT_DIGITS,
    MAX_NODES,
    Converter,
    is_scalar,
    mark,
    parse,
    scalar,
    text_position,
)

__all__ = ["MAX_FILE_BYTES", "MAX_YAML_BYTES", "Path_", "SourceMap", "describe", "dotted",
           "load_data", "read_text"]

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
