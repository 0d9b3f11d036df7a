"""Write new values into the architecture's text, keeping everything else.

The calibrated bands (:func:`set_nominals`) and the identified edge weights
(:func:`set_weights`, ``identify --write-back``). The text is composed with ruamel.yaml
(the round-trip composer, which keeps the position of every node); each
``modules.<m>.residual.nominal`` (or ``edges.<i>.weight``) scalar is replaced
where it stands, between its start and end marks, and the line gets an
end-of-line comment (``# calibrated: …``, ``# identified: …``). Nothing else of the file changes —
comments, flow mappings, key order, blank lines and quoting stay byte for byte
— and the result is loaded again to check that it holds exactly the new values.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from archself.errors import LoadError, OutputError
from archself.model.architecture import split_ref
from archself.model.loader import load_text

__all__ = [
    "check_output", "format_band", "format_weight", "replace_scalars", "same_file",
    "set_nominals", "set_weights",
]

COMMENT_TAG = "# calibrated:"
WEIGHT_TAG = "# identified:"


def format_band(value: float, digits: int = 3) -> str:
    """``value`` rounded *up* to ``digits`` significant digits, as a YAML float.

    Rounding up keeps the stated false-alarm rate (a wider band never adds alarms).

    Examples
    --------
    >>> format_band(0.000612345)
    '0.000613'
    >>> format_band(0.15)
    '0.15'
    >>> format_band(2.0)
    '2.0'
    >>> format_band(1.234e-05)
    '1.24e-05'
    """
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"a band must be positive and finite, not {value!r}")
    e = math.floor(math.log10(value)) - (digits - 1)
    q = math.ceil(value / 10.0**e - 1e-9) * 10.0**e
    text = f"{q:.{digits}g}"
    if float(text) < value * (1 - 1e-12):  # representation rounded down: one more digit
        text = f"{q:.{digits + 1}g}"
    if "e" not in text and "." not in text:
        text += ".0"
    return text


def _child(node: Any, key: str) -> Any:
    from ruamel.yaml.nodes import MappingNode, ScalarNode

    if not isinstance(node, MappingNode):
        return None
    for k, v in node.value:
        if isinstance(k, ScalarNode) and k.value == key:
            return v
    return None


def _comment_start(line: str) -> int:
    """Index of a ``#`` comment in ``line`` (outside quotes), or -1."""
    quote = None
    i = 0
    while i < len(line):
        ch = line[i]
        if quote:
            if ch == "\\" and quote == '"':
                i += 2
                continue
            if ch == quote:
                if quote == "'" and i + 1 < len(line) and line[i + 1] == "'":
                    i += 2
                    continue
                quote = None
        elif ch in "\"'":
            quote = ch
        elif ch == "#" and (i == 0 or line[i - 1] in " \t"):
            return i
        i += 1
    return -1


def set_nominals(
    text: str, file: str, values: dict[str, float], comment: str, *, verify: bool = True
) -> str:
    """The text with ``modules.<m>.residual.nominal`` set to ``values[m]`` for each m.

    Parameters
    ----------
    text : str
        The architecture file's text.
    file : str
        Its name (for messages).
    values : dict
        module -> new band (written by :func:`format_band`).
    comment : str
        Text after ``# calibrated:`` on every changed line (a previous
        ``# calibrated:`` comment is replaced; another comment is kept and the
        calibration note appended to it).
    verify : bool
        Load the result as an architecture and check the values (off for
        fragments that are not whole architecture files).

    Raises
    ------
    LoadError
        A module without a ``nominal`` scalar, or a ``residual`` reached through
        a YAML alias shared by modules that get different values (with the
        position).
    """
    from ruamel.yaml import YAML
    from ruamel.yaml.nodes import ScalarNode

    root = YAML(typ="rt").compose(text)
    modules = _child(root, "modules")
    edits: dict[int, tuple[int, int, str, str]] = {}  # id(node) -> (start, end, new, module)
    for name, value in values.items():
        node = _child(_child(_child(modules, name), "residual"), "nominal")
        if not isinstance(node, ScalarNode):
            raise LoadError(
                "no residual.nominal value to calibrate", file, path=f"modules.{name}.residual"
            )
        new = format_band(value)
        start, end = node.start_mark, node.end_mark
        old = edits.get(id(node))
        if old is not None and old[2] != new:
            raise LoadError(
                f"residual.nominal is shared (a YAML alias) with module {old[3]!r}, which "
                f"gets another band ({old[2]} vs {new}); write the value out for each module",
                file,
                start.line + 1,
                start.column + 1,
                f"modules.{name}.residual.nominal",
            )
        edits[id(node)] = (start.index, end.index, new, name)
    result = replace_scalars(text, [(s, e, new) for s, e, new, _ in edits.values()], comment)
    if verify:  # the new text holds exactly the new values

        arch = load_text(result, file).arch
        for name, value in values.items():
            got, v = arch.modules[name].residual.nominal, float(format_band(value))
            if got != v:  # pragma: no cover - a bug of the editor, not of the file
                raise LoadError(f"writing the band of {name} failed ({got} != {v})", file)
    return result


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether two paths name the same file (same device and inode; False if one is missing)."""
    try:
        sa, sb = os.stat(a), os.stat(b)
    except OSError:
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def check_output(source: str | Path, output: str | Path, *, in_place: bool, force: bool) -> None:
    """Refuse a calibrated copy that would replace the input or another file unasked.

    Raises
    ------
    OutputError
        ``output`` is the input (same inode) without ``in_place`` and ``force``,
        it exists without ``force``, or its folder does not exist.
    """
    out = Path(output)
    if same_file(source, out):
        if not (in_place and force):
            raise OutputError(
                f"{out}: error: is the input file; pass --in-place --force to overwrite it"
            )
        return
    if out.exists() and not force:
        raise OutputError(f"{out}: error: exists; pass --force to overwrite it")
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(f"{out}: error: cannot write: folder {folder} does not exist")


def replace_scalars(
    text: str, edits: list[tuple[int, int, str]], comment: str, tag: str = COMMENT_TAG
) -> str:
    """Replace ``text[start:end]`` by each new scalar and tag every changed line.

    Each changed line gets the end-of-line comment ``<tag> <comment>`` (an earlier
    comment with that tag is replaced, another comment is kept before it). Used for the bands
    (:func:`set_nominals`) and the edge weights of ``archself identify --write-back``.
    """
    out = text
    changed_lines: set[int] = set()
    # replace from the end so that earlier indices stay valid
    for s, e, new in sorted(edits, key=lambda t: -t[0]):
        out = out[:s] + new + out[e:]
        changed_lines.add(out.count("\n", 0, s))
    lines = out.split("\n")
    note = f"{tag} {comment}".rstrip()
    for i in sorted(changed_lines):
        line = lines[i]
        cut = _comment_start(line)
        if cut < 0:
            lines[i] = f"{line.rstrip()}  {note}"
        elif line[cut:].startswith(tag):
            lines[i] = f"{line[:cut].rstrip()}  {note}"
        else:
            lines[i] = f"{line.rstrip()}; {note[2:]}"
    return "\n".join(lines)


def format_weight(value: float) -> str:
    """A weight as a YAML float with 3 decimals (``0.0`` for zero).

    Examples
    --------
    >>> format_weight(0.41234), format_weight(0.0), format_weight(1.0)
    ('0.412', '0.0', '1.0')
    """
    text = f"{round(value, 3):.3f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def set_weights(text: str, file: str, values: Mapping[tuple[str, str], float], comment: str) -> str:
    """The text with the weights of the edges ``source → target`` set to ``values``.

    Parallel edges of a pair (several ``carries``) share the fitted weight in the
    proportion of their declared weights (equally when those are 0). Every
    changed line gets ``# identified: <comment>``; nothing else changes
    (:func:`set_nominals` does the same for bands). The result is
    loaded again and checked.

    Raises
    ------
    LoadError
        An edge whose weight is not a plain scalar, or is shared through a YAML alias.
    """
    from ruamel.yaml import YAML
    from ruamel.yaml.nodes import MappingNode, ScalarNode, SequenceNode

    root = YAML(typ="rt").compose(text)
    seq = _child(root, "edges")
    if not isinstance(seq, SequenceNode):
        raise LoadError("no edges to write weights into", file, path="edges")
    mods = _child(root, "modules")
    names = {k.value for k, _ in mods.value} if isinstance(mods, MappingNode) else set()
    groups: dict[tuple[str, str], list[tuple[int, Any, float]]] = {}
    for i, item in enumerate(seq.value):
        if not isinstance(item, MappingNode):
            continue
        s, t, w = _child(item, "from"), _child(item, "to"), _child(item, "weight")
        if not (isinstance(s, ScalarNode) and isinstance(t, ScalarNode)):
            continue
        key = (split_ref(s.value, names)[0], split_ref(t.value, names)[0])  # module.port ends
        if key in values:
            if not isinstance(w, ScalarNode):
                raise LoadError("edge weight is not a plain value", file, path=f"edges.{i}.weight")
            groups.setdefault(key, []).append((i, w, float(w.value)))
    edits: dict[int, tuple[int, int, str]] = {}
    expect: dict[int, float] = {}
    for key, items in groups.items():
        total = sum(d for _, _, d in items)
        for i, node, d in items:
            share = d / total if total > 0 else 1.0 / len(items)
            new = format_weight(values[key] * share)
            if id(node) in edits and edits[id(node)][2] != new:
                raise LoadError(
                    "edge weight is shared (a YAML alias) with another edge; write it out",
                    file,
                    node.start_mark.line + 1,
                    node.start_mark.column + 1,
                    f"edges.{i}.weight",
                )
            edits[id(node)] = (node.start_mark.index, node.end_mark.index, new)
            expect[i] = float(new)
    result = replace_scalars(text, list(edits.values()), comment, WEIGHT_TAG)
    arch = load_text(result, file).arch
    for i, w in expect.items():
        if arch.edges[i].weight != w:  # pragma: no cover - a bug of the editor
            raise LoadError(f"writing the weight of edge {i} failed", file)
    return result
