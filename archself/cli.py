"""The ``archself`` command line (typer).

Data goes to stdout, diagnostics to stderr. Exit codes: 0 ok, 1 findings or a
user error, 2 usage error, 130 interrupted. Heavy libraries (python-control,
filterpy, matplotlib) are imported inside the commands that need them, never at
start-up.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from archself.errors import ArchselfError

app = typer.Typer(
    name="archself",
    help="Carry a system's architecture as data: validate it, simulate it, adapt it (MAPE-K).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _fail(msg: str, code: int = 1) -> typer.Exit:
    typer.echo(f"error: {msg}" if not msg.startswith(("error", "/")) and ":" not in msg[:200]
               else msg, err=True)
    return typer.Exit(code)


def _die(err: ArchselfError) -> typer.Exit:
    typer.echo(str(err), err=True)
    return typer.Exit(err.exit_code)


# --------------------------------------------------------------------------- validate
@app.command()
def validate(
    paths: Annotated[list[Path], typer.Argument(help="Architecture files to check.", metavar="PATH...")],
    json_out: Annotated[bool, typer.Option("--json", help="Print findings as JSON.")] = False,
    strict: Annotated[bool, typer.Option("--strict", help="Treat warnings as errors.")] = False,
) -> None:
    """Check architecture files against the schema and the semantic rules.

    Exit 0 when no file has an error finding, 1 otherwise.
    """
    from archself.check import check
    from archself.findings import Finding
    from archself.loader import SchemaError, load_architecture

    failed = False
    report: list[dict[str, object]] = []
    for path in paths:
        try:
            loaded = load_architecture(path)
            findings = check(loaded)
        except SchemaError as exc:
            findings = exc.findings
        except ArchselfError as exc:
            e = exc
            findings = [Finding("error", "load", getattr(e, "message", str(e)),
                                getattr(e, "path", ""), str(path), getattr(e, "line", None),
                                getattr(e, "col", None))]
        bad = [f for f in findings if f.severity == "error" or (strict and f.severity == "warning")]
        failed |= bool(bad)
        if json_out:
            report.append({"file": str(path), "ok": not bad,
                           "findings": [f.to_dict() for f in findings]})
        else:
            for f in findings:
                typer.echo(str(f), err=True)
            if not bad:
                n = len(findings)
                typer.echo(f"{path}: ok" + (f" ({n} warning{'s' * (n != 1)})" if n else ""))
    if json_out:
        typer.echo(json.dumps(report if len(report) != 1 else report[0], indent=2,
                              ensure_ascii=False))
    raise typer.Exit(1 if failed else 0)


# --------------------------------------------------------------------------- schema
@app.command()
def schema(
    output: Annotated[Optional[Path], typer.Option("-o", "--output", help="Write to FILE.")] = None,
    check_file: Annotated[
        Optional[Path], typer.Option("--check", help="Exit 1 if FILE differs from the model.")
    ] = None,
) -> None:
    """Print the JSON Schema of architecture files, generated from the model."""
    from archself.atomic import write_text
    from archself.schema import schema_text

    text = schema_text()
    if check_file is not None:
        try:
            current = check_file.read_text(encoding="utf-8")
        except OSError as exc:
            raise _fail(f"{check_file}: cannot read: {exc.strerror}") from None
        if current != text:
            typer.echo(f"{check_file}: stale; regenerate with `archself schema -o {check_file}`",
                       err=True)
            raise typer.Exit(1)
        typer.echo(f"{check_file}: up to date")
        return
    if output is None:
        sys.stdout.write(text)
    else:
        try:
            write_text(output, text)
        except ArchselfError as exc:
            raise _die(exc) from None


def main() -> None:
    """Entry point of the ``archself`` script."""
    try:
        app()
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        raise SystemExit(130) from None
    except ArchselfError as exc:
        typer.echo(str(exc), err=True)
        raise SystemExit(exc.exit_code) from None
    except Exception as exc:  # a bug, not a user error: say so in one line
        import os

        if os.environ.get("ARCHSELF_DEBUG"):
            raise
        typer.echo(f"internal error: {type(exc).__name__}: {exc} "
                   "(set ARCHSELF_DEBUG=1 for the traceback; please report it)", err=True)
        raise SystemExit(3) from None
