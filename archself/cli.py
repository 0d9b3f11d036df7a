"""The ``archself`` command line (typer).

Data goes to stdout, diagnostics to stderr. Exit codes (``archself.errors.EXIT_CODES``,
docs/hardening.md): 0 ok, 1 findings or a user error, 2 usage error, 3 internal
error (a bug), 130 interrupted (SIGINT), 143 terminated (SIGTERM). No output is
written onto an input (:mod:`archself.outputs`). Heavy libraries (python-control,
filterpy, matplotlib) are imported inside the commands that need them, never at
start-up.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any

import typer

from archself.errors import ArchselfError

app = typer.Typer(
    name="archself",
    help="Carry a system's architecture as data: validate it, simulate it, adapt it (MAPE-K).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version(value: bool) -> None:
    if value:
        from archself import __version__

        typer.echo(f"archself {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool, typer.Option("--version", "-V", callback=_version, is_eager=True,
                           help="Print the version and exit.")
    ] = False,
) -> None:
    """Carry a system's architecture as data: validate it, simulate it, adapt it (MAPE-K)."""


# Options shared by the commands that run many simulations (campaign, calibrate).
ExecutorOption = Annotated[str, typer.Option("--executor", help="local (process pool) or dask.")]
AddressOption = Annotated[
    str | None, typer.Option("--address", help="Dask scheduler, tcp://HOST:PORT.")
]
WorkersOption = Annotated[
    int | None, typer.Option("--workers", min=1, help="Processes (default: all cores).")
]


def _fail(msg: str, code: int = 1) -> typer.Exit:
    typer.echo(msg if ":" in msg else f"error: {msg}", err=True)
    return typer.Exit(code)


def _die(err: ArchselfError) -> typer.Exit:
    typer.echo(str(err), err=True)
    return typer.Exit(err.exit_code)


def _emit(text: str, output: Path | None, done: str) -> None:
    """Write ``text`` to stdout (no ``output``, or ``-``) or atomically to ``output``."""
    if output is None or str(output) == "-":
        sys.stdout.write(text)
        return
    from archself.atomic import write_text

    try:
        write_text(output, text)
    except ArchselfError as exc:
        raise _die(exc) from None
    typer.echo(done, err=True)


#: Files ``simulate --report DIR`` writes that an input could be named like.
_RUN_REPORT_FILES = ("index.html", "summary.json")
#: ``simulate`` refuses more steps than this (runs × duration / step) without --yes.
SIM_MAX_STEPS = 5_000_000
#: and an estimated memory above this (bytes).
SIM_MAX_BYTES = 2 * 1024**3


def _inputs(*paths: Path, what: str = "an architecture file") -> None:
    """Every input must be a regular file (or a pipe): not missing, a folder or a device."""
    from archself.outputs import check_input

    for p in paths:
        check_input(p, what)


def _simulation_estimate(arch: Any, scenario: str, runs: int) -> tuple[int, int]:
    """``(steps, bytes)`` of ``runs`` runs of ``scenario`` (0, 0 for an unknown scenario)."""
    sc = arch.scenarios.get(scenario)
    if sc is None:
        return 0, 0
    steps = runs * round(float(sc.duration_s) / float(arch.runtime.step_s))
    n_res = sum(1 for m in arch.modules.values() if m.residual)
    # recorded per step: time, J, configuration, 4 series of ~3 floats, residual rows
    return steps, steps * (250 + 40 * n_res)


def _check_simulation_size(arch: Any, scenario: str, runs: int, yes: bool) -> None:
    steps, size = _simulation_estimate(arch, scenario, runs)
    if yes or (steps <= SIM_MAX_STEPS and size <= SIM_MAX_BYTES):
        return
    raise _fail(
        f"error: {runs} run{'s' * (runs != 1)} of {scenario} = {steps:,} steps, about "
        f"{size / 1024**2:,.0f} MB of series: more than the cap ({SIM_MAX_STEPS:,} steps, "
        f"{SIM_MAX_BYTES // 1024**3} GB); shorten duration_s or raise step_s, or pass --yes"
    )


@contextmanager
def _numeric(path: Path) -> Iterator[None]:
    """Numeric trouble of the libraries as located one-line messages.

    Warnings of numpy/scipy (overflow, singular matrix, ...) are collected and
    printed once each (at most 5) as ``PATH: warning: ...`` when the command
    succeeds, and dropped when it fails (its one-line message says why);
    an OverflowError or FloatingPointError (a value of the file out of the range of
    a float, e.g. ``acceptable: 1e308`` squared) is a one-line error, exit 1.
    """
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        try:
            yield
        except (OverflowError, FloatingPointError) as exc:
            detail = str(exc.args[-1]) if exc.args else type(exc).__name__
            raise _fail(
                f"{path}: error: a value of the file is out of the range of the computation "
                f"({type(exc).__name__}: {detail}); use smaller magnitudes"
            ) from None
        # after a success only: an error's one-line message is not led by warnings
        seen: set[str] = set()
        for w in caught:
            if not _numeric_warning(w):
                continue
            text = str(w.message).splitlines()[0] if str(w.message) else ""
            where = Path(w.filename).name
            line = f"{path}: warning: {w.category.__name__}: {text} (in {where})"
            if line not in seen and len(seen) < 5:
                seen.add(line)
                typer.echo(line, err=True)


def _numeric_warning(w: Any) -> bool:
    """A warning worth showing: from numpy/scipy/the runtime, not a library's deprecation."""
    if issubclass(w.category, DeprecationWarning | PendingDeprecationWarning):
        return False
    return issubclass(w.category, RuntimeWarning) or "numpy" in w.category.__module__ or (
        "scipy" in w.category.__module__
    )


# --------------------------------------------------------------------------- validate
@app.command()
def validate(
    paths: Annotated[
        list[Path], typer.Argument(help="Architecture files to check.", metavar="PATH...")
    ],
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
            _inputs(path)
            loaded = load_architecture(path)
            findings = check(loaded)
        except SchemaError as exc:
            findings = exc.findings
        except ArchselfError as exc:
            e = exc
            findings = [
                Finding(
                    "error",
                    "load",
                    getattr(e, "message", str(e)),
                    getattr(e, "path", ""),
                    str(path),
                    getattr(e, "line", None),
                    getattr(e, "col", None),
                )
            ]
        bad = [f for f in findings if f.severity == "error" or (strict and f.severity == "warning")]
        failed |= bool(bad)
        if json_out:
            report.append(
                {"file": str(path), "ok": not bad, "findings": [f.to_dict() for f in findings]}
            )
        else:
            for f in findings:
                typer.echo(str(f), err=True)
            if not bad:
                n = len(findings)
                typer.echo(f"{path}: ok" + (f" ({n} warning{'s' * (n != 1)})" if n else ""))
    if json_out:
        typer.echo(
            json.dumps(report if len(report) != 1 else report[0], indent=2, ensure_ascii=False)
        )
    raise typer.Exit(1 if failed else 0)


# --------------------------------------------------------------------------- schema
@app.command()
def schema(
    output: Annotated[Path | None, typer.Option("-o", "--output", help="Write to FILE.")] = None,
    check_file: Annotated[
        Path | None, typer.Option("--check", help="Exit 1 if FILE differs from the model.")
    ] = None,
) -> None:
    """Print the JSON Schema of architecture files, generated from the model."""
    from archself.schema import schema_text

    _write_or_check(
        {"architecture.schema.json": schema_text()}, output, check_file, "archself schema -o"
    )


@app.command()
def docs(
    folder: Annotated[Path, typer.Argument(help="Folder of the reference pages.")] = Path("docs"),
    check: Annotated[bool, typer.Option("--check", help="Exit 1 if a page is stale.")] = False,
) -> None:
    """Regenerate the reference pages (format.md from the schema, cli.md from this CLI)."""
    from archself.docgen import reference_pages

    for name, text in reference_pages(app).items():  # docgen never imports this module
        target = folder / name
        if check:
            _write_or_check({name: text}, None, target, f"archself docs {folder}")
        else:
            _write_or_check({name: text}, target, None, "")


def _write_or_check(
    pages: dict[str, str], output: Path | None, check_file: Path | None, regen: str
) -> None:

    (text,) = pages.values()
    if check_file is not None:
        try:
            _inputs(check_file, what="a file")
            current = check_file.read_text(encoding="utf-8")
        except ArchselfError as exc:
            raise _die(exc) from None
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


# --------------------------------------------------------------------------- init
@app.command()
def init(
    name: Annotated[str, typer.Argument(help="Name of the system; writes NAME.yaml.")],
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing file.")] = False,
) -> None:
    """Write a small, valid architecture file to start from (NAME.yaml).

    The file carries the schema modeline, so an editor with yaml-language-server
    completes and checks it while you edit.
    """
    import os

    from archself.atomic import write_text
    from archself.reports.render import render
    from archself.resources import schema_path

    if not name.strip() or name.endswith(("/", os.sep)) or Path(name).name in (".", ".."):
        raise _fail(f"NAME {name!r}: expected a name such as 'tank' or 'plants/tank.yaml'", 2)
    target = Path(name if name.endswith((".yaml", ".yml")) else f"{name}.yaml")
    if target.exists() and not force:
        raise _fail(f"{target}: error: exists; pass --force to overwrite it")
    folder = target.parent if str(target.parent) else Path(".")
    try:
        schema = os.path.relpath(schema_path(), folder.resolve())
    except ValueError:  # another drive
        schema = schema_path().as_uri()
    text = render("init.yaml.j2", name=target.stem, file_name=target.name, schema_url=schema)
    try:
        write_text(target, text)
    except ArchselfError as exc:
        raise _die(exc) from None
    typer.echo(f"wrote {target}; next: archself validate {target}")


# --------------------------------------------------------------------------- simulate
def _load(path: Path):
    from archself.check import check, has_errors
    from archself.loader import load_architecture

    loaded = load_architecture(path)
    findings = check(loaded)
    if has_errors(findings):
        for f in findings:
            if f.severity == "error":
                typer.echo(str(f), err=True)
        raise typer.Exit(1)
    return loaded.arch


def _run(
    arch, scenario: str, config: str | None, seed: int | None, adaptive: bool, show_progress: bool
):
    from archself.sim.run import simulate as run_simulation

    adapt = None
    if adaptive:
        from archself.runtime import MapeK

        adapt = MapeK(arch)
    if not show_progress:
        return run_simulation(arch, scenario, configuration=config, seed=seed, adapt=adapt)
    from contextlib import ExitStack

    steps, size = _simulation_estimate(arch, scenario, 1)
    label = (
        f"{scenario} ({'adaptive' if adaptive else 'fixed'}, {steps:,} steps, "
        f"~{max(1, round(size / 1024**2)):,} MB)"
    )
    with ExitStack() as stack:
        state: dict[str, Any] = {"done": 0, "bar": None}

        def progress(done: int, total: int) -> None:
            # the bar starts with the first simulated step, not before the imports and
            # the build, so that its time estimate is that of the simulation
            if state["bar"] is None:
                state["bar"] = stack.enter_context(
                    typer.progressbar(length=100, label=label, file=sys.stderr)
                )
            pct = int(100 * done / max(total, 1))
            if pct > state["done"]:
                state["bar"].update(pct - state["done"])
                state["done"] = pct

        return run_simulation(
            arch, scenario, configuration=config, seed=seed, adapt=adapt, progress=progress
        )


def _switches_text(switches: list[dict]) -> str:
    if not switches:
        return "none"
    return "; ".join(
        f"t = {s['t_s']:.1f} s {s['from']} → {s['to']} ({s['action']})" for s in switches
    )


def _summary(results: list) -> str:
    from archself.sim.run import metric_rows

    rows = metric_rows(results[0].unit)  # labels carry the unit of runtime.objective
    first = results[0]
    head = f"scenario {first.scenario} · seed {first.seed} · start {first.configuration}"
    lines = [head]
    names = [f"{r.mode} (→ {r.final_configuration})" for r in results]
    width = max(16, *(len(n) + 2 for n in names))
    left = max(18, *(len(label) + 2 for label, _, _ in rows))
    lines.append(" " * left + "".join(n.rjust(width) for n in names))
    for label, key, decimals in rows:
        vals = "".join(f"{r.metrics[key]:.{decimals}f}".rjust(width) for r in results)
        lines.append(label.ljust(left) + vals)
    for r in results:
        lines.append(f"switches ({r.mode}): {_switches_text(r.switches)}")
    return "\n".join(lines)


@app.command()
def simulate(
    arch_path: Annotated[Path, typer.Argument(metavar="ARCH", help="Architecture file.")],
    scenario: Annotated[str, typer.Option("--scenario", "-s", help="Scenario of the file.")],
    config: Annotated[
        str | None, typer.Option("--config", "-c", help="Start configuration (default: initial).")
    ] = None,
    fixed: Annotated[bool, typer.Option("--fixed", help="Hold the architecture fixed.")] = False,
    compare: Annotated[
        bool, typer.Option("--compare", help="Run the fixed baseline beside the adaptive run.")
    ] = False,
    seed: Annotated[
        int | None, typer.Option("--seed", min=0, help="Seed ≥ 0 (default: the scenario's).")
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    trace: Annotated[
        Path | None,
        typer.Option("--trace", help="Write the time series and decision log (JSON) to FILE."),
    ] = None,
    report: Annotated[
        Path | None,
        typer.Option(
            "--report",
            metavar="DIR",
            help="Write an HTML run report with the paper's figures to DIR.",
        ),
    ] = None,
    yes: Annotated[
        bool, typer.Option("--yes", help="Run even past the size cap (see docs/hardening.md).")
    ] = False,
) -> None:
    """Simulate a scenario: adaptive MAPE-K by default, --fixed for a fixed architecture.

    With --compare both run from the same start and seed; --trace FILE writes the
    adaptive trace to FILE and the fixed one to FILE with '.fixed' before the suffix.
    """
    if fixed and compare:
        raise _fail("--fixed and --compare exclude each other", 2)
    if trace is not None and not (trace.parent if str(trace.parent) else Path(".")).is_dir():
        raise _fail(f"{trace}: cannot write: folder {trace.parent} does not exist")
    from archself.atomic import protect
    from archself.outputs import refuse_same_file

    fixed_trace = None if trace is None else trace.with_name(f"{trace.stem}.fixed{trace.suffix}")
    try:
        _inputs(arch_path)
        for target, what in ((trace, "--trace"), (fixed_trace if compare else None, "--trace")):
            if target is not None:
                refuse_same_file([arch_path], target, what)
        if report is not None:
            for name in _RUN_REPORT_FILES:
                refuse_same_file([arch_path], report / name, "--report")
        with protect([arch_path]), _numeric(arch_path):
            arch = _load(arch_path)
            if config is not None and config not in arch.configurations:
                known = ", ".join(arch.configurations)
                raise _fail(f"{arch_path}: unknown configuration '{config}'; known: {known}")
            _check_simulation_size(arch, scenario, 2 if compare else 1, yes)
            show = sys.stderr.isatty() and not json_out
            modes = [False, True] if compare else [not fixed]
            results = [_run(arch, scenario, config, seed, adaptive, show) for adaptive in modes]
            if trace is not None:
                for r in results:
                    target = trace
                    if compare and r.mode == "fixed" and fixed_trace is not None:
                        target = fixed_trace
                    r.write_trace(target)
            if report is not None:
                from archself.reports.run_report import write_run_report

                write_run_report(arch, results, report)
                typer.echo(f"report: {report / 'index.html'}", err=True)
    except ArchselfError as exc:
        raise _die(exc) from None
    if json_out:
        data = [r.to_dict() for r in results]
        typer.echo(json.dumps(data if compare else data[0], indent=2, ensure_ascii=False))
    else:
        typer.echo(_summary(results))


# --------------------------------------------------------------------------- report
@app.command()
def report(
    arch_path: Annotated[Path, typer.Argument(metavar="ARCH", help="Architecture file.")],
    output: Annotated[
        Path,
        typer.Option(
            "-o", "--output", metavar="DIR", help="Folder to write the report into (created)."
        ),
    ],
    no_render: Annotated[
        bool, typer.Option("--no-render", help="DOT sources only, even if `dot` is installed.")
    ] = False,
    force: Annotated[
        bool, typer.Option("--force", help="Replace the report in an existing, non-empty DIR.")
    ] = False,
    yes: Annotated[
        bool, typer.Option("--yes", help="Write even past the cap on the number of files.")
    ] = False,
) -> None:
    """Architecture report: DSMs (HTML, Markdown, CSV), Fig. 1 graphs and configuration diffs.

    Graphs are rendered to SVG and PNG when Graphviz `dot` is on PATH; index.html links all.
    The report is written beside DIR and swapped in when complete (no half report,
    no stale files); a non-empty DIR is replaced only with --force.
    """
    from archself.atomic import protect
    from archself.outputs import refuse_input_inside

    try:
        _inputs(arch_path)
        refuse_input_inside([arch_path], output, "-o")
        with protect([arch_path]), _numeric(arch_path):
            arch = _load(arch_path)
            import shutil

            from archself.reports.architecture import (
                MAX_FILES,
                count_report_files,
                write_architecture_report,
            )

            files = count_report_files(arch, not no_render and shutil.which("dot") is not None)
            if files > MAX_FILES and not yes:
                raise _fail(
                    f"{arch_path}: error: the report would be {files:,} files "
                    f"({len(arch.configurations):,} configurations), more than the cap of "
                    f"{MAX_FILES:,}; pass --yes to write them"
                )
            if files > MAX_FILES:
                typer.echo(f"writing {files:,} files into {output}", err=True)
            rep = write_architecture_report(arch, output, dot=not no_render, force=force)
    except ArchselfError as exc:
        raise _die(exc) from None
    if rep.note and not no_render:
        typer.echo(f"note: {rep.note}", err=True)
    typer.echo(str(rep.index))


# --------------------------------------------------------------------------- explain
@app.command()
def explain(
    trace: Annotated[Path, typer.Argument(help="A trace written by `simulate --trace`.")],
) -> None:
    """Explain a run's decisions: why (and why not) the architecture switched."""
    from archself.runtime.decisions import explain as render

    try:
        _inputs(trace, what="a trace (JSON)")
        doc = json.loads(trace.read_text(encoding="utf-8"))
        meta, decisions = doc["meta"], doc["decisions"]
    except ArchselfError as exc:
        raise _die(exc) from None
    except FileNotFoundError:
        raise _fail(f"{trace}: error: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise _fail(f"{trace}: error: not an archself trace ({type(exc).__name__})") from None
    typer.echo(
        f"{meta.get('architecture', '?')} · scenario {meta.get('scenario')} · "
        f"seed {meta.get('seed')} · {meta.get('mode')} · "
        f"{meta.get('configuration')} → {meta.get('final_configuration')}"
    )
    typer.echo(render(decisions))


# --------------------------------------------------------------------------- campaign
@app.command()
def campaign(
    arch_path: Annotated[Path, typer.Argument(metavar="ARCH", help="Architecture file.")],
    scenarios: Annotated[
        list[str], typer.Option("--scenario", "-s", help="Scenario of the file (repeatable).")
    ],
    seeds: Annotated[
        int, typer.Option("--seeds", help="Seeds (replicates) per scenario and sweep point.")
    ],
    sweep: Annotated[
        list[str] | None,
        typer.Option(
            "--sweep",
            metavar="PATH=START:STOP:NUM",
            help="Vary a value of the file, e.g. runtime.threshold=0.4:0.7:4 or "
            "scenarios.imu_drift.faults[0].magnitude=1e-4,7e-4 (repeatable: product).",
        ),
    ] = None,
    mode: Annotated[str, typer.Option("--mode", help="both, fixed or adaptive.")] = "both",
    executor: ExecutorOption = "local",
    address: AddressOption = None,
    workers: WorkersOption = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Results file (Parquet).")] = Path(
        "results.parquet"
    ),
    resume: Annotated[
        bool, typer.Option("--resume", help="Keep the runs already in --out; run the rest.")
    ] = False,
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing --out.")] = False,
    traces: Annotated[
        Path | None, typer.Option("--traces", metavar="DIR", help="Write every run's trace here.")
    ] = None,
    root_seed: Annotated[
        int, typer.Option("--root-seed", min=0, help="Root of the seed sequence (≥ 0).")
    ] = 0,
    json_out: Annotated[bool, typer.Option("--json", help="Print the outcome as JSON.")] = False,
    yes: Annotated[
        bool, typer.Option("--yes", help="Run even past the size cap (see docs/hardening.md).")
    ] = False,
) -> None:
    """Run a Monte Carlo campaign: scenarios x sweep values x seeds, fixed and adaptive.

    One Parquet row per run, written as runs finish; Ctrl-C keeps the finished
    runs (exit 130; SIGTERM: 143) and --resume continues. The same command gives
    the same table whatever the number of workers. A campaign larger than the cap
    (runs, steps) needs --yes; --out is never the architecture file.
    """
    from archself.campaign.driver import plan_campaign, run_campaign
    from archself.campaign.sweep import parse_sweep

    modes = {"both": ("fixed", "adaptive"), "fixed": ("fixed",), "adaptive": ("adaptive",)}
    if mode not in modes:
        raise _fail(f"--mode {mode}: expected both, fixed or adaptive", 2)
    if executor not in ("local", "dask"):
        raise _fail(f"--executor {executor}: expected local or dask", 2)
    if resume and force:
        raise _fail("--resume and --force exclude each other", 2)
    from archself.atomic import protect
    from archself.outputs import refuse_same_file

    try:
        _inputs(arch_path)
        refuse_same_file([arch_path], out, "--out")
        sweeps = [parse_sweep(s) for s in sweep or []]
        with protect([arch_path]), _numeric(arch_path):
            jobs, meta = plan_campaign(
                arch_path,
                scenarios,
                seeds,
                sweeps,
                modes=modes[mode],
                root_seed=root_seed,
                traces=traces,
                yes=yes,
            )
            show = sys.stderr.isatty() and not json_out
            bar = None
            state = {"done": 0}
            steps = int(meta.get("steps", 0))

            def progress(done: int, total: int) -> None:
                nonlocal bar
                if bar is None:
                    per = steps // max(len(jobs), 1)
                    label = f"{total:,} runs × {per:,} steps"
                    bar = typer.progressbar(length=total, label=label, file=sys.stderr)
                    bar.__enter__()
                bar.update(done - state["done"])
                state["done"] = done

            try:
                outcome = run_campaign(
                    jobs,
                    meta,
                    out,
                    executor=executor,
                    workers=workers,
                    address=address,
                    resume=resume,
                    force=force,
                    progress=progress if show else None,
                    notice=lambda msg: typer.echo(f"warning: {msg}", err=True),
                )
            finally:
                if bar is not None:
                    bar.__exit__(None, None, None)
    except ArchselfError as exc:
        raise _die(exc) from None
    data = {
        "out": str(outcome.out),
        "planned": outcome.planned,
        "skipped": outcome.skipped,
        "ran": outcome.ran,
        "failed": outcome.failed,
        "rows": outcome.rows,
        "executor": outcome.executor,
        "workers": outcome.workers,
        "elapsed_s": round(outcome.elapsed_s, 3),
        "errors": outcome.errors,
    }
    if json_out:
        typer.echo(json.dumps(data, indent=2, ensure_ascii=False))
    else:
        rate = f", {outcome.ran / outcome.elapsed_s:.2f} runs/s" if outcome.elapsed_s > 0 else ""
        typer.echo(
            f"{outcome.out}: {outcome.rows} runs ({outcome.ran} new, {outcome.skipped} "
            f"already there, {outcome.failed} failed) in {outcome.elapsed_s:.1f} s on "
            f"{outcome.workers} {outcome.executor} worker"
            f"{'s' * (outcome.workers != 1)}{rate}"
        )
        for e in outcome.errors:
            typer.echo(f"failed: {e}", err=True)


@app.command("campaign-report")
def campaign_report_cmd(
    results: Annotated[Path, typer.Argument(metavar="RESULTS", help="Parquet file of `campaign`.")],
    out_dir: Annotated[Path, typer.Option("-o", "--output", metavar="DIR", help="Report folder.")],
    expect: Annotated[
        list[str] | None,
        typer.Option(
            "--expect",
            metavar="SCENARIO=CONFIG",
            help="Expected final configuration of a scenario (repeatable).",
        ),
    ] = None,
    tau: Annotated[
        str | None, typer.Option("--tau", metavar="PATH", help="Swept column holding τ.")
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Summarize a campaign: correct switches, detection delay, false switches, errors, τ sweep.

    Writes DIR/index.html (figures as SVG beside it) and DIR/summary.json.
    """
    from archself.atomic import protect
    from archself.campaign.report import campaign_report, parse_expect, summary_text
    from archself.outputs import refuse_same_file

    try:
        _inputs(results, what="a results file (Parquet)")
        for name in _RUN_REPORT_FILES:
            refuse_same_file([results], out_dir / name, "-o")
        with protect([results]), _numeric(results):
            summary = campaign_report(
                results, out_dir, expect=parse_expect(expect or []), tau_path=tau
            )
    except ArchselfError as exc:
        raise _die(exc) from None
    if json_out:
        from archself.jsondata import jsonable

        typer.echo(json.dumps(jsonable(summary.to_dict()), indent=2, ensure_ascii=False))
    else:
        typer.echo(summary_text(summary))
        typer.echo(f"report: {out_dir / 'index.html'}", err=True)


# --------------------------------------------------------------------------- export, info
@app.command()
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
) -> None:
    """Export the architecture for other tools: GraphML, node-link JSON, edge CSV, ROS 2 modes."""
    from archself.export import FORMATS

    if to not in FORMATS:
        raise _fail(f"error: --to: unknown format '{to}'; choose one of {', '.join(FORMATS)}", 2)
    _inputs(arch)
    try:
        if output is not None and str(output) != "-":
            from archself.outputs import refuse_same_file

            refuse_same_file([arch], output, "--output")
        from archself.export import export as export_text

        text = export_text(_load(arch), to)
    except ArchselfError as exc:
        raise _die(exc) from None
    _emit(text, output, f"{output}: {to}")


@app.command()
def info(
    arch: Annotated[Path, typer.Argument(metavar="FILE", help="Architecture file.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """What a file holds: modules, configurations, actions, scenarios and runtime settings."""
    from archself.summary import summarize, summary_text

    _inputs(arch)
    try:
        data = summarize(_load(arch))
    except ArchselfError as exc:
        raise _die(exc) from None
    typer.echo(json.dumps(data, indent=2) if as_json else summary_text(data))


# --------------------------------------------------------------------------- calibrate
@app.command()
def calibrate(
    arch_path: Annotated[Path, typer.Argument(metavar="ARCH", help="Architecture file.")],
    false_switch: Annotated[
        float,
        typer.Option("--false-switch", metavar="P", help="Target false alarms per nominal run."),
    ] = 0.01,
    seeds: Annotated[
        int, typer.Option("--seeds", min=1, help="Runs per scenario and configuration.")
    ] = 100,
    scenarios: Annotated[
        list[str] | None,
        typer.Option("--scenario", "-s", help="Fault-free scenario (repeatable; default: all)."),
    ] = None,
    configurations: Annotated[
        list[str] | None,
        typer.Option("--configuration", "-c", help="Configuration (repeatable; default: all)."),
    ] = None,
    verify_seeds: Annotated[
        int, typer.Option("--verify-seeds", min=0, help="Fresh seeds to measure the new rate on.")
    ] = 0,
    executor: ExecutorOption = "local",
    address: AddressOption = None,
    workers: WorkersOption = None,
    root_seed: Annotated[int, typer.Option("--root-seed", help="Root of the seed sequence.")] = 0,
    output: Annotated[
        Path | None,
        typer.Option("-o", "--output", metavar="FILE", help="Write the calibrated copy."),
    ] = None,
    in_place: Annotated[
        bool, typer.Option("--in-place", help="Calibrate ARCH itself (needs --force).")
    ] = False,
    force: Annotated[bool, typer.Option("--force", help="Overwrite FILE (or ARCH).")] = False,
    report_dir: Annotated[
        Path | None, typer.Option("--report", metavar="DIR", help="Write the HTML/Markdown report.")
    ] = None,
    json_out: Annotated[
        bool, typer.Option("--json", help="Print the bands and rates as JSON.")
    ] = False,
    save_runs: Annotated[
        Path | None,
        typer.Option("--save-runs", metavar="FILE", help="Keep the runs' residuals (.npz)."),
    ] = None,
    from_runs: Annotated[
        Path | None,
        typer.Option("--from-runs", metavar="FILE", help="Use saved runs instead of running."),
    ] = None,
    envelope: Annotated[
        list[str] | None,
        typer.Option(
            "--envelope",
            metavar="PATH=VALUES",
            help="Operating condition to cover, as campaign --sweep (repeatable: product), e.g. "
            "modules.gps.params.noise_m.value=0.2,0.4; the bands hold in the worst point.",
        ),
    ] = None,
) -> None:
    """Derive residual bands (residual.nominal) for a target false-switch rate from nominal runs.

    Runs every fault-free scenario fixed in every configuration for --seeds seeds
    (local pool or Dask), records the Monitor's filtered residuals and chooses the
    bands so that at most P of the nominal runs raise a candidate (Gumbel tail of
    the per-run maxima). docs/calibrate.md.
    """
    from archself.calibration.driver import calibrate as run_calibration
    from archself.calibration.edit import check_output

    if not 0.0 < false_switch < 1.0:
        raise _fail(f"--false-switch {false_switch:g}: expected a rate between 0 and 1", 2)
    if executor not in ("local", "dask"):
        raise _fail(f"--executor {executor}: expected local or dask", 2)
    if in_place and output is not None:
        raise _fail("--in-place and --output exclude each other", 2)
    if in_place and not force:
        raise _fail("--in-place overwrites ARCH: pass --force as well", 2)
    target = arch_path if in_place else output
    try:
        if target is not None:
            check_output(arch_path, target, in_place=in_place, force=force)
        if save_runs is not None:
            check_output(arch_path, save_runs, in_place=False, force=force)
        show = sys.stderr.isatty() and not json_out
        bar = None
        state = {"done": 0}

        def progress(done: int, total: int) -> None:
            nonlocal bar
            if done < state["done"] or bar is None:
                if bar is not None:
                    bar.__exit__(None, None, None)
                bar = typer.progressbar(length=total, label=f"{total} runs", file=sys.stderr)
                bar.__enter__()
                state["done"] = 0
            bar.update(done - state["done"])
            state["done"] = done

        try:
            cal = run_calibration(
                arch_path, false_switch=false_switch, seeds=seeds, scenarios=scenarios,
                configurations=configurations, root_seed=root_seed, executor=executor,
                workers=workers, address=address, verify_seeds=verify_seeds,
                progress=progress if show else None, save_runs=save_runs, from_runs=from_runs,
                envelope=envelope or (),
            )
        finally:
            if bar is not None:
                bar.__exit__(None, None, None)
        if target is not None:
            from archself.atomic import write_text

            write_text(target, cal.text)
        if report_dir is not None:
            from archself.calibration.report import write_report

            index = write_report(cal, report_dir)
    except ArchselfError as exc:
        raise _die(exc) from None
    if json_out:
        typer.echo(json.dumps(cal.to_dict(), indent=2, ensure_ascii=False))
    else:
        from archself.calibration.report import summary_text

        typer.echo(summary_text(cal))
    if target is not None:
        typer.echo(f"wrote {target}", err=True)
    if report_dir is not None:
        typer.echo(f"report: {index}", err=True)


# --------------------------------------------------------------------------- identify
def _perturbations(items: list[str] | None) -> dict[str, tuple[str, float]]:
    """``--perturb MODULE=KIND:X`` options as module -> (kind, magnitude)."""
    out: dict[str, tuple[str, float]] = {}
    for item in items or ():
        name, _, rest = item.partition("=")
        kind, _, mag = rest.partition(":")
        try:
            value = float(mag)
        except ValueError:
            value = math.nan
        if not name or not kind or not math.isfinite(value):
            raise _fail(f"--perturb {item}: expected MODULE=KIND:MAGNITUDE, e.g. imu=bias:0.01", 2)
        out[name] = (kind, value)
    return out


@app.command()
def identify(
    arch_path: Annotated[Path, typer.Argument(metavar="ARCH", help="Architecture file.")],
    configurations: Annotated[
        list[str] | None,
        typer.Option("--configuration", "-c", help="Configuration (repeatable; default: all)."),
    ] = None,
    scenario: Annotated[
        str | None,
        typer.Option("--scenario", "-s", help="Fault-free scenario (default: nominal)."),
    ] = None,
    seeds: Annotated[
        int, typer.Option("--seeds", min=1, help="Seeds per experiment and configuration.")
    ] = 3,
    kind: Annotated[
        str, typer.Option("--kind", help="Fault kind of each perturbation (on the main output).")
    ] = "bias",
    magnitude: Annotated[
        float, typer.Option("--magnitude", metavar="X", help="Size of each perturbation.")
    ] = 0.1,
    perturb: Annotated[
        list[str] | None,
        typer.Option(
            "--perturb", metavar="MODULE=KIND:X",
            help="Perturbation of one module (repeatable; X = 0 leaves it out).",
        ),
    ] = None,
    settle: Annotated[
        float | None,
        typer.Option("--settle", metavar="S",
                     help="Average from S seconds (default: warm-up + 5 × longest smoothing)."),
    ] = None,
    min_excitation: Annotated[
        float,
        typer.Option("--min-excitation", help="A source moving its Δr less is not identifiable."),
    ] = 0.05,
    executor: Annotated[
        str, typer.Option("--executor", help="local (process pool), dask or inline.")
    ] = "local",
    address: AddressOption = None,
    workers: WorkersOption = None,
    root_seed: Annotated[int, typer.Option("--root-seed", help="Root of the seed sequence.")] = 0,
    json_out: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    all_edges: Annotated[
        bool, typer.Option("--all", help="List the edges that are not identifiable too.")
    ] = False,
    output: Annotated[
        Path | None,
        typer.Option("-o", "--output", metavar="FILE", help="Write the Markdown report."),
    ] = None,
    write_back: Annotated[
        Path | None,
        typer.Option("--write-back", metavar="FILE",
                     help="Write a copy of ARCH with the fitted weights (comments kept)."),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite FILE.")] = False,
) -> None:
    """Estimate the edge weights W from perturbation experiments; fitted vs declared.

    Runs the fault-free scenario fixed in each configuration, unperturbed and with a
    small fault on each module that takes it, --seeds times, and fits the weights of
    the edges into each module with a residual from the differences of the
    time-averaged residuals (non-negative least squares, standard errors, R²).
    docs/identify.md.
    """
    from archself.calibration.edit import check_output
    from archself.calibration.identify import identify as run_identify

    if executor not in ("local", "dask", "inline"):
        raise _fail(f"--executor {executor}: expected local, dask or inline", 2)
    if not math.isfinite(magnitude):
        raise _fail(f"--magnitude {magnitude}: expected a finite number", 2)
    overrides = _perturbations(perturb)
    try:
        from archself.outputs import refuse_same_file

        _inputs(arch_path)

        if output is not None and str(output) != "-":
            refuse_same_file([arch_path], output, "-o")
        if write_back is not None:
            check_output(arch_path, write_back, in_place=False, force=force)
        with _numeric(arch_path):
            ident = run_identify(
                arch_path, configurations=configurations, scenario=scenario, seeds=seeds,
                kind=kind, magnitude=magnitude, perturb=overrides, settle_s=settle,
                min_excitation=min_excitation, root_seed=root_seed, executor=executor,
                workers=workers, address=address,
            )
        copy = None
        if write_back is not None:
            from archself.calibration.identify import written_copy

            copy = written_copy(ident)
    except ArchselfError as exc:
        raise _die(exc) from None
    from archself.calibration.identify import markdown_table, summary_text

    if json_out:
        typer.echo(json.dumps(ident.to_dict(), indent=2, ensure_ascii=False))
    elif output is None or str(output) != "-":
        typer.echo(summary_text(ident, all_edges=all_edges), nl=False)
    if output is not None:
        _emit(markdown_table(ident), output, f"wrote {output}")
    if write_back is not None and copy is not None:
        from archself.atomic import write_text

        try:
            write_text(write_back, copy)
        except ArchselfError as exc:
            raise _die(exc) from None
        typer.echo(f"wrote {write_back}", err=True)


# --------------------------------------------------------------------------- generate
#: ``generate`` refuses more modules than this without --yes (≈ 22 MB of YAML).
GENERATE_MAX = 100_000


@app.command()
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
    from archself.generate import generate_architecture

    if n > GENERATE_MAX and not yes:
        raise _fail(
            f"error: N = {n:,} modules is more than the cap of {GENERATE_MAX:,} (about "
            f"{GENERATE_MAX * 230 // 1024**2} MB of YAML; the loader reads at most 20 MB); "
            "pass --yes to generate it anyway"
        )
    if feedback > n * fan_in and not yes:
        raise _fail(f"error: --feedback {feedback:,} is more than N × --fan-in edges")
    fan_in = min(fan_in, n)  # no module has more than N − 1 predecessors
    text = generate_architecture(n, seed=seed, fan_in=fan_in, feedback=feedback)
    _emit(text, output, f"{output}: {n} modules")


def main() -> None:
    """Entry point of the ``archself`` script."""
    from archself.campaign.executors import single_thread_blas

    single_thread_blas()  # before numpy loads: small matrices, no use for BLAS threads
    import signal

    from archself.errors import Terminated, raise_terminated

    signal.signal(signal.SIGTERM, raise_terminated)  # the clean-up of Ctrl-C, exit 143
    try:
        app()
    except SystemExit as exc:
        # typer turns Ctrl-C into a silent exit 130: say what happened
        cause = exc.__context__.__cause__ if exc.__context__ is not None else None
        if exc.code == 130 and isinstance(cause, KeyboardInterrupt):
            terminated = isinstance(cause, Terminated)
            typer.echo("terminated" if terminated else "interrupted", err=True)
            raise SystemExit(143 if terminated else 130) from None
        raise
    except KeyboardInterrupt as exc:
        terminated = isinstance(exc, Terminated)
        typer.echo("terminated" if terminated else "interrupted", err=True)
        raise SystemExit(143 if terminated else 130) from None
    except ArchselfError as exc:
        typer.echo(str(exc), err=True)
        raise SystemExit(exc.exit_code) from None
    except MemoryError:
        typer.echo("error: out of memory; the work asked for is too large for this machine",
                   err=True)
        raise SystemExit(1) from None
    except OSError as exc:  # the system refused (permissions, disk full): not a bug
        where = f"{exc.filename}: " if exc.filename else ""
        typer.echo(f"{where}error: {exc.strerror or exc}", err=True)
        raise SystemExit(1) from None
    except Exception as exc:  # a bug, not a user error: say so in one line
        import os

        if os.environ.get("ARCHSELF_DEBUG"):
            raise
        typer.echo(
            f"internal error: {type(exc).__name__}: {exc} "
            "(set ARCHSELF_DEBUG=1 for the traceback; please report it)",
            err=True,
        )
        raise SystemExit(3) from None
