"""Commands on files: validate, schema, docs, init, export, info, generate."""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Annotated, Any

import typer

from archself.cli.base import (
    STDIN_NAME,
    _die,
    _emit,
    _err,
    _fail,
    _inputs,
    _load,
    _read_stdin,
    guard,
    numeric_lines,
)
from archself.errors import ArchselfError, unknown
from archself.resources import data_dir


def validate(
    paths: Annotated[
        list[Path],
        typer.Argument(help="Architecture files to check; '-' reads one from stdin.",
                       metavar="PATH..."),
    ],
    json_out: Annotated[
        bool,
        typer.Option("--json", help="Print a JSON list, one {file, ok, findings} per PATH "
                     "(a list even for one file)."),
    ] = False,
    strict: Annotated[bool, typer.Option("--strict", help="Treat warnings as errors.")] = False,
    stability: Annotated[
        bool,
        typer.Option("--stability", help="Check every configuration's whole-loop stability "
                     "as `runtime.stability.verify: warning` does where the file leaves it off "
                     "(compiles and runs every configuration; with --strict its warnings are "
                     "errors; docs/stability.md)."),
    ] = False,
) -> None:
    """Check architecture files against the schema and the semantic rules.

    Exit 0 when no file has an error finding, 1 otherwise. `-` reads the file from
    stdin (named `<stdin>` in the findings). A file whose whole-loop stability is not
    checked (`runtime.stability.verify: off`, no --stability) says so in one `info`
    finding.
    """
    from archself.check import check
    from archself.findings import Finding
    from archself.model.loader import SchemaError, load_architecture, load_text

    if sum(str(p) == "-" for p in paths) > 1:
        raise _fail("'-' (stdin) can be given once", 2)
    failed = False
    report: list[dict[str, object]] = []
    for path in paths:
        caught: list[warnings.WarningMessage] = []
        loaded = None
        stdin = str(path) == "-"
        if stdin:
            path = Path(STDIN_NAME)
        try:
            if not stdin:
                _inputs(path)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")  # recorded, never printed as Python warnings
                loaded = (load_text(_read_stdin(), STDIN_NAME) if stdin
                          else load_architecture(path))
                findings = check(loaded, "warning" if stability else None)
            findings += _warning_findings(caught, str(path))
        except SchemaError as exc:
            findings = exc.findings
        except ArchselfError as exc:
            findings = [Finding("error", "load", getattr(exc, "message", str(exc)),
                                getattr(exc, "path", ""), str(path), getattr(exc, "line", None),
                                getattr(exc, "col", None))]
        bad = [f for f in findings if f.severity == "error" or (strict and f.severity == "warning")]
        failed |= bool(bad)
        table = _stability_table(loaded, stability)
        if json_out:
            report.append({"file": str(path), "ok": not bad, "findings": findings,
                           "stability": _verdicts(table)})
        else:
            for f in findings:
                _err(str(f), failing=f in bad)
            if not bad:  # a failing file prints nothing on stdout (its findings say why)
                n = sum(f.severity == "warning" for f in findings)  # info is not a warning
                typer.echo(f"{path}: ok" + (f" ({n} warning{'s' * (n != 1)})" if n else ""))
                if table is not None:
                    from archself.check.stability import table_text

                    typer.echo(table_text(table))
    if json_out:  # one shape: a list, whatever the number of files
        from archself.io.jsondata import ValidateList, document

        typer.echo(json.dumps(document(ValidateList, report, complete=True), indent=2,
                              ensure_ascii=False))
    raise typer.Exit(1 if failed else 0)


def _stability_table(loaded: object, asked: bool) -> list | None:
    """The whole-loop table the check computed (``verify`` on or ``--stability``), or None."""
    arch = getattr(loaded, "arch", None)
    if arch is None or (arch.runtime.stability.verify == "off" and not asked):
        return None
    from archself.check.stability import _TABLES

    return next((t for a, t in _TABLES if a is arch), None)


def _warning_findings(caught: list, file: str) -> list:
    """numpy/scipy warnings of a check as findings (once each): no warning text on the terminal."""
    from archself.findings import Finding

    lines = numeric_lines(caught, lambda w, text: "numeric trouble while checking: "
                          f"{w.category.__name__}: {text}", True)
    return [Finding("warning", "numeric", msg, "", file, None, None) for msg in lines]


def schema(
    output: Annotated[Path | None, typer.Option("-o", "--output", help="Write to FILE.")] = None,
    check_file: Annotated[
        Path | None, typer.Option("--check", help="Exit 1 if FILE differs from the model.")
    ] = None,
    builtin: Annotated[
        bool,
        typer.Option("--builtin", help="Offer only the built-in module types (the schema "
                     "checked in as schemas/architecture.schema.json), not installed plugins'."),
    ] = False,
) -> None:
    """Print the JSON Schema of architecture files, generated from the model.

    A module's `type` offers the registered types for completion (`examples`): the
    built-in ones and those of the installed plugins (--builtin: built-in only).
    """
    from archself.model.schema import schema_text

    regen = "archself schema --builtin -o" if builtin else "archself schema -o"
    _write_or_check(schema_text(installed=not builtin), output, check_file, regen)


def docs(
    folder: Annotated[Path, typer.Argument(help="Folder of the reference pages.")] = Path("docs"),
    check: Annotated[bool, typer.Option("--check", help="Exit 1 if a page is stale.")] = False,
) -> None:
    """Regenerate the reference pages (format.md from the schema, cli.md from this CLI)."""
    from archself.cli import app  # every command, whichever this process runs
    from archself.reports.docgen import reference_pages

    for name, text in reference_pages(app).items():  # docgen never imports this module
        target = folder / name
        if check:
            _write_or_check(text, None, target, f"archself docs {folder}")
        else:
            _write_or_check(text, target, None, "")


def _write_or_check(text: str, output: Path | None, check_file: Path | None, regen: str) -> None:
    """Write ``text`` to ``output`` (stdout if None), or with ``check_file`` compare it.

    A stale ``check_file`` exits 1 with the command (``regen``) that regenerates it.
    """
    if check_file is not None:
        try:
            with guard((check_file, "a file"), numeric=False):
                current = check_file.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise _fail(f"{check_file}: error: not UTF-8 text") from None
        except OSError as exc:
            raise _fail(f"{check_file}: error: cannot read: {exc.strerror}") from None
        if current != text:
            typer.echo(
                f"{check_file}: stale; regenerate with `{regen} {check_file}`"
                if regen.endswith("-o")
                else f"{check_file}: stale; run `{regen}`",
                err=True,
            )
            raise typer.Exit(1)
        typer.echo(f"{check_file}: up to date")
    else:
        _emit(text, output, f"wrote {output}")


#: ``init --template``: name -> (what it is, the ``templates/`` file or the shipped
#: ``architectures/`` file it copies).
TEMPLATES: dict[str, tuple[str, str]] = {
    "tank": ("a tank under level control with a spare transmitter (the default)",
             "templates/init.yaml.j2"),
    "lti": ("a first-order LTI plant, PI and Kalman filters: generic blocks only",
            "templates/init_lti.yaml.j2"),
    "process": ("the shipped liquid-level process (docs/process_plant.md)",
                "architectures/process_plant.yaml"),
    "diffdrive": ("the paper's differential-drive robot (Fig. 1, docs/reproduction.md)",
                  "architectures/diffdrive.yaml"),
    "motor": ("the DC-motor drive of generic blocks (docs/motor_drive.md)",
              "architectures/motor_drive.yaml"),
    "thermal": ("a heated zone of generic blocks: a multi-input plant, an expression, "
                "sensor silence (docs/blocks.md)", "architectures/thermal_zone.yaml"),
}


def _template_choice(value: str) -> str:
    """``--template``'s value, or a usage error with "did you mean" and the choices."""
    if value in TEMPLATES:
        return value
    import difflib

    close = difflib.get_close_matches(value, list(TEMPLATES), n=1)
    hint = f"did you mean '{close[0]}'? " if close else ""
    raise typer.BadParameter(f"unknown template {value!r}; {hint}choose from: "
                             f"{', '.join(TEMPLATES)}")


def _template_text(template: str, name: str, file_name: str, schema: str) -> str:
    """The text ``init`` writes: a rendered template, or a shipped architecture renamed.

    A shipped architecture is copied as it is, its modeline pointing at ``schema`` and
    its top-level ``name`` replaced by ``name``.
    """
    import re

    from archself.reports.render import render, yaml_string

    folder, _, file = TEMPLATES[template][1].partition("/")
    if folder == "templates":
        return render(file, name=name, file_name=file_name, schema_url=schema)
    text = (data_dir(folder) / file).read_text(encoding="utf-8")
    text = re.sub(r"\A# yaml-language-server: \$schema=.*$",
                  lambda _: f"# yaml-language-server: $schema={schema}", text, count=1, flags=re.M)
    return re.sub(r"^name: .*$", lambda _: f"name: {yaml_string(name)}", text, count=1,
                  flags=re.M)


def init(
    name: Annotated[str, typer.Argument(help="Name of the system; writes NAME.yaml.")],
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing file.")] = False,
    template: Annotated[
        str,
        typer.Option("--template", "-t", metavar="[" + "|".join(TEMPLATES) + "]",
                     callback=_template_choice,
                     autocompletion=lambda: list(TEMPLATES),
                     help="What to start from: " + "; ".join(
                         f"{k}: {v[0]}" for k, v in TEMPLATES.items()) + "."),
    ] = "tank",
    schema_ref: Annotated[
        str | None,
        typer.Option("--schema", metavar="REF",
                     help="The modeline's schema: a path or URL, or 'copy' to write "
                     "architecture.schema.json beside NAME.yaml (default: the project's "
                     "schemas/architecture.schema.json if there is one, else the published URL)."),
    ] = None,
) -> None:
    """Write a small, valid architecture file to start from (NAME.yaml).

    --template chooses it: a small tank (the default), a generic-blocks LTI loop, or a
    copy of a shipped example under the new name. The file carries the schema
    modeline, so an editor with yaml-language-server completes and checks it while
    you edit. The modeline never points into an
    installed package (a virtual environment's site-packages moves and goes): it names
    the schema of the project the file is in (a `schemas/architecture.schema.json` in
    its folder or above, as in the archself repository), else the schema's published
    URL, or what --schema says.
    """
    import os

    from archself.io.files import protect, write_text

    if not name.strip() or name.endswith(("/", os.sep)) or Path(name).name in (".", ".."):
        raise _fail(f"NAME {name!r}: expected a name such as 'tank' or 'plants/tank.yaml'", 2)
    target = Path(name if name.endswith((".yaml", ".yml")) else f"{name}.yaml")
    if any(ord(c) < 32 or ord(c) == 127 for c in name) or len(target.stem) > 128:
        # the stem is the file's `name` (a Name: printable, ≤ 128) and goes into comments
        raise _fail(f"NAME {name!r}: expected at most 128 printable characters "
                    "(no control characters) before .yaml", 2)
    if schema_ref is not None and any(ord(c) < 32 or ord(c) == 127 for c in schema_ref):
        raise _fail(f"--schema {schema_ref!r}: expected a path or URL without control "
                    "characters", 2)
    if target.exists() and not force:
        raise _fail(f"{target}: error: exists; pass --force to overwrite it")
    folder = target.parent
    copy_to = folder / "architecture.schema.json" if schema_ref == "copy" else None
    if copy_to is not None:
        schema = copy_to.name
    elif schema_ref is not None:
        schema = schema_ref
    else:
        schema = _project_schema(folder)
    text = _template_text(template, target.stem, target.name, schema)
    try:
        with protect([], [target, copy_to]):
            if copy_to is not None:
                from archself.model.schema import schema_text

                write_text(copy_to, schema_text())
            write_text(target, text)
    except ArchselfError as exc:
        raise _die(exc) from None
    typer.echo(f"wrote {target}; next: archself validate {target}")


def _project_schema(folder: Path) -> str:
    """The modeline's schema for a file in ``folder``: the nearest
    ``schemas/architecture.schema.json`` in it or above (relative), else the ``$id`` URL.

    A folder inside an installed package (``site-packages``, ``dist-packages``) is never
    named: a virtual environment is not where a project's files should point.
    """
    import os

    from archself.model.schema import SCHEMA_ID

    here = folder.resolve()
    for d in (here, *here.parents):
        cand = d / "schemas" / "architecture.schema.json"
        if cand.is_file() and not {"site-packages", "dist-packages"} & set(cand.parts):
            try:
                return Path(os.path.relpath(cand, here)).as_posix()
            except ValueError:  # another drive
                return cand.as_uri()
    return SCHEMA_ID


def export(
    arch: Annotated[Path, typer.Argument(metavar="FILE", help="Architecture file.")],
    to: Annotated[
        str,
        typer.Option("--to", metavar="FORMAT",
                     help="graphml, node-link, edges-csv or ros2-modes (docs/export.md)."),
    ],
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="Write to FILE (default: stdout).")
    ] = None,
    nodes: Annotated[
        str | None,
        typer.Option("--nodes", metavar="M1,M2,...",
                     help="ros2-modes: the modules that run as nodes (default: the functional "
                     "ones)."),
    ] = None,
) -> None:
    """Export the architecture for other tools: GraphML, node-link JSON, edge CSV, ROS 2 modes."""
    from archself.reports.export import FORMATS

    if to not in FORMATS:
        raise _fail(f"error: --to: {unknown('format', to, FORMATS)}", 2)
    with guard(arch, refuse=[("--output", output)], numeric=False):
        from archself.reports.export import export as export_text

        parts = [n.strip() for n in nodes.split(",") if n.strip()] if nodes else None
        text = export_text(_load(arch), to, nodes=parts)
    _emit(text, output, f"{output}: {to}")


def info(
    arch: Annotated[Path, typer.Argument(metavar="FILE", help="Architecture file.")],
    as_json: Annotated[
        bool, typer.Option("--json", help="Print what the file holds as one JSON object.")
    ] = False,
    stability: Annotated[
        bool, typer.Option("--stability", help="Add the whole-loop stability table (compiles "
                           "and runs every configuration; docs/stability.md).")
    ] = False,
) -> None:
    """What a file holds: modules, configurations, actions, scenarios and runtime settings."""
    from archself.reports.summary import summarize, summary_text

    with guard(arch, numeric=False):
        loaded = _load(arch)
        data = summarize(loaded)
    table = None
    if stability:
        from archself.check.stability import loop_table, table_text

        table = loop_table(loaded)
    if as_json:
        from archself.io.jsondata import InfoDoc, document

        data = document(InfoDoc, {**data, "stability": _verdicts(table)}, complete=True)
        typer.echo(json.dumps(data, indent=2))
    else:
        typer.echo(summary_text(data) + ("" if table is None else "\n" + table_text(table)))


#: ``generate`` refuses more modules than this without --yes (≈ 27 MB of JSON-compatible YAML).
GENERATE_MAX = 100_000
#: ... and more than this even with --yes (≈ 27 GB: more than the memory that builds it).
GENERATE_HARD_MAX = 100_000_000


def generate(
    n: Annotated[int, typer.Argument(metavar="N", min=2, help="Number of modules.")],
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="Write to FILE (default: stdout).")
    ] = None,
    seed: Annotated[int, typer.Option("--seed", min=0, help="Seed of the random wiring.")] = 0,
    fan_in: Annotated[int, typer.Option("--fan-in", min=1, help="Max. edges into a module.")] = 3,
    feedback: Annotated[
        int, typer.Option("--feedback", min=0, help="Weak backward edges (cycles).")
    ] = 0,
    yes: Annotated[
        bool, typer.Option("--yes", help=f"Generate even more than {GENERATE_MAX:,} modules.")
    ] = False,
) -> None:
    """Generate a large DAG-like architecture of N generic.relay modules (scaling studies)."""
    from archself.io.yaml_source import MAX_FILE_BYTES
    from archself.model.generate import generate_architecture

    for what, count in (("N", n), ("--feedback", feedback)):
        if count > GENERATE_HARD_MAX:  # np.sqrt of a huge int raised TypeError (exit 3)
            raise _fail(f"error: {what} = {count:,} is more than the hard cap of "
                        f"{GENERATE_HARD_MAX:,}, even with --yes")
    if n > GENERATE_MAX and not yes:
        raise _fail(
            f"error: N = {n:,} modules is more than the cap of {GENERATE_MAX:,} (about "
            f"{GENERATE_MAX * 270 // 1024**2} MB; the loader reads at most "
            f"{MAX_FILE_BYTES // 1024**2} MiB of JSON); "
            "pass --yes to generate it anyway"
        )
    if feedback > n * fan_in and not yes:
        raise _fail(f"error: --feedback {feedback:,} is more than N × --fan-in edges")
    fan_in = min(fan_in, n)  # no module has more than N − 1 predecessors
    text = generate_architecture(n, seed=seed, fan_in=fan_in, feedback=feedback)
    _emit(text, output, f"{output}: {n} modules")


def _verdicts(table: Any) -> list[dict[str, Any]]:
    """The whole-loop table as the data of ``--json`` (``VerdictDoc``: with the margin)."""
    return [{**vars(v), "margin": v.margin} for v in table or ()]
