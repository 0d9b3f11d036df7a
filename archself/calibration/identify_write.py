"""``identify --write-back``: the fitted weights written into a copy of the file's text.

:func:`set_weights` edits the edges' ``weight`` scalars in place (comments and
layout kept, every changed line tagged ``# identified: …``, the result loaded again
and checked), as :mod:`archself.calibration.edit` does for bands;
:func:`written_copy` does it with the weights pooled over configurations.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from archself.calibration.identify_results import Identification, IdentifyError
from archself.errors import LoadError

__all__ = ["COMMENT_TAG", "format_weight", "set_weights", "written_copy"]

COMMENT_TAG = "# identified:"


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
    (:mod:`archself.calibration.edit` does the same for bands). The result is
    loaded again and checked.

    Raises
    ------
    LoadError
        An edge whose weight is not a plain scalar, or is shared through a YAML alias.
    """
    from ruamel.yaml import YAML
    from ruamel.yaml.nodes import MappingNode, ScalarNode, SequenceNode

    from archself.calibration.edit import _child, replace_scalars
    from archself.model.architecture import split_ref
    from archself.model.loader import load_text

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
    result = replace_scalars(text, list(edits.values()), comment, COMMENT_TAG)
    arch = load_text(result, file).arch
    for i, w in expect.items():
        if arch.edges[i].weight != w:  # pragma: no cover - a bug of the editor
            raise LoadError(f"writing the weight of edge {i} failed", file)
    return result


def written_copy(ident: Identification) -> str:
    """The file's text with the fitted weights (pooled over configurations) written in."""
    values = {k: w for k, (w, _) in ident.fitted_weights().items()}
    if not values:
        raise IdentifyError(f"{ident.file}: no edge was identifiable; nothing to write back")
    comment = (
        f"archself identify, {ident.seeds} seeds, scenario {ident.scenario}, "
        f"configurations {'/'.join(ident.configurations)}"
    )
    return set_weights(ident.text, ident.file, values, comment)
