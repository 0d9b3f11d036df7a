"""The checks of ``archself calibrate`` before any run: the file, the chosen scenarios
and configurations, and every point of the ``--envelope``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from archself.calibration.bands import alarm_threshold
from archself.calibration.result import CalibrationError
from archself.campaign.sweep import CampaignError, apply_values, parse_sweep, sweep_points
from archself.check import check, has_errors
from archself.errors import ArchselfError, LoadError, unknown
from archself.model.loader import Loaded, load_text, read_text

__all__ = ["chosen_configurations", "load_checked", "located", "parse_envelope", "prepare"]


def load_checked(path: str | Path, error: type[ArchselfError]) -> tuple[str, Any]:
    """Read, load and check the file; its first error finding raised as ``error``.

    Returns
    -------
    tuple
        ``(text, loaded)``: the file's text and its :class:`~archself.model.loader.Loaded`.
    """

    text = read_text(path)
    loaded = load_text(text, str(path))
    findings = check(loaded)
    if has_errors(findings):
        raise error(str(next(f for f in findings if f.severity == "error")))
    return text, loaded


def located(loaded: Any, path: tuple[str, ...], message: str) -> LoadError:
    """A one-line error at the node of ``path`` in the loaded file."""
    line, col = loaded.source.locate(path)
    return LoadError(message, loaded.file, line, col, ".".join(path))


def chosen_configurations(
    arch: Any, file: str, configurations: Sequence[str] | None, error: type[ArchselfError]
) -> list[str]:
    """The configurations asked for (each once, in order), or all; an unknown one raised."""
    for c in configurations or ():
        if c not in arch.configurations:
            raise error(f"{file}: {unknown('configuration', c, arch.configurations)}")
    return list(dict.fromkeys(configurations or arch.configurations))


def prepare(
    arch_path: str | Path, scenarios: Sequence[str] | None, configurations: Sequence[str] | None
) -> tuple[str, Any, list[str], list[str], float]:
    """Load and check the file; pick the scenarios and configurations to calibrate.

    Returns
    -------
    tuple
        ``(text, loaded, scenarios, configurations, tau)``: the file's text, its
        :class:`~archself.model.loader.Loaded`, the fault-free scenarios and the
        configurations chosen, and the alarm threshold τ of its selector.

    Raises
    ------
    CalibrationError, LoadError
        A file with errors, ``normalization: none``, ``top_k``, no residual, an unknown
        or faulty scenario, an unknown configuration.
    """
    text, loaded = load_checked(arch_path, CalibrationError)
    arch = loaded.arch
    rt = arch.runtime
    if rt.normalization != "nominal":
        raise located(
            loaded,
            ("runtime", "normalization"),
            "calibrate sets the bands of normalization: nominal; with 'none' the bands are "
            "not used",
        )
    try:
        tau = alarm_threshold(rt)
    except ValueError as exc:
        raise located(loaded, ("runtime", "top_k"), str(exc)) from None
    if not any(m.residual is not None for m in arch.modules.values()):
        raise located(loaded, ("modules",), "no module declares a residual: nothing to calibrate")
    if scenarios:
        for s in scenarios:
            if s not in arch.scenarios:
                known = ", ".join(arch.scenarios) or "none"
                raise CalibrationError(f"{loaded.file}: unknown scenario {s!r}; known: {known}")
            if arch.scenarios[s].faults:
                raise located(
                    loaded,
                    ("scenarios", s, "faults"),
                    f"scenario {s!r} has faults; calibration needs fault-free (nominal) scenarios",
                )
        if len(set(scenarios)) != len(scenarios):
            raise CalibrationError("the same --scenario is given twice")
        chosen = list(scenarios)
    else:
        chosen = [n for n, s in arch.scenarios.items() if not s.faults]
        if not chosen:
            raise located(
                loaded,
                ("scenarios",),
                "no fault-free scenario to calibrate on; declare one (no faults)",
            )
    confs = chosen_configurations(arch, loaded.file, configurations, CalibrationError)
    return text, loaded, chosen, confs, tau


def parse_envelope(loaded: Any, specs: Sequence[str]) -> tuple[Any, ...]:
    """Parse ``--envelope`` specs and check every point gives a valid file."""
    if not specs:
        return ()

    try:
        sweeps = tuple(parse_sweep(s) for s in specs)
        for point in sweep_points(sweeps):
            swept = apply_values(loaded.data, sweeps, point, loaded.file, loaded.source)
            bad = [f for f in check(Loaded(swept, loaded.source, loaded.data))
                   if f.severity == "error"]
            if bad:
                setting = ", ".join(f"{s.path}={v:g}" for s, v in zip(sweeps, point, strict=True))
                raise CalibrationError(f"--envelope {setting}: {bad[0]}")
    except CampaignError as exc:
        raise CalibrationError(f"--envelope: {exc}") from None
    return sweeps
