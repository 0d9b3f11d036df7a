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
)


def _fail(msg: str, code: int = 1) -> typer.Exit:
    typer.echo(msg if ":" in msg else f"error: {msg}", err=True)
    return typer.Exit(code)


def _die(err: ArchselfError) -> typer.Exit:
    typer.echo(str(err), err=True)
    return typer.Exit(err.exit_code)


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
    from archself.atomic import write_text

    (text,) = pages.values()
    if check_file is not None:
        try:
            current = check_file.read_text(encoding="utf-8")
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
    elif output is None:
        sys.stdout.write(text)
    else:
        try:
            write_text(output, text)
        except ArchselfError as exc:
            raise _die(exc) from None
        typer.echo(f"wrote {output}", err=True)


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

    label = f"{scenario} ({'adaptive' if adaptive else 'fixed'})"
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
    rows = [
        ("max error [m]", "max_error_m", "{:.3f}"),
        ("final error [m]", "final_error_m", "{:.3f}"),
        ("RMS error [m]", "rms_error_m", "{:.3f}"),
        ("peak time [s]", "peak_time_s", "{:.1f}"),
    ]
    first = results[0]
    head = f"scenario {first.scenario} · seed {first.seed} · start {first.configuration}"
    lines = [head]
    names = [f"{r.mode} (→ {r.final_configuration})" for r in results]
    width = max(16, *(len(n) + 2 for n in names))
    lines.append(" " * 18 + "".join(n.rjust(width) for n in names))
    for label, key, fmt in rows:
        vals = "".join(fmt.format(r.metrics[key]).rjust(width) for r in results)
        lines.append(label.ljust(18) + vals)
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
) -> None:
    """Simulate a scenario: adaptive MAPE-K by default, --fixed for a fixed architecture.

    With --compare both run from the same start and seed; --trace FILE writes the
    adaptive trace to FILE and the fixed one to FILE with '.fixed' before the suffix.
    """
    if fixed and compare:
        raise _fail("--fixed and --compare exclude each other", 2)
    if trace is not None and not (trace.parent if str(trace.parent) else Path(".")).is_dir():
        raise _fail(f"{trace}: cannot write: folder {trace.parent} does not exist")
    try:
        arch = _load(arch_path)
        if config is not None and config not in arch.configurations:
            known = ", ".join(arch.configurations)
            raise _fail(f"{arch_path}: unknown configuration '{config}'; known: {known}")
        show = sys.stderr.isatty() and not json_out
        modes = [False, True] if compare else [not fixed]
        results = [_run(arch, scenario, config, seed, adaptive, show) for adaptive in modes]
        if trace is not None:
            for r in results:
                target = trace
                if compare and r.mode == "fixed":
                    target = trace.with_name(f"{trace.stem}.fixed{trace.suffix}")
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
) -> None:
    """Architecture report: DSMs (HTML, Markdown, CSV), Fig. 1 graphs and configuration diffs.

    Graphs are rendered to SVG and PNG when Graphviz `dot` is on PATH; index.html links all.
    """
    try:
        arch = _load(arch_path)
        from archself.reports.architecture import write_architecture_report

        rep = write_architecture_report(arch, output, dot=not no_render)
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
        doc = json.loads(trace.read_text(encoding="utf-8"))
        meta, decisions = doc["meta"], doc["decisions"]
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
    executor: Annotated[
        str, typer.Option("--executor", help="local (process pool) or dask.")
    ] = "local",
    address: Annotated[
        str | None, typer.Option("--address", help="Dask scheduler, tcp://HOST:PORT.")
    ] = None,
    workers: Annotated[
        int | None, typer.Option("--workers", min=1, help="Processes (default: all cores).")
    ] = None,
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
    root_seed: Annotated[int, typer.Option("--root-seed", help="Root of the seed sequence.")] = 0,
    json_out: Annotated[bool, typer.Option("--json", help="Print the outcome as JSON.")] = False,
) -> None:
    """Run a Monte Carlo campaign: scenarios x sweep values x seeds, fixed and adaptive.

    One Parquet row per run, written as runs finish; Ctrl-C keeps the finished
    runs (exit 130) and --resume continues. The same command gives the same
    table whatever the number of workers.
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
    try:
        sweeps = [parse_sweep(s) for s in sweep or []]
        jobs, meta = plan_campaign(
            arch_path,
            scenarios,
            seeds,
            sweeps,
            modes=modes[mode],
            root_seed=root_seed,
            traces=traces,
        )
        show = sys.stderr.isatty() and not json_out
        bar = None
        state = {"done": 0}

        def progress(done: int, total: int) -> None:
            nonlocal bar
            if bar is None:
                bar = typer.progressbar(length=total, label=f"{total} runs", file=sys.stderr)
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
    from archself.campaign.report import campaign_report, parse_expect, summary_text

    try:
        summary = campaign_report(results, out_dir, expect=parse_expect(expect or []), tau_path=tau)
    except ArchselfError as exc:
        raise _die(exc) from None
    if json_out:
        from archself.campaign.report import _jsonable

        typer.echo(json.dumps(_jsonable(summary.to_dict()), indent=2, ensure_ascii=False))
    else:
        typer.echo(summary_text(summary))
        typer.echo(f"report: {out_dir / 'index.html'}", err=True)


# --------------------------------------------------------------------------- generate
@app.command()
def generate(
    n: Annotated[int, typer.Argument(metavar="N", min=2, help="Number of modules.")],
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="Write to FILE (default: stdout).")
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the random wiring.")] = 0,
    fan_in: Annotated[int, typer.Option("--fan-in", min=1, help="Max. edges into a module.")] = 3,
    feedback: Annotated[
        int, typer.Option("--feedback", min=0, help="Weak backward edges (cycles).")
    ] = 0,
) -> None:
    """Generate a large DAG-like architecture of N generic.relay modules (scaling studies)."""
    from archself.atomic import write_text
    from archself.generate import generate_architecture

    text = generate_architecture(n, seed=seed, fan_in=fan_in, feedback=feedback)
    if output is None:
        sys.stdout.write(text)
        return
    try:
        write_text(output, text)
    except ArchselfError as exc:
        raise _die(exc) from None
    typer.echo(f"{output}: {n} modules", err=True)


def main() -> None:
    """Entry point of the ``archself`` script."""
    from archself.campaign.executors import single_thread_blas

    single_thread_blas()  # before numpy loads: small matrices, no use for BLAS threads
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
        typer.echo(
            f"internal error: {type(exc).__name__}: {exc} "
            "(set ARCHSELF_DEBUG=1 for the traceback; please report it)",
            err=True,
        )
        raise SystemExit(3) from None
