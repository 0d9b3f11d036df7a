"""Commands that fit the file to nominal runs: calibrate (residual bands), identify (W)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated

import typer

from archself.cli.base import (
    AddressOption,
    Executor,
    ExecutorOption,
    IdentifyExecutor,
    RootSeedOption,
    WorkersOption,
    _emit,
    _fail,
    guard,
    note,
    show_progress,
)

ConfigurationsOption = Annotated[
    list[str] | None,
    typer.Option("--configuration", "-c", help="Configuration (repeatable; default: all)."),
]


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
    configurations: ConfigurationsOption = None,
    verify_seeds: Annotated[
        int, typer.Option("--verify-seeds", min=0, help="Fresh seeds to measure the new rate on.")
    ] = 0,
    executor: ExecutorOption = Executor.local,
    address: AddressOption = None,
    workers: WorkersOption = None,
    root_seed: RootSeedOption = 0,
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
        bool,
        typer.Option("--json", help="Print the bands and rates as one JSON object "
                     "(docs/json.md)."),
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
    weight: Annotated[
        list[str] | None,
        typer.Option(
            "--weight",
            metavar="MODULE=W",
            help="A module's weight in the split of the false-alarm budget between the "
            "channels of a configuration (default 1 each; repeatable).",
        ),
    ] = None,
) -> None:
    """Derive residual bands (residual.nominal) for a target false-switch rate from nominal runs.

    Runs every fault-free scenario fixed in every configuration for --seeds seeds
    (local pool or Dask), records the Monitor's filtered residuals and chooses the
    bands so that at most P of the nominal runs raise a candidate (Gumbel tail of
    the per-run maxima). docs/calibrate.md.
    """
    _calibrate(
        arch_path, false_switch=false_switch, seeds=seeds, scenarios=scenarios,
        configurations=configurations, verify_seeds=verify_seeds, executor=executor,
        address=address, workers=workers, root_seed=root_seed, output=output, in_place=in_place,
        force=force, report_dir=report_dir, json_out=json_out, save_runs=save_runs,
        from_runs=from_runs, envelope=envelope, weight=weight,
    )


def _calibrate(
    arch_path: Path, *, false_switch: float, seeds: int, scenarios: list[str] | None,
    configurations: list[str] | None, verify_seeds: int, executor: Executor,
    address: str | None, workers: int | None, root_seed: int, output: Path | None,
    in_place: bool, force: bool, report_dir: Path | None, json_out: bool,
    save_runs: Path | None, from_runs: Path | None, envelope: list[str] | None,
    weight: list[str] | None,
) -> None:
    """``archself calibrate``: the options guarded, the bands derived, written and printed."""
    from archself.calibration.driver import calibrate as run_calibration
    from archself.calibration.edit import check_output
    from archself.campaign.driver import RunProgress

    if not 0.0 < false_switch < 1.0:
        raise _fail(f"--false-switch {false_switch:g}: expected a rate between 0 and 1", 2)
    if in_place and output is not None:
        raise _fail("--in-place and --output exclude each other", 2)
    weights: dict[str, float] = {}
    for spec in weight or ():
        name, _, value = spec.partition("=")
        try:
            weights[name.strip()] = float(value)
        except ValueError:
            raise _fail(f"--weight {spec}: expected MODULE=W, e.g. odometry=4", 2) from None
    if in_place and not force:
        raise _fail("--in-place overwrites ARCH: pass --force as well", 2)
    target = arch_path if in_place else output

    def outputs() -> None:
        if target is not None:
            check_output(arch_path, target, in_place=in_place, force=force)
        if save_runs is not None:
            check_output(arch_path, save_runs, in_place=False, force=force)
        if report_dir is not None:
            from archself.io.files import refuse_foreign_folder

            refuse_foreign_folder(report_dir, "calibration.json", "--report")

    with guard(None if in_place else arch_path, check=outputs,  # in place: written
               locks=[target, save_runs, report_dir], numeric=False):
        show = show_progress(json_out)
        bar = RunProgress("{total:,} runs")
        try:
            cal = run_calibration(
                arch_path, false_switch=false_switch, seeds=seeds, scenarios=scenarios,
                configurations=configurations, root_seed=root_seed,
                executor=executor.value, workers=workers, address=address,
                verify_seeds=verify_seeds, progress=bar.update if show else None,
                save_runs=save_runs, from_runs=from_runs, envelope=envelope or (),
                weights=weights,
            )
        finally:
            bar.close()
        if target is not None:
            from archself.io.files import write_text

            write_text(target, cal.text)
        if report_dir is not None:
            from archself.calibration.report import write_report

            index = write_report(cal, report_dir)
    if json_out:
        typer.echo(json.dumps(cal.to_dict(), indent=2, ensure_ascii=False))
    else:
        from archself.calibration.report import summary_text

        typer.echo(summary_text(cal))
    if target is not None:
        note(f"wrote {target}")
    if report_dir is not None:
        note(f"report: {index}")


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


def identify(
    arch_path: Annotated[Path, typer.Argument(metavar="ARCH", help="Architecture file.")],
    configurations: ConfigurationsOption = None,
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
        IdentifyExecutor,
        typer.Option("--executor", help="local (process pool), dask or inline (this process)."),
    ] = IdentifyExecutor.local,
    address: AddressOption = None,
    workers: WorkersOption = None,
    root_seed: RootSeedOption = 0,
    json_out: Annotated[
        bool, typer.Option("--json", help="Print the fitted and declared W as one JSON object "
                     "(docs/json.md).")
    ] = False,
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
    _identify(
        arch_path, configurations=configurations, scenario=scenario, seeds=seeds, kind=kind,
        magnitude=magnitude, perturb=perturb, settle=settle, min_excitation=min_excitation,
        executor=executor, address=address, workers=workers, root_seed=root_seed,
        json_out=json_out, all_edges=all_edges, output=output, write_back=write_back, force=force,
    )


def _identify(
    arch_path: Path, *, configurations: list[str] | None, scenario: str | None, seeds: int,
    kind: str, magnitude: float, perturb: list[str] | None, settle: float | None,
    min_excitation: float, executor: IdentifyExecutor, address: str | None,
    workers: int | None, root_seed: int, json_out: bool, all_edges: bool, output: Path | None,
    write_back: Path | None, force: bool,
) -> None:
    """``archself identify``: the options guarded, W fitted, the report and copy written."""
    from archself.calibration.edit import check_output
    from archself.calibration.identify import identify as run_identify
    from archself.calibration.identify import written_copy
    from archself.calibration.identify_results import markdown_table, summary_text

    if not math.isfinite(magnitude):
        raise _fail(f"--magnitude {magnitude}: expected a finite number", 2)
    overrides = _perturbations(perturb)
    with guard(arch_path, refuse=[("-o", output)], locks=[output, write_back],
               check=None if write_back is None else lambda: check_output(
                   arch_path, write_back, in_place=False, force=force)):
        ident = run_identify(
            arch_path, configurations=configurations, scenario=scenario, seeds=seeds,
            kind=kind, magnitude=magnitude, perturb=overrides, settle_s=settle,
            min_excitation=min_excitation, root_seed=root_seed, executor=executor.value,
            workers=workers, address=address,
        )
        copy = written_copy(ident) if write_back is not None else None
        if json_out:
            typer.echo(json.dumps(ident.to_dict(), indent=2, ensure_ascii=False))
        elif output is None or str(output) != "-":
            typer.echo(summary_text(ident, all_edges=all_edges), nl=False)
        if output is not None:
            _emit(markdown_table(ident), output, f"wrote {output}")
        if write_back is not None and copy is not None:
            from archself.io.files import write_text

            write_text(write_back, copy)
            note(f"wrote {write_back}")
