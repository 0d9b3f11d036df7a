"""Validation findings as data: what is wrong, how badly, and where."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from archself.errors import located

Severity = Literal["error", "warning", "info"]


@dataclass(frozen=True)
class Finding:
    """One result of loading or checking an architecture file.

    Attributes
    ----------
    severity : {'error', 'warning', 'info'}
        Errors make ``archself validate`` exit 1.
    code : str
        A short stable identifier of the rule (``schema``, ``reference``, ``spectral-radius``...).
    message : str
        What is wrong and what was expected, in one line.
    path : str
        Dotted path of the node (``edges[3].from``).
    file : str
    line, col : int or None
        1-based position of the node.
    """

    severity: Severity
    code: str
    message: str
    path: str = ""
    file: str = "<input>"
    line: int | None = None
    col: int | None = None

    def __str__(self) -> str:
        return located(self.file, self.line, self.col, self.path, self.message, self.severity)
