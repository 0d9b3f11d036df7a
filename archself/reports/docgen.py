"""Reference pages generated from the schema and the command line, so that they cannot drift.

This module imports neither :mod:`archself.cli` nor typer at import time: the command
line passes its app to :func:`reference_pages` (``archself docs``).
"""

from __future__ import annotations

import json
from typing import Any

from archself.model.schema import architecture_schema
from archself.reports.render import render


def _type(s: dict[str, Any]) -> str:
    if "$ref" in s:
        name = s["$ref"].split("/")[-1]
        return f"[{name}](#{name.lower()})"
    if "const" in s:
        return f"`{json.dumps(s['const'])}`"
    if "enum" in s:
        return " | ".join(f"`{v}`" for v in s["enum"])
    for key in ("anyOf", "oneOf"):
        if key in s:
            parts = [_type(a) for a in s[key] if a.get("type") != "null"]
            return " or ".join(dict.fromkeys(parts))
    t = s.get("type")
    if t == "array":
        if "prefixItems" in s:
            return "[" + ", ".join(_type(i) for i in s["prefixItems"]) + "]"
        return f"list of {_type(s.get('items', {}))}"
    if t == "object":
        sub = s.get("additionalProperties")
        if not isinstance(sub, dict) and s.get("patternProperties"):
            sub = next(iter(s["patternProperties"].values()))
        return f"map name → {_type(sub)}" if isinstance(sub, dict) else "mapping"
    bounds = []
    if s.get("minimum") is not None and s.get("minimum") == -s.get("maximum", 0) != 0:
        bounds.append(f"|x| ≤ {s['maximum']:g}")  # the global magnitude cap
    else:
        for k, sym in (("minimum", "≥"), ("exclusiveMinimum", ">"), ("maximum", "≤"),
                       ("exclusiveMaximum", "<")):
            if k in s:
                v = s[k]
                bounds.append(f"{sym} {v:g}" if isinstance(v, float) else f"{sym} {v}")
    return (t or "any") + (f" ({', '.join(bounds)})" if bounds else "")


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def format_reference() -> str:
    """Markdown reference of every object of the architecture file format."""

    schema = architecture_schema(installed=False)
    defs = schema.get("$defs", {})
    objects = [("Architecture", schema)] + sorted(defs.items())
    sections = []
    for name, s in objects:
        if "properties" not in s:
            continue
        req = set(s.get("required", []))
        props = []
        for pname, p in s["properties"].items():
            props.append({
                "name": pname,
                "type": _cell(_type(p)),
                "required": pname in req,
                "default": _cell(f"`{json.dumps(p['default'])}`") if "default" in p else "",
                "description": _cell(p.get("description", "")),
            })
        title = "Architecture (top level)" if name == "Architecture" else name
        sections.append({"title": title, "description": _cell(s.get("description", "")).strip(),
                         "properties": props})
    return render("format.md.j2", sections=sections)


def cli_reference(cli: Any) -> str:
    """Markdown reference of every command of ``cli``, from the command line's own help.

    ``cli`` is the typer app (or its click group) of :mod:`archself.cli`, passed in by
    the caller: this module does not import the command line, which imports it.
    """
    import typer
    import typer.main

    group: Any = typer.main.get_command(cli) if isinstance(cli, typer.Typer) else cli
    ctx = group.make_context("archself", [], resilient_parsing=True)
    ctx.max_content_width = ctx.terminal_width = 100
    commands = []
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        if cmd is None or cmd.hidden:
            continue
        sub = cmd.make_context(name, [], parent=ctx, resilient_parsing=True)
        sub.max_content_width = sub.terminal_width = 100
        commands.append({"name": name, "summary": cmd.get_short_help_str(100),
                         "help": cmd.get_help(sub).rstrip()})
    return render("cli.md.j2", overview=group.get_help(ctx).rstrip(), commands=commands)


def reference_pages(cli: Any = None) -> dict[str, str]:
    """File name → content of the generated reference pages in ``docs/``.

    ``format.md`` always; ``cli.md`` when the command line ``cli`` (the typer app of
    :mod:`archself.cli`) is given: ``archself docs`` passes its own app.
    """
    pages = {"format.md": format_reference()}
    if cli is not None:
        pages["cli.md"] = cli_reference(cli)
    return pages
