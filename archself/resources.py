"""Locate the data shipped with archself (schemas, templates, example architectures).

In a wheel they live in ``archself/_data/``; in a source checkout (editable
install) they are the top-level folders of the repository.
"""

from __future__ import annotations

from pathlib import Path

_PKG = Path(__file__).resolve().parent


def data_dir(name: str) -> Path:
    """Path of the shipped folder ``name`` (``schemas``, ``templates``, ``architectures``)."""
    inside = _PKG / "_data" / name
    if inside.is_dir():
        return inside
    return _PKG.parent / name


def schema_path() -> Path:
    """Path of ``architecture.schema.json``."""
    return data_dir("schemas") / "architecture.schema.json"
