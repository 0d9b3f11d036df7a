"""Commands on single runs: simulate, explain (``report`` is in :mod:`archself.cli.reports`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from archself.cli.base import (
    _RUN_REPORT_FILES,
    DpiOption,
    FormatOption,
    PastCapOption,
    _fail,
    _formats,
    _known_configuration,
    _load,
    guard,
    note,
    show_progress,
)

#: ``simulate`` refuses more steps than this (runs × duration / step) without --yes.
SIM_MAX_STEPS = 5_000_000
#: and an estimated memory above this (bytes).
SIM_MAX_BYTES = 2 * 1024**3


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


def _run(
    arch, scenario: str, config: str | None, seed: int | None, adaptive: bool, show_progress: bool,
    learned: Any = None,
):
    from contextlib import ExitStack

    from archself.sim.run import simulate as run_simulation

    adapt = None
    if adaptive:
        from archself.runtime import MapeK

        adapt = MapeK(arch, learned=learned)

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

        return run_simulation(arch, scenario, configuration=config, seed=seed, adapt=adapt,
                              progress=progress if show_progress else None)


def _switches_text(switches: list[dict]) -> str:
    if not switches:
        return "none"
    return "; ".join(
        f"t = {s['t_s']:.1f} s {s['from']} → {s['to']} ({s['action']})" for s in switches
    )


def _summary(results: list) -> str:
    from archself.sim.result import metric_rows

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
    for r in results:
        if r.faults:
            lines.append(f"module faults ({r.mode}): {_faults_text(r.faults)}")
    return "\n".join(lines)


def _faults_text(faults: list[dict]) -> str:
    """``module reason t = a–b s (n steps)``, the first five, then how many more."""
    text = [f"{f['module']} {f['reason']} t = {f['first_s']:.1f}–{f['last_s']:.1f} s "
            f"({f['steps']:,} step{'s' * (f['steps'] != 1)})" for f in faults[:5]]
    more = len(faults) - 5
    return "; ".join(text) + (f"; and {more} more" if more > 0 else "")


def simulate(
    arch_path: Annotated[
        Path, typer.Argument(metavar="ARCH", help="Architecture file ('-': stdin).")
    ],
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
    json_out: Annotated[
        bool,
        typer.Option("--json", help="Print one JSON object {runs: [...]}, one {scenario, "
                     "seed, mode, configuration, final_configuration, unit, metrics, "
                     "switches} per run: one run, or [fixed, adaptive] with --compare "
                     "(docs/json.md)."),
    ] = False,
    trace: Annotated[
        Path | None,
        typer.Option(
            "--trace", metavar="FILE",
            help="Write the time series and decision log to FILE: Parquet if it ends in "
            ".parquet, else JSON; '-' writes JSON to stdout (the summary goes to stderr).",
        ),
    ] = None,
    report: Annotated[
        Path | None,
        typer.Option(
            "--report",
            metavar="DIR",
            help="Write an HTML run report with the paper's figures to DIR.",
        ),
    ] = None,
    fig_format: FormatOption = None,
    dpi: DpiOption = 150,
    yes: PastCapOption = False,
    knowledge: Annotated[
        Path | None,
        typer.Option("--knowledge", metavar="FILE", help="Start from what earlier runs learned "
                     "(a table --save-knowledge wrote, or the trace of a run with learning "
                     "on); switches runtime.learning on "
                     "(docs/learning.md)."),
    ] = None,
    save_knowledge: Annotated[
        Path | None,
        typer.Option("--save-knowledge", metavar="FILE", help="Write what the adaptive run "
                     "learned from its actions' outcomes to FILE (JSON); switches "
                     "runtime.learning on."),
    ] = None,
    online: Annotated[
        bool,
        typer.Option("--online", help="Switch runtime.online's updates of W and of the bands "
                     "on for the adaptive run, with the file's other online settings; every "
                     "update is in the trace and the decision log (docs/learning.md)."),
    ] = False,
) -> None:
    """Simulate a scenario: adaptive MAPE-K by default, --fixed for a fixed architecture.

    With --compare both run from the same start and seed; --trace FILE writes the
    adaptive trace to FILE and the fixed one to FILE with '.fixed' before the suffix.
    """
    _simulate(
        arch_path, scenario, config=config, fixed=fixed, compare=compare, seed=seed,
        json_out=json_out, trace=trace, report=report, fig_format=fig_format, dpi=dpi, yes=yes,
        knowledge=(knowledge, save_knowledge), online=online,
    )


def _knowledge_table(arch_path: Path, paths: tuple[Path | None, Path | None]) -> Any:
    """The learned table ``--knowledge`` reads (an empty one for ``--save-knowledge``)."""
    source, target = paths
    if source is None and target is None:
        return None
    if target is not None:
        if not target.name or not target.parent.is_dir():
            raise _fail(f"{target}: cannot write: --save-knowledge takes a file in a folder "
                        f"that exists")
    from archself.runtime.knowledge import OutcomeTable, load_table

    return OutcomeTable() if source is None else load_table(source)


def _check_options(trace: Path | None, *, fixed: bool, compare: bool, json_out: bool,
                   knowledge: tuple[Path | None, Path | None]) -> None:
    """``simulate``'s options that exclude each other (usage errors, exit 2) and a
    ``--trace`` with no file name or folder (exit 1), before anything is read."""
    if fixed and compare:
        raise _fail("--fixed and --compare exclude each other", 2)
    if fixed and knowledge != (None, None):
        raise _fail("--knowledge and --save-knowledge need the adaptive run (not --fixed)", 2)
    to_stdout = trace is not None and str(trace) == "-"
    if to_stdout and compare:
        raise _fail(
            "--trace - writes one run to stdout and --compare makes two; name a file instead", 2
        )
    if to_stdout and json_out:
        raise _fail("--trace - and --json both write to stdout: choose one", 2)
    if trace is None or to_stdout:
        return
    if not trace.name:  # '' or '.': no file name to write
        raise _fail(f"{trace}: cannot write: is a folder; --trace takes a file name")
    if not trace.parent.is_dir():
        raise _fail(f"{trace}: cannot write: folder {trace.parent} does not exist")


def _simulate(
    arch_path: Path, scenario: str, *, config: str | None, fixed: bool, compare: bool,
    seed: int | None, json_out: bool, trace: Path | None, report: Path | None,
    fig_format: list[Any] | None, dpi: int, yes: bool,
    knowledge: tuple[Path | None, Path | None] = (None, None), online: bool = False,
) -> None:
    """``archself simulate``: the options checked, the runs made and written (guarded),
    the outcome printed."""
    to_stdout = trace is not None and str(trace) == "-"
    _check_options(trace, fixed=fixed, compare=compare, json_out=json_out,
                   knowledge=knowledge)
    trace = None if to_stdout else trace
    fixed_trace = None if trace is None else trace.with_name(f"{trace.stem}.fixed{trace.suffix}")
    fixed_trace = fixed_trace if compare else None
    learned: Any = None

    def outputs() -> None:  # the report folder and the knowledge table, before any run
        nonlocal learned
        if report is not None:
            from archself.io.files import refuse_foreign_folder

            refuse_foreign_folder(report, "summary.json", "--report")
        learned = _knowledge_table(arch_path, knowledge)

    report_files = [("--report", report / n) for n in _RUN_REPORT_FILES] if report else []
    with guard(arch_path, (knowledge[0], "a knowledge table (JSON) or a trace"),
               refuse=[("--trace", trace), ("--trace", fixed_trace), *report_files,
                       ("--save-knowledge", knowledge[1])],
               locks=[trace, fixed_trace, report, knowledge[1]], check=outputs):
        arch = _load(arch_path)
        if online:  # --online: both updates on, the file's other settings
            arch.runtime.online.weights.enabled = arch.runtime.online.bands.enabled = True
        _known_configuration(arch, config, arch_path)
        _check_simulation_size(arch, scenario, 2 if compare else 1, yes)
        show = show_progress(json_out)
        modes = [False, True] if compare else [not fixed]
        results = [_run(arch, scenario, config, seed, adaptive, show,
                        learned if adaptive else None) for adaptive in modes]
        if knowledge[1] is not None:
            learned.save(knowledge[1])
        if trace is not None:
            for r in results:
                r.write_trace(fixed_trace if r.mode == "fixed" and compare else trace)
        if report is not None:
            from archself.reports.run_report import write_run_report

            write_run_report(arch, results, report, formats=_formats(fig_format), dpi=dpi)
            note(f"report: {report / 'index.html'}")
    _print_runs(results, to_stdout, json_out)


def _print_runs(results: list[Any], to_stdout: bool, json_out: bool) -> None:
    """The runs on stdout: the trace (``--trace -``; the summary on stderr), one JSON
    object (``--json``) or the summary table."""
    if to_stdout:
        from archself.io.trace import json_text

        typer.echo(_summary(results), err=True)
        sys.stdout.write(json_text(results[0]))
    elif json_out:
        # one shape whatever the options: an object with the list of runs
        data = {"runs": [r.to_dict() for r in results]}  # io.jsondata.SimulateDoc
        typer.echo(json.dumps(data, indent=2, ensure_ascii=False))
    else:
        typer.echo(_summary(results))


def explain(
    trace: Annotated[
        Path, typer.Argument(help="A trace written by `simulate --trace` (Parquet or JSON); "
                             "'-' reads it from stdin.")
    ],
    json_out: Annotated[
        bool,
        typer.Option(
            "--json",
            help="Print one JSON object {run, cycles, switches, updates, segments} (notable "
            "cycles in full, repeats summarized; docs/json.md).",
        ),
    ] = False,
) -> None:
    """Explain a run's decisions: why (and why not) the architecture switched."""
    from archself.runtime.explanation import explain as render
    from archself.runtime.explanation import explain_data
    from archself.sim.result import read_trace, trace_from_bytes

    with guard((trace, "a trace (Parquet or JSON)"), numeric=False):
        if str(trace) == "-":
            from archself.io.yaml_source import MAX_FILE_BYTES

            res = trace_from_bytes(sys.stdin.buffer.read(MAX_FILE_BYTES), "<stdin>")
        else:
            res = read_trace(trace)
    meta, decisions = res.trace_meta(), res.trace_decisions()
    if json_out:
        from archself.io.jsondata import ExplainDoc, document

        # one shape for logs with and without the source estimate ê (older traces)
        data = document(ExplainDoc, {"run": meta, **explain_data(decisions)}, complete=True)
        typer.echo(json.dumps(data, indent=1))
        return
    typer.echo(
        f"{meta.get('architecture', '?')} · scenario {meta.get('scenario')} · "
        f"seed {meta.get('seed')} · {meta.get('mode')} · "
        f"{meta.get('configuration')} → {meta.get('final_configuration')}"
    )
    typer.echo(render(decisions))
    if meta.get("knowledge"):  # runtime.learning / runtime.online: what the run learned
        from archself.runtime.knowledge import knowledge_summary

        for line in knowledge_summary(meta["knowledge"]):
            typer.echo(line)
