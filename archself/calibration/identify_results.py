"""What ``archself identify`` found: per edge declared vs fitted W, the experiments, the error.

:class:`Identification` is the result of :func:`archself.calibration.identify.identify`
(rows :class:`EdgeRow`, :class:`Experiment`, the fits per target) with its JSON form
and the weights pooled over configurations; :func:`summary_text` (the terminal table:
per configuration the identifiable edges, the fit per target, the modules not
perturbed) and :func:`markdown_table` (the same as Markdown, with the experiments)
show it; :class:`IdentifyError` is the one-line refusal of the command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import Field

from archself.errors import ArchselfError
from archself.io.jsondata import JobDoc, OutDoc, document
from archself.runtime.identify_fit import TargetFit

__all__ = ["FLAG_SE", "EdgeRow", "Experiment", "Identification", "IdentificationDoc",
           "IdentifyError", "markdown_table", "summary_text"]

#: Flag a fitted weight as different from the declared one beyond this many SE.
FLAG_SE = 2.0


class IdentifyError(ArchselfError):
    """The identification cannot be done as asked (one-line message, exit 1)."""


@dataclass
class EdgeRow:
    """One edge pair (source → target) of one configuration: declared vs fitted."""

    configuration: str
    source: str
    target: str
    carries: list[str]
    declared: float
    effective: float
    fitted: float
    se: float
    identifiable: bool
    reason: str

    @property
    def differs(self) -> bool | None:
        """|fitted − effective| > 2 SE (None when not identifiable or without an SE)."""
        if not self.identifiable or not math.isfinite(self.se):
            return None
        return abs(self.fitted - self.effective) > max(FLAG_SE * self.se, 1e-9)


@dataclass
class Experiment:
    """One perturbed module of one configuration and what it excited."""

    configuration: str
    module: str
    kind: str
    magnitude: float
    seeds: int
    own_delta: float  # mean Δr of the module itself (NaN when hidden)
    max_delta: float  # largest mean |Δr| over the observed modules


@dataclass
class Identification:
    """What :func:`identify` found."""

    architecture: str
    file: str
    scenario: str
    configurations: list[str]
    seeds: int
    root_seed: int
    w_scale: float
    settle_s: float
    rows: list[EdgeRow]
    fits: dict[str, dict[str, TargetFit]]
    experiments: list[Experiment]
    skipped: dict[str, list[str]]  # configuration -> active modules not perturbed (why)
    failed: list[str]
    runs: int
    elapsed_s: float
    executor: str
    text: str = ""

    def fitted_weights(self) -> dict[tuple[str, str], tuple[float, float]]:
        """(source, target) -> (weight, SE) pooled over configurations.

        Inverse-variance weighted where every estimate has an SE > 0, the mean
        otherwise.
        """
        by: dict[tuple[str, str], list[EdgeRow]] = {}
        for r in self.rows:
            if r.identifiable:
                by.setdefault((r.source, r.target), []).append(r)
        out: dict[tuple[str, str], tuple[float, float]] = {}
        for key, rows in by.items():
            se = np.array([r.se for r in rows])
            w = np.array([r.fitted for r in rows])
            if np.all(np.isfinite(se)) and np.all(se > 0):
                iv = 1.0 / se**2
                out[key] = (float(iv @ w / iv.sum()), float(1.0 / math.sqrt(iv.sum())))
            else:
                out[key] = (float(w.mean()), float(se[0]) if len(rows) == 1 else math.nan)
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON data (``--json``): an :class:`IdentificationDoc` (NaN: null)."""
        return document(
            IdentificationDoc, self, complete=True, elapsed_s=round(self.elapsed_s, 3),
            edges=[{f: getattr(r, f) for f in EdgeDoc.model_fields} for r in self.rows],
            targets={c: {t: {f: getattr(fit, f) for f in TargetDoc.model_fields}
                         for t, fit in fits.items()} for c, fits in self.fits.items()},
            not_perturbed=self.skipped)


# ------------------------------------------------------------------ the tables
def _f(v: float, digits: int = 3) -> str:
    return "—" if not (isinstance(v, float | int) and math.isfinite(v)) else f"{v:.{digits}f}"


def _cells(r: EdgeRow) -> tuple[str, str, str]:
    """Fitted W, SE and flag of an edge as the tables show them."""
    if not r.identifiable:
        return "—", "—", f"not identifiable: {r.reason}"
    d = r.differs
    return f"{r.fitted:.3f}", _f(r.se), "" if d is None else ("DIFFERS" if d else "ok")


def summary_text(ident: Identification, *, all_edges: bool = False) -> str:
    """The terminal table: identifiable edges per configuration, then the rest counted."""
    lines = [
        f"identify {ident.file} · scenario {ident.scenario} · {ident.seeds} seed"
        f"{'s' * (ident.seeds != 1)} · {ident.runs} runs in {ident.elapsed_s:.1f} s "
        f"({ident.executor}) · averages after {ident.settle_s:g} s"
    ]
    if ident.w_scale != 1.0:
        lines.append(f"declared weights × {ident.w_scale:.4g} (the loop's ρ(W) scale) = effective")
    for c in ident.configurations:
        rows = [r for r in ident.rows if r.configuration == c]
        shown = [r for r in rows if r.identifiable or all_edges]
        lines += ["", f"configuration {c}"]
        width = max([len(f"{r.source} -> {r.target}") for r in shown] + [4])
        lines.append(f"  {'edge':<{width}}  {'declared':>8}  {'fitted':>8}  {'SE':>7}  flag")
        for r in shown:
            fitted, se, flag = _cells(r)
            lines.append(f"  {f'{r.source} -> {r.target}':<{width}}  {r.effective:>8.3f}  "
                         f"{fitted:>8}  {se:>7}  {flag}")
        hidden = len(rows) - len(shown)
        if hidden:
            lines.append(f"  ({hidden} more edge{'s' * (hidden != 1)} not identifiable; --all)")
        fits = ident.fits.get(c, {})
        if fits:
            lines.append(
                "  fit per target: "
                + ", ".join(f"{t} R² {_f(f.r2, 2)} ({f.rows} eq.)" for t, f in fits.items())
            )
        skipped = ident.skipped.get(c) or []
        if skipped:
            lines.append(f"  not perturbed: {', '.join(skipped)}")
    if ident.failed:
        lines += ["", f"{len(ident.failed)} failed run(s); first: {ident.failed[0]}"]
    return "\n".join(lines) + "\n"


def markdown_table(ident: Identification) -> str:
    """The report as Markdown: the edge table, the fit per target, the experiments."""
    out = [
        f"# Identified influence weights of {ident.architecture}",
        "",
        f"File `{ident.file}`, scenario `{ident.scenario}`, {ident.seeds} seeds, "
        f"{ident.runs} runs in {ident.elapsed_s:.1f} s ({ident.executor}); averages after "
        f"{ident.settle_s:g} s. Flag: |fitted − declared| > {FLAG_SE:g} SE.",
        "",
        "| configuration | edge | declared W | fitted W | SE | flag |",
        "| --- | --- | ---: | ---: | ---: | --- |",
    ]
    for r in ident.rows:
        fitted, se, flag = _cells(r)
        out.append(f"| {r.configuration} | {r.source} → {r.target} | {r.effective:.3f} | "
                   f"{fitted} | {se} | {flag} |")
    out += [
        "",
        "| configuration | target | equations | largest Δr | R² | RMS of the fit |",
        "| --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for c, fits in ident.fits.items():
        for t, f in fits.items():
            out.append(
                f"| {c} | {t} | {f.rows} | {_f(f.moved, 4)} | {_f(f.r2, 2)} | {_f(f.rms, 4)} |"
            )
    out += [
        "",
        "| configuration | perturbed | fault | own Δr | largest Δr |",
        "| --- | --- | --- | ---: | ---: |",
    ]
    for e in ident.experiments:
        out.append(
            f"| {e.configuration} | {e.module} | {e.kind} {e.magnitude:g} | {_f(e.own_delta)} | "
            f"{_f(e.max_delta)} |"
        )
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------ the JSON document
Number = int | float  # as given: an int stays an int in the JSON


class EdgeDoc(OutDoc):
    """One edge of one configuration: declared, effective and fitted weight."""

    configuration: str
    source: str
    target: str
    carries: list[str]
    declared: Number
    effective: Number
    fitted: float | None = Field(description="null when the edge is not identifiable")
    se: float | None
    identifiable: bool
    reason: str
    differs: bool | None = Field(description="|fitted − effective| > 2 SE; null without one")


class TargetDoc(OutDoc):
    """The fit of one target module's residual."""

    rows: int
    r2: float | None
    rms: float | None
    moved: float | None = Field(description="how far the residual moved")


class ExperimentDoc(OutDoc):
    """One perturbed module and what it excited."""

    configuration: str
    module: str
    kind: str
    magnitude: Number
    seeds: int
    own_delta: float | None
    max_delta: float | None


class IdentificationDoc(JobDoc):
    """``archself identify --json``."""

    scenario: str
    configurations: list[str]
    runs: int
    failed: list[str]
    w_scale: Number
    settle_s: Number
    edges: list[EdgeDoc]
    targets: dict[str, dict[str, TargetDoc]]
    experiments: list[ExperimentDoc]
    not_perturbed: dict[str, list[str]] = Field(
        description="per configuration, the modules not perturbed and why")
