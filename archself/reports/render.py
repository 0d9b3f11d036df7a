r"""The Jinja environment of the reports and the quoting filters it needs.

Every text file a report writes (HTML, Markdown, CSV, DOT) is rendered from a
template in ``templates/`` by :func:`render`, in a
:class:`jinja2.sandbox.SandboxedEnvironment` with ``StrictUndefined``:

- ``*.html.j2`` templates are autoescaped (module names are user data);
- DOT templates quote every id and label with :func:`dot_quote` / :func:`dot_label`;
- Markdown cells go through :func:`md_cell`, CSV fields through :func:`csv_field`.

Examples
--------
>>> print(dot_quote('say "hi" \\ bye'))
"say \"hi\" \\ bye"
>>> print(md_cell("a|b <i>"))
a\|b &lt;i&gt;
>>> print(csv_field('=1+1, "x" y'))
"'=1+1, ""x"" y"
"""

from __future__ import annotations

import functools
import re
import unicodedata
from typing import Any

from archself.resources import data_dir

__all__ = [
    "csv_field", "dot_label", "dot_quote", "md_cell", "num", "render", "slug", "yaml_string",
]


def yaml_string(value: Any) -> str:
    """A YAML double-quoted scalar (JSON string syntax is valid YAML 1.2).

    Examples
    --------
    >>> print(yaml_string('tank "A": 1'))
    "tank \\"A\\": 1"
    """
    import json

    return json.dumps(str(value), ensure_ascii=False)


def dot_quote(value: Any) -> str:
    """A DOT quoted string (``"..."``) for an id or a label.

    Backslashes and double quotes are escaped; newlines become DOT's ``\\n``
    (a centred line break) and other control characters are dropped, so no
    value can close the string or inject attributes. Graphviz keeps ``\\\\`` literally
    in ids (ids stay unique and consistent) and shows it as one backslash in labels.
    """
    s = str(value)
    s = s.replace("\\", "\\\\").replace('"', '\\"')
    s = s.replace("\r\n", "\n").replace("\r", "\n").replace("\n", "\\n")
    s = "".join(ch for ch in s if ch == "\t" or unicodedata.category(ch) != "Cc")
    return f'"{s}"'


def dot_label(value: Any) -> str:
    """:func:`dot_quote` for text that Graphviz *displays*.

    Graphviz decodes HTML entities (``&amp;``, ``&lt;``) in labels, so ``&`` is
    written as ``&amp;`` to show the name exactly as written.
    """
    return dot_quote(str(value).replace("&", "&amp;"))


_MD_SPECIAL = re.compile(r"([\\`*_\[\]|~])")


def md_cell(value: Any) -> str:
    """Text for a Markdown table cell: inline markup and HTML neutralised.

    ``&``, ``<`` and ``>`` become entities (Markdown passes raw HTML through),
    Markdown punctuation and ``|`` are backslash-escaped, line breaks become spaces.
    """
    s = " ".join(str(value).split("\n"))
    s = s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return _MD_SPECIAL.sub(r"\\\1", s)


def csv_field(value: Any) -> str:
    """One RFC 4180 CSV field; text starting with ``= + - @`` is prefixed with ``'``.

    The prefix keeps spreadsheet programs from evaluating a module name as a
    formula (CSV injection); numbers are passed through unchanged.
    """
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return num(value)
    s = str(value)
    if s[:1] in ("=", "+", "-", "@", "\t", "\r"):
        s = "'" + s
    if any(ch in s for ch in ',"\n\r') or s != s.strip():
        s = '"' + s.replace('"', '""') + '"'
    return s


def num(value: Any, digits: int = 6) -> str:
    """A number in the shortest form with ``digits`` significant digits (``0.3``, ``12``)."""
    if value is None:
        return ""
    v = float(value)
    if v != v:
        return "nan"
    if v == 0:
        return "0"
    return format(v, f".{digits}g")


def slug(value: str) -> str:
    """A file-name-safe ASCII form of a name (``'fusion "GPS" & <i>'`` → ``fusion-GPS-i``).

    Examples
    --------
    >>> slug('contrôle "A" & <b>')
    'controle-A-b'
    >>> slug("<>")
    'x'
    """
    ascii_ = unicodedata.normalize("NFKD", value).encode("ascii", "ignore").decode("ascii")
    s = re.sub(r"[^A-Za-z0-9_.]+", "-", ascii_).strip("-.")
    return s[:60] or "x"


def unique_slugs(names: list[str]) -> dict[str, str]:
    """:func:`slug` of each name, made unique with ``-2``, ``-3``, ... in the given order."""
    seen: set[str] = set()
    out: dict[str, str] = {}
    for name in names:
        base = slug(name)
        s, k = base, 2
        while s.lower() in seen:
            s, k = f"{base}-{k}", k + 1
        seen.add(s.lower())
        out[name] = s
    return out


@functools.cache
def environment() -> Any:
    """The sandboxed Jinja environment over ``templates/`` (built once)."""
    from jinja2 import FileSystemLoader, StrictUndefined, select_autoescape
    from jinja2.sandbox import SandboxedEnvironment

    env = SandboxedEnvironment(
        loader=FileSystemLoader(str(data_dir("templates"))),
        undefined=StrictUndefined,
        autoescape=select_autoescape(
            enabled_extensions=("html", "html.j2"), default_for_string=True, default=False
        ),
        keep_trailing_newline=True,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters.update(
        dot_quote=dot_quote, dot_label=dot_label, md_cell=md_cell, csv_field=csv_field,
        num=num, yaml_string=yaml_string,
    )
    return env


def render(template: str, **context: Any) -> str:
    """Render ``templates/<template>`` with ``context``."""
    return environment().get_template(template).render(**context)
