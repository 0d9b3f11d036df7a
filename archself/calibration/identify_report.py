"""The identification as text: the terminal table and the Markdown report.

:func:`summary_text` gives per configuration the identifiable edges (declared,
fitted, SE, flag), the fit per target and the modules not perturbed;
:func:`markdown_table` the same as Markdown tables with the experiments.
"""

from __future__ import annotations

import math

from archself.calibration.identify_results import FLAG_SE, EdgeRow, Identification

__all__ = ["markdown_table", "summary_text"]


def _f(v: float, digits: int = 3) -> str:
    return "—" if not (isinstance(v, float | int) and math.isfinite(v)) else f"{v:.{digits}f}"


def _flag(r: EdgeRow) -> str:
    d = r.differs
    return "" if d is None else ("DIFFERS" if d else "ok")


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
            edge = f"{r.source} -> {r.target}"
            if r.identifiable:
                lines.append(
                    f"  {edge:<{width}}  {r.effective:>8.3f}  {r.fitted:>8.3f}  "
                    f"{_f(r.se):>7}  {_flag(r)}"
                )
            else:
                lines.append(
                    f"  {edge:<{width}}  {r.effective:>8.3f}  {'—':>8}  {'—':>7}  "
                    f"not identifiable: {r.reason}"
                )
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
        if r.identifiable:
            out.append(
                f"| {r.configuration} | {r.source} → {r.target} | {r.effective:.3f} | "
                f"{r.fitted:.3f} | {_f(r.se)} | {_flag(r)} |"
            )
        else:
            out.append(
                f"| {r.configuration} | {r.source} → {r.target} | {r.effective:.3f} | — | — | "
                f"not identifiable: {r.reason} |"
            )
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
