"""Short, bounded HTML for notebooks: what the ``_repr_html_`` of archself's objects show.

A card is a bold head line and a two-column table; lists are cut after a few items
(``a, b, c, … (12 more)``) and tables after a few rows, so that a 10,000-module
architecture shows in as many characters as a small one.

Examples
--------
>>> few([f"m{i}" for i in range(12)], 3)
'm0, m1, m2, … (9 more)'
>>> len(card("big", [("modules", few(["x" * 10] * 10_000))])) < 400
True
"""

from __future__ import annotations

from collections.abc import Sequence
from html import escape
from typing import Any

__all__ = ["MAX_ROWS", "card", "few", "table"]

#: Rows a table shows before "… (N more)".
MAX_ROWS = 12


def few(items: Sequence[Any], n: int = 8) -> str:
    """The first ``n`` items joined by commas, and how many more there are."""
    shown = ", ".join(str(x) for x in items[:n])
    return shown + (f", … ({len(items) - n} more)" if len(items) > n else "")


def card(head: str, rows: Sequence[tuple[str, Any]], extra: str = "") -> str:
    """``head`` (plain text, escaped) in bold over a table of ``(label, value)`` rows.

    ``extra`` is HTML appended inside the card (a :func:`table`).
    """
    body = "".join(f"<tr><th style=\"text-align:left\">{escape(str(k))}</th>"
                   f"<td style=\"text-align:left\">{escape(str(v))}</td></tr>" for k, v in rows)
    return (f"<div class=\"archself\"><p><b>{escape(head)}</b></p>"
            f"<table>{body}</table>{extra}</div>")


def table(header: Sequence[str], rows: Sequence[Sequence[Any]], limit: int = MAX_ROWS) -> str:
    """An HTML table of at most ``limit`` rows (then one row saying how many are left)."""
    head = "".join(f"<th>{escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{escape(str(v))}</td>" for v in r) + "</tr>"
                   for r in rows[:limit])
    if len(rows) > limit:
        body += f"<tr><td colspan=\"{len(header)}\">… ({len(rows) - limit} more)</td></tr>"
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
