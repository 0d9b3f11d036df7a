"""Commands over many runs: campaign and campaign-report."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from archself.cli.base import (
    _RUN_REPORT_FILES,
    AddressOption,
    DpiOption,
    Executor,
    ExecutorOption,
    FormatOption,
    Mode,
    PastCapOption,
    RootSeedOption,
    RunProgress,
    TraceFormat,
    WorkersOption,
    _die,
    _err,
    _fail,
    _formats,
    _inputs,
    _numeric,
    note,
    show_progress,
)
from archself.errors import ArchselfError


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
    mode: Annotated[
        Mode, typer.Option("--mode", help="Fixed and adaptive runs, or one of them.")
    ] = Mode.both,
    executor: ExecutorOption = Executor.local,
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
    trace_format: Annotated[
        TraceFormat,
        typer.Option("--trace-format", help="Format of the --traces files (parquet: ~6× "
                     "smaller, pd.read_parquet; both read by explain and report --trace)."),
    ] = TraceFormat.json,
    root_seed: RootSeedOption = 0,
    json_out: Annotated[
        bool,
        typer.Option("--json", help="Print the outcome as one JSON object {architecture, "
                     "file, seeds, root_seed, executor, elapsed_s, archself_version, out, "
                     "planned, skipped, ran, failed, rows, workers, errors} (docs/json.md)."),
    ] = False,
    yes: PastCapOption = False,
    lanes: Annotated[
        int | None,
        typer.Option("--lanes", min=1, help="Runs stepped together per batch (1: one "
                     "by one; default: shared over the workers within memory, at most 256, "
                     "where every module type of the file is batched, else 1). "
                     "Same results."),
    ] = None,
) -> None:
    """Run a Monte Carlo campaign: scenarios x sweep values x seeds, fixed and adaptive.

    One Parquet row per run, written as runs finish; Ctrl-C keeps the finished
    runs (exit 130; SIGTERM: 143) and --resume continues. The same command gives
    the same table whatever the number of workers. A campaign larger than the cap
    (runs, steps) needs --yes; --out is never the architecture file.
    """
    _campaign(
        arch_path, scenarios, seeds, sweep=sweep, mode=mode, executor=executor, address=address,
        workers=workers, out=out, resume=resume, force=force, traces=traces,
        trace_format=trace_format, root_seed=root_seed, json_out=json_out, yes=yes, lanes=lanes,
    )


def _campaign(
    arch_path: Path, scenarios: list[str], seeds: int, *, sweep: list[str] | None, mode: Mode,
    executor: Executor, address: str | None, workers: int | None, out: Path, resume: bool,
    force: bool, traces: Path | None, trace_format: TraceFormat, root_seed: int,
    json_out: bool, yes: bool, lanes: int | None,
) -> None:
    """``archself campaign``: the options guarded, the campaign planned and run, the outcome
    printed."""
    from archself.campaign.driver import plan_campaign, run_campaign
    from archself.campaign.sweep import parse_sweep
    from archself.io.files import protect, refuse_same_file

    if resume and force:
        raise _fail("--resume and --force exclude each other", 2)

    try:
        _inputs(arch_path)
        refuse_same_file([arch_path], out, "--out")
        sweeps = [parse_sweep(s) for s in sweep or []]
        with protect([arch_path], [out, traces]), _numeric(arch_path):
            jobs, meta = plan_campaign(
                arch_path,
                scenarios,
                seeds,
                sweeps,
                modes=("fixed", "adaptive") if mode is Mode.both else (mode.value,),
                root_seed=root_seed,
                traces=traces,
                trace_format=trace_format.value,
                yes=yes,
            )
            show = show_progress(json_out)
            per = int(meta.get("steps", 0)) // max(len(jobs), 1)
            bar = RunProgress(f"{{total:,}} runs × {per:,} steps")
            try:
                outcome = run_campaign(
                    jobs,
                    meta,
                    out,
                    executor=executor.value,
                    workers=workers,
                    address=address,
                    resume=resume,
                    force=force,
                    progress=bar.update if show else None,
                    notice=lambda msg: _err(f"warning: {msg}"),
                    lanes=lanes,
                )
            finally:
                bar.close()
    except ArchselfError as exc:
        raise _die(exc) from None
    if json_out:
        from archself.io.jsondata import CampaignDoc

        doc = CampaignDoc(**{**vars(outcome), "out": str(outcome.out),
                             "elapsed_s": round(outcome.elapsed_s, 3)},
                          architecture=meta["architecture"], file=meta["file"], seeds=seeds,
                          root_seed=root_seed)
        typer.echo(json.dumps(doc.model_dump(mode="json"), indent=2, ensure_ascii=False))
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
    fig_format: FormatOption = None,
    dpi: DpiOption = 150,
    json_out: Annotated[
        bool,
        typer.Option("--json", help="Print the summary as one JSON object (DIR/summary.json; "
                     "docs/json.md)."),
    ] = False,
) -> None:
    """Summarize a campaign: correct switches, detection delay, false switches, errors, τ sweep.

    Writes DIR/index.html (figures beside it: SVG unless --format says otherwise) and
    DIR/summary.json.
    """
    from archself.campaign.aggregate import parse_expect
    from archself.campaign.report import campaign_report, summary_text
    from archself.io.files import protect, refuse_same_file

    try:
        _inputs(results, what="a results file (Parquet)")
        for name in _RUN_REPORT_FILES:
            refuse_same_file([results], out_dir / name, "-o")
        with protect([results], [out_dir]), _numeric(results):
            summary = campaign_report(
                results, out_dir, expect=parse_expect(expect or []), tau_path=tau,
                formats=_formats(fig_format, "svg"), dpi=dpi,
            )
    except ArchselfError as exc:
        raise _die(exc) from None
    if json_out:

        from archself.io.jsondata import CampaignReportDoc, document

        typer.echo(json.dumps(document(CampaignReportDoc, summary, complete=True), indent=2,
                              ensure_ascii=False))
    else:
        typer.echo(summary_text(summary))
        note(f"report: {out_dir / 'index.html'}")
