"""``archself report``: the architecture's report, or a run report rebuilt from traces."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from archself.cli.base import (
    _RUN_REPORT_FILES,
    DpiOption,
    FormatOption,
    _fail,
    _formats,
    _load,
    guard,
    note,  # --quiet/--verbose
)


def report(
    output: Annotated[
        Path,
        typer.Option(
            "-o", "--output", metavar="DIR", help="Folder to write the report into (created)."
        ),
    ],
    arch_path: Annotated[
        Path | None,
        typer.Argument(metavar="[ARCH]",
                       help="Architecture file (optional with --trace: the trace holds it)."),
    ] = None,
    trace: Annotated[
        list[Path] | None,
        typer.Option(
            "--trace", metavar="TRACE",
            help="Rebuild the run report of a saved trace (Parquet or JSON) instead; twice "
            "for a fixed and an adaptive run of the same scenario and seed.",
        ),
    ] = None,
    fig_format: FormatOption = None,
    dpi: DpiOption = 150,
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

    With --trace TRACE it is the run report of `simulate --report` instead, rebuilt from
    the saved trace(s) without running anything (ARCH is then optional); a DIR that holds
    other files and no earlier run report needs --force.
    """
    if trace:
        _report_from_traces(arch_path, trace, output, _formats(fig_format), dpi, force)
        return
    if arch_path is None:
        raise _fail("missing argument ARCH (or --trace TRACE for a run report)", 2)
    from archself.io.files import refuse_input_inside

    with guard(arch_path, locks=[output],
               check=lambda: refuse_input_inside([arch_path], output, "-o")):
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
            note(f"writing {files:,} files into {output}")
        rep = write_architecture_report(arch, output, dot=not no_render, force=force)
    if rep.note and not no_render:
        note(f"note: {rep.note}")
    typer.echo(str(rep.index))


def _report_from_traces(
    arch_path: Path | None, traces: list[Path], output: Path, formats: tuple[str, ...], dpi: int,
    force: bool = False,
) -> None:
    """``report --trace``: the run report of saved traces (one run, or fixed + adaptive)."""
    from archself.io.files import refuse_foreign_folder
    from archself.sim.result import read_trace

    if len(traces) > 2:
        raise _fail("--trace takes one run, or two (fixed and adaptive)", 2)
    with guard(*((t, "a trace") for t in traces), arch_path, locks=[output],
               refuse=[("-o", output / name) for name in _RUN_REPORT_FILES],
               check=None if force else lambda: refuse_foreign_folder(output, "summary.json",
                                                                      "-o")):
        results = [read_trace(t) for t in traces]
        for t, r in zip(traces, results, strict=True):
            if not {"t", "J"} <= set(r.series):
                raise _fail(f"{t}: error: the trace has no series t and J (a live run's "
                            "decision log?); a run report needs a trace of simulate --trace")
            if arch_path is None and not isinstance(r.meta.get("report"), dict):
                raise _fail(f"{t}: error: the trace does not hold the run report's "
                            "settings (written by an older archself); pass the "
                            "architecture file: archself report ARCH --trace TRACE -o DIR")
        if len(results) == 2:
            a, b = results
            if {a.mode, b.mode} != {"fixed", "adaptive"} or (a.scenario, a.seed) != (
                    b.scenario, b.seed):
                raise _fail(
                    f"{traces[1]}: error: two traces must be a fixed and an adaptive run "
                    f"of one scenario and seed; got {a.mode} {a.scenario} seed {a.seed} "
                    f"and {b.mode} {b.scenario} seed {b.seed}")
            results.sort(key=lambda r: r.mode != "fixed")  # fixed first, as --compare
        arch = None
        if arch_path is not None:
            arch = _load(arch_path)
            if results[0].scenario not in arch.scenarios:
                raise _fail(f"{arch_path}: error: has no scenario "
                            f"'{results[0].scenario}' of the trace")
        from archself.reports.run_report import write_run_report

        write_run_report(arch, results, output, formats=formats, dpi=dpi)
    typer.echo(str(output / "index.html"))
