"""``archself calibrate --report DIR``: the residual distributions and the chosen bands.

Writes ``DIR/index.html`` and ``DIR/calibration.md`` (rendered from
``templates/calibration.html.j2`` and ``templates/calibration.md.j2`` in the
sandboxed, autoescaping environment of :mod:`archself.reports.render`),
``DIR/calibration.json`` (:meth:`Calibration.to_dict`) and, when matplotlib is
installed, one SVG histogram per module and the tail figure (imported lazily,
object-oriented API, deterministic SVG).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from archself.calibration.edit import same_file
from archself.calibration.result import Calibration, CellResult
from archself.errors import OutputError
from archself.io.files import write_text
from archself.reports.render import render, unique_slugs

__all__ = ["report_model", "summary_text", "write_report"]

QUANTILES = (0.5, 0.9, 0.99)


def _q(v: np.ndarray, q: float) -> float:
    return float(np.quantile(v, q)) if v.size else math.nan


def _fmt(v: float | None, digits: int = 3) -> str:
    if v is None or v != v:
        return "–"
    if math.isinf(v):
        return "∞"
    if v == 0:
        return "0"
    return f"{v:.{digits}g}"


def _pct(v: float | None) -> str:
    if v is None or v != v:
        return "–"
    if 0 < v < 1e-4:
        return f"{100 * v:.1e} %"
    return f"{100 * v:.2g} %"


def report_model(cal: Calibration) -> dict[str, Any]:
    """Everything the templates show, as plain strings and numbers."""
    rates = cal.rates()
    return {
        "architecture": cal.architecture,
        "file": Path(cal.file).name,
        "tau": _fmt(cal.tau),
        "p": _pct(cal.false_switch),
        "p_value": cal.false_switch,
        "weights": "".join(
            f", weight {b.name} {b.weight:g}" for b in cal.modules.values() if b.weight != 1
        ),
        "seeds": cal.seeds,
        "root_seed": cal.root_seed,
        "runs": cal.runs,
        "scenarios": ", ".join(cal.scenarios),
        "configurations": ", ".join(cal.configurations),
        "scale": _fmt(cal.scale, 4),
        "elapsed": f"{cal.elapsed_s:.1f} s",
        "executor": cal.executor,
        "verify_seeds": cal.verify_seeds,
        "rates": {k: _pct(v) for k, v in rates.items()},
        "bands": _band_rows(cal),
        "dists": _distributions(cal),
        "cells": [_cell_row(c) for c in cal.cells],
        "tail_figure": None,
    }


def _band_rows(cal: Calibration) -> list[dict[str, Any]]:
    """A row per module: its old and new band, their ratio, the alarm level."""
    bands = []
    for m, b in cal.modules.items():
        alarm = b.new * (1.0 + cal.tau / b.sensitivity) if b.sensitivity > 0 else math.nan
        bands.append(
            {
                "module": m,
                "signal": b.signal,
                "configurations": ", ".join(b.configurations) or "–",
                "old": _fmt(b.old),
                "new": _fmt(b.new),
                "ratio": _fmt(b.new / b.old, 2) if b.old > 0 else "–",
                "alarm": _fmt(alarm),
                "calibrated": b.calibrated,
                "note": b.note,
            }
        )
    return bands


def _distributions(cal: Calibration) -> list[dict[str, Any]]:
    """Per module and cell: quantiles of its filtered residual per cycle and per run."""

    slugs = unique_slugs(list(cal.modules))
    dists = []
    for m in cal.modules:
        rows = []
        for c in cal.data:
            if m not in c.modules:
                continue
            cyc = c.cycles(m)
            rmax = c.run_max(m)
            rows.append(
                {
                    "cell": f"{c.scenario} / {c.configuration}",
                    "runs": c.runs,
                    "cycles": int(cyc.size),
                    "cycle_q": [_fmt(_q(cyc, q)) for q in QUANTILES],
                    "cycle_max": _fmt(float(cyc.max()) if cyc.size else math.nan),
                    "run_q": [_fmt(_q(rmax, q)) for q in (0.5, 0.9)],
                    "run_max": _fmt(float(rmax.max()) if rmax.size else math.nan),
                }
            )
        dists.append({"module": m, "slug": slugs[m], "rows": rows, "figure": None})
    return dists


def _cell_row(c: CellResult) -> dict[str, Any]:
    """A (scenario, configuration) cell: its runs, the tail fitted, the rates."""
    return {
        "scenario": c.scenario,
        "configuration": c.configuration,
        "runs": c.runs,
        "failed": len(c.failed),
        "forced": c.forced,
        "gumbel": (
            f"loc {_fmt(c.fit_new.all.loc)}, scale {_fmt(c.fit_new.all.scale)}"
            if c.fit_new.all.loc is not None
            else "no fit"
        ),
        "tail": (
            f"top {_pct(c.fit_new.all.tail_share)} over {_fmt(c.fit_new.all.tail_u)}, "
            f"β {_fmt(c.fit_new.all.tail_beta)}"
            if c.fit_new.all.tail_u is not None
            else "no fit"
        ),
        "old_predicted": _pct(c.old_predicted),
        "old_empirical": _pct(c.old_empirical),
        "new_predicted": _pct(c.new_predicted),
        "new_empirical": _pct(c.new_empirical),
        "verify_runs": c.verify_runs,
        "verify_new": _pct(c.verify_new) if c.verify_runs else "–",
        "verify_old": _pct(c.verify_old) if c.verify_runs else "–",
        "scale_needed": _fmt(c.scale_needed, 4),
    }


def _save(fig: Any, path: Path) -> None:
    from archself.reports.figures import write_figure

    write_figure(path.parent, path.stem, fig, ["svg"], 150)


def _fig_module(cal: Calibration, module: str, path: Path) -> bool:
    from archself.sim.plot import paper_figure

    b = cal.modules[module]
    fig = paper_figure(6.4, 3.2)
    ax = fig.add_subplot()
    drawn = False
    for c in cal.data:
        if module not in c.modules:
            continue
        cyc = c.cycles(module)
        if not cyc.size or not np.any(cyc > 0):
            continue
        ax.hist(cyc, bins=60, histtype="step", density=True, label=f"{c.configuration}")
        drawn = True
    if not drawn:
        return False
    ax.axvline(b.old, color="#999999", linestyle="--", label=f"old band {_fmt(b.old)}")
    ax.axvline(b.new, color="#1f77b4", linestyle="-", label=f"new band {_fmt(b.new)}")
    if b.sensitivity > 0:
        level = b.new * (1 + cal.tau / b.sensitivity)
        ax.axvline(level, color="#c0392b", linestyle=":", label=f"alone at τ: {_fmt(level)}")
    ax.set_yscale("log")
    ax.set_xlabel(f"|filtered {b.signal}| per cycle after the warm-up")
    ax.set_ylabel("density")
    ax.set_title(f"{module}: nominal residual signal")
    ax.legend(frameon=False, fontsize="small")
    _save(fig, path)
    return True


def _fig_tail(cal: Calibration, path: Path) -> bool:
    from scipy.stats import gumbel_r

    from archself.sim.plot import paper_figure

    fig = paper_figure(6.4, 3.6)
    ax = fig.add_subplot()
    drawn = False
    for c in cal.cells:
        fit = c.fit_new.all
        v = np.sort(fit.values[np.isfinite(fit.values)])
        if not v.size:
            continue
        surv = 1.0 - np.arange(v.size) / v.size  # share of runs ≥ v
        label = f"{c.scenario}/{c.configuration}"
        color = ax.step(v, surv, where="post", label=label)[0].get_color()
        if fit.loc is not None and fit.scale is not None:
            grid = np.linspace(float(v.min()), max(1.2, float(v.max()) * 1.2), 200)
            body = 1 - fit.f0 - fit.finf
            ax.plot(grid, fit.finf + body * gumbel_r.sf(grid, fit.loc, fit.scale), color=color,
                    linestyle=":", linewidth=1)
        if fit.tail_u is not None:
            grid = np.linspace(fit.tail_u, max(1.2, float(v.max()) * 1.2), 100)
            ax.plot(grid, [c.fit_new.predicted(float(g)) for g in grid], color=color,
                    linestyle="--", linewidth=1)
        drawn = True
    if not drawn:
        return False
    ax.axvline(1.0, color="#000000", linewidth=1, label="the new bands (s = 1)")
    ax.axhline(cal.false_switch, color="#c0392b", linestyle="--", label=f"p = {cal.false_switch:g}")
    ax.set_yscale("log")
    ax.set_ylim(bottom=min(cal.false_switch / 10, 0.5 / max(c.runs for c in cal.cells)))
    ax.set_xlabel("critical scale S of a run (false alarm when the bands are ≤ S × new)")
    ax.set_ylabel("share of runs ≥ S")
    ax.set_title("S per run: data, Gumbel (dotted), prediction (dashed)")
    ax.legend(frameon=False, fontsize="small")
    _save(fig, path)
    return True


def write_report(cal: Calibration, out_dir: str | Path) -> Path:
    """Write the report into ``out_dir``; the path of its ``index.html``.

    Raises
    ------
    OutputError
        If the folder or a file cannot be written.
    """
    from archself.reports.architecture import new_folder

    out = Path(out_dir)
    for name in ("index.html", "calibration.md", "calibration.json"):
        if same_file(cal.file, out / name):
            raise OutputError(f"{out / name}: error: is the input file; choose another --report")
    with new_folder(out):
        _write(cal, out)
    return out / "index.html"


def _write(cal: Calibration, out: Path) -> None:
    model = report_model(cal)
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        pass
    else:
        for d in model["dists"]:
            name = f"residual-{d['slug']}.svg"
            if _fig_module(cal, d["module"], out / name):
                d["figure"] = name
        if _fig_tail(cal, out / "tail.svg"):
            model["tail_figure"] = "tail.svg"
    write_text(out / "index.html", render("calibration.html.j2", r=model))
    write_text(out / "calibration.md", render("calibration.md.j2", r=model))
    write_text(
        out / "calibration.json",
        json.dumps(cal.to_dict(), indent=2, ensure_ascii=False) + "\n",
    )


def summary_text(cal: Calibration) -> str:
    """The command's terminal output: one line per module and the rates."""
    rates = cal.rates()
    cells = len(cal.cells)
    workers = f" on {cal.workers} workers" if cal.workers else ""
    points = cal.runs // max(cal.seeds * cells, 1)
    envelope = f" × {points} envelope points" if points > 1 else ""
    lines = [
        f"{cal.architecture}: τ = {_fmt(cal.tau)}, target p = {cal.false_switch:g} false alarms "
        f"per nominal run; {cal.runs} runs ({cal.seeds} seeds × {cells} scenario/configuration"
        f"{envelope}) "
        f"in {cal.elapsed_s:.1f} s ({cal.executor}{workers})"
    ]
    width = max(len(m) for m in cal.modules)
    for m, b in cal.modules.items():
        if b.calibrated:
            lines.append(f"  {m:<{width}}  {b.signal}: {_fmt(b.old)} → {_fmt(b.new)}")
        else:
            lines.append(f"  {m:<{width}}  {b.signal}: {_fmt(b.old)} kept ({b.note})")
    lines.append(
        "  false alarms per run, worst configuration: old bands "
        f"{_pct(rates['empirical_old'])} observed ({_pct(rates['predicted_old'])} predicted), "
        f"new {_pct(rates['empirical_new'])} observed ({_pct(rates['predicted_new'])} predicted)"
    )
    if cal.verify_seeds:
        lines.append(
            f"  on {cal.verify_seeds} fresh seeds: old {_pct(rates['verify_old'])}, "
            f"new {_pct(rates['verify_new'])} ({cal.verify_elapsed_s:.1f} s)"
        )
    return "\n".join(lines)
