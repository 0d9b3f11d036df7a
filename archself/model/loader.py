"""Load architecture files: YAML 1.2 with source positions, then the pydantic model.

The work is split by job:

- :mod:`archself.io.yaml_source` reads the file (size cap, UTF-8) and turns the YAML 1.2
  text into plain data and a :class:`SourceMap` (positions found on demand);
- :mod:`archself.model.messages` turns schema violations into located findings
  (dotted path, what was expected, "did you mean");
- this module validates the data against :class:`archself.model.architecture.Architecture` and
  returns a :class:`Loaded` (model, data, positions) or raises :class:`SchemaError`.

The names of those modules that other code uses (``load_data``, ``read_text``,
``SourceMap``, ``dotted``, ``MAX_FILE_BYTES``, ``schema_findings``) are
importable from here too.

Examples
--------
>>> from archself.model.loader import load_text
>>> try:
...     load_text("archself: 1\\nnmae: x\\n", "x.yaml")
... except SchemaError as err:
...     print(next(f for f in err.findings if f.path == "nmae"))
x.yaml:2:1: error: nmae: unknown key 'nmae'; did you mean 'name'?
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from archself.errors import LoadError
from archself.findings import Finding
from archself.io.yaml_source import (
    MAX_FILE_BYTES,
    MAX_YAML_BYTES,
    SourceMap,
    dotted,
    load_data,
    read_text,
)
from archself.model.messages import schema_findings

__all__ = [
    "MAX_FILE_BYTES",
    "MAX_YAML_BYTES",
    "Loaded",
    "SchemaError",
    "SourceMap",
    "dotted",
    "load_architecture",
    "load_data",
    "load_text",
    "read_text",
    "schema_findings",
]


@contextlib.contextmanager
def gc_paused() -> Iterator[None]:
    """Pause the cyclic garbage collector while the block runs (restored after).

    Reading, validating and checking a file, and wiring the linear models of a
    closed loop (:mod:`archself.linear.wiring`), make many small objects and none in a
    reference cycle (10^5 modules are some 10^6): each burst of allocations made the
    collector walk every object of the process again (3.1 of the model's 4.2 s of CPU
    at 10^5 modules, a third of the closed loop's at 10^4). Reference counting frees
    everything as before.

    Examples
    --------
    >>> import gc
    >>> with gc_paused():
    ...     gc.isenabled()
    False
    >>> gc.isenabled()
    True
    """
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


class SchemaError(LoadError):
    """The file parsed but does not match the schema; ``findings`` holds every violation."""

    def __init__(self, findings: list[Finding]) -> None:
        self.findings = findings
        f = findings[0]
        super().__init__(f.message, f.file, f.line, f.col, f.path)


@dataclass
class Loaded:
    """An architecture loaded from a file, with the positions of its nodes."""

    arch: Any  # archself.model.architecture.Architecture
    source: SourceMap
    data: dict[str, Any]

    @property
    def file(self) -> str:
        return self.source.file


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

    from archself.model.architecture import Architecture

    with gc_paused():
        try:
            data, src = load_data(text, file)
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
