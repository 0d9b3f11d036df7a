"""The campaign report's figures: detection delays, errors fixed vs adaptive, τ sweep.

Drawn with matplotlib's object-oriented API (:class:`matplotlib.figure.Figure`, no
pyplot), imported inside the functions: only ``campaign-report`` loads matplotlib.
``plot_*`` return the Figure (None when there is nothing to draw);
:func:`archself.campaign.report.campaign_report` writes it as SVG, PNG or PDF
(deterministic bytes: :func:`archself.reports.figures.figure_bytes`).

They are made to stay readable on real campaigns of 1,000+ runs
(``docs/campaign/``, 1,008 runs):

- delays: one set of bins for every scenario, as wide as the delays' quantum (the
  loop period) or 1/40 of the range, so 168 runs detected in the first cycle are one
  tall bar, not a hairline, and the tallest bars of each scenario are labelled;
- errors: one panel per scenario (its own scale, log only when fixed and adaptive
  are a decade apart), every run drawn as a point beside its box and the medians
  written under the boxes, so a tight distribution (168 fixed runs within 0.5 %) is
  still seen;
- τ sweep: τ on the x axis, the median delay (10–90 % band) above and the
  false-switch and detection rates (95 % Wilson intervals) below, so a sweep where
  no τ ever switches falsely does not pile every point onto x = 0; a false-switch
  rate shared by every scenario (over the fault-free runs) is drawn once, and the
  legend sits under the figure.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from archself.campaign.results import read_results

#: ``"one"``/``"two"`` columns, (width, height) in inches, or None: the report's size
#: (:func:`archself.sim.plot.paper_figure`).
Size = str | tuple[float, float] | None

__all__ = ["plot_delays", "plot_errors", "plot_results", "plot_tau"]

COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2"]
MODE_COLORS = {"fixed": "#999999", "adaptive": "#1f77b4"}
MARKERS = ["s", "^", "D", "v", "o", "P"]
#: Area [pt²] of a run's marker beside its box: ~4 px across at 100 dpi (was 2 px).
MARKER_AREA = 10
ERROR_TITLES = {"rms_error": "RMS", "max_error": "Maximum", "final_error": "Final"}


#: Padding [in] around the figure's content: text drawn by a browser in another font than
#: matplotlib measured (an SVG keeps its text as text) must still fit in the canvas.
PAD_IN = 0.1


def _figure(width: float = 6.4, height: float = 3.6, size: Size = None) -> Any:
    from matplotlib.layout_engine import ConstrainedLayoutEngine

    from archself.sim.plot import paper_figure

    return paper_figure(width, height, size,
                        layout=ConstrainedLayoutEngine(w_pad=PAD_IN, h_pad=PAD_IN))


def _title(set_title: Any, title: bool | str, default: str, **kwargs: Any) -> None:
    """``set_title`` (of an axes, or ``fig.suptitle``) with ``default`` for True, a
    string as given, nothing for False."""
    if title:
        set_title(title if isinstance(title, str) else default, **kwargs)


def _integer_ticks(axis: Any) -> None:
    """Counts on ``axis``: ticks on whole numbers only."""
    from matplotlib.ticker import MaxNLocator

    axis.set_major_locator(MaxNLocator(integer=True))


def _ok(r: Mapping[str, Any], metric: str) -> bool:
    v = r.get(metric)
    return r.get("error") is None and v is not None and math.isfinite(v)


def _bins(values: list[float]) -> list[float]:
    """Common bin edges: a multiple of the values' quantum (their smallest gap, e.g. the
    loop period) about 1/40 of the range wide, each bin centred on multiples of it."""
    lo, hi = min(values), max(values)
    distinct = sorted(set(values))
    gaps = [b - a for a, b in zip(distinct, distinct[1:], strict=False) if b - a > 1e-9]
    quantum = min(gaps) if gaps else 1.0
    width = quantum * max(1, math.ceil((hi - lo) / 40 / quantum - 1e-9))
    edges = [lo - quantum / 2]
    while edges[-1] <= hi:
        edges.append(edges[-1] + width)
    return edges


def plot_delays(rows: list[dict[str, Any]], names: list[str], size: Size = None,
                title: bool | str = False) -> Any:
    """Histogram of the detection delays of the adaptive runs, per faulted scenario.

    The counts axis has whole-number ticks. ``size``: a paper's column (``"one"``) or
    page (``"two"``); ``title`` True writes the report's title.
    """
    data = {n: [r["detection_delay_s"] for r in rows
                if r["scenario"] == n and r["mode"] == "adaptive"
                and _ok(r, "detection_delay_s")] for n in names}
    data = {n: d for n, d in data.items() if d}
    if not data:
        return None
    edges = _bins([v for d in data.values() for v in d])
    fig = _figure(size=size)
    ax = fig.add_subplot()
    for k, (n, d) in enumerate(data.items()):
        color = COLORS[k % len(COLORS)]
        median = statistics.median(d)  # the table's median (the mean of two when n is even)
        counts, _, _ = ax.hist(d, bins=edges, alpha=0.65, color=color,
                               label=f"{n} (n = {len(d)}, median {median:.3g} s)")
        top = max(counts)
        for i in (j for j in range(len(counts)) if counts[j] == top):  # every tallest bar
            ax.annotate(f"{int(counts[i])}", ((edges[i] + edges[i + 1]) / 2, counts[i]),
                        textcoords="offset points", xytext=(0, 2), ha="center", fontsize=7,
                        color=color)
    ax.set_xlabel("detection delay [s]")
    ax.set_ylabel("runs")
    ax.set_ylim(top=ax.get_ylim()[1] * 1.08)
    _integer_ticks(ax.yaxis)
    ax.legend(frameon=False, fontsize=8)
    _title(ax.set_title, title, "Detection delay: first switch after the fault onset")
    return fig


def plot_errors(rows: list[dict[str, Any]], names: list[str], metric: str,
                unit: str | None = None, size: Size = None, title: bool | str = False) -> Any:
    """Fixed vs adaptive ``metric``, one panel per scenario: boxes, every run, medians.

    Every run is a marker beside its box (paired seeds: the same replicate in both
    modes). ``size``: a paper's column (``"one"``) or page (``"two"``); ``title`` True
    writes the report's title.
    """
    panels = []
    for n in names:
        groups = [(mode, [r[metric] for r in rows if r["scenario"] == n
                          and r["mode"] == mode and _ok(r, metric)])
                  for mode in ("fixed", "adaptive")]
        groups = [(m, v) for m, v in groups if v]
        if groups:
            panels.append((n, groups))
    if not panels:
        return None
    fig = _figure(max(6.4, 2.2 * len(panels)), 3.8, size)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    label = ERROR_TITLES[metric]
    u = f" [{unit}]" if unit else ""
    for ax, (n, groups) in zip(axes, panels, strict=True):
        values = [v for _, vs in groups for v in vs]
        lo, hi = min(values), max(values)
        log = lo > 0 and hi / lo > 10
        parts = ax.boxplot([vs for _, vs in groups], patch_artist=True, showfliers=False,
                           widths=0.5)
        for k, ((mode, vs), patch) in enumerate(zip(groups, parts["boxes"], strict=True)):
            patch.set_facecolor(MODE_COLORS[mode])
            patch.set_alpha(0.45)
            # every run, spread sideways by its rank (deterministic, no random jitter)
            xs = [k + 1.33 + 0.12 * ((i * 0.618) % 1.0) for i in range(len(vs))]
            ax.scatter(xs, vs, s=MARKER_AREA, color=MODE_COLORS[mode], alpha=0.55,
                       lw=0.4, edgecolors="white")
        for med in parts["medians"]:
            med.set_color("#000000")
        # the median written under its box, where it covers neither box nor points; the
        # same number as the report's table (the mean of the two middle runs when n is even)
        ax.set_xticks(range(1, len(groups) + 1),
                      [f"{m}\n{statistics.median(vs):.3g}" for m, vs in groups])
        ax.set_xlim(0.5, len(groups) + 0.75)
        if log:
            ax.set_yscale("log")
            ax.set_ylim(lo / 1.6, hi * 1.6)
        else:
            pad = (hi - lo) * 0.15 or abs(hi) * 0.1 or 1.0
            ax.set_ylim(lo - pad, hi + pad)
        ax.set_title(n, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylabel(f"{label if metric == 'rms_error' else label.lower()} error{u}")
    _title(fig.suptitle, title,
           f"{label} error, fixed vs adaptive (paired seeds; medians under the boxes)",
           fontsize=10)
    return fig


def plot_results(path: str | Path, metric: str = "max_error", size: Size = None,
                 title: bool | str = False) -> Any:
    """:func:`plot_errors` of a campaign's results file (every scenario in it).

    Raises
    ------
    CampaignError
        If the file is not a campaign's results
        (:func:`archself.campaign.results.read_results`).
    ValueError
        If ``metric`` is none of ``max_error``, ``final_error``, ``rms_error``.
    """

    if metric not in ERROR_TITLES:
        raise ValueError(f"metric must be one of {', '.join(ERROR_TITLES)}, not {metric!r}")
    rows = read_results(path)[0].to_pylist()
    names = list(dict.fromkeys(r["scenario"] for r in rows))
    unit = next((r["unit"] for r in rows if r.get("unit")), None)
    return plot_errors(rows, names, metric, unit, size, title)


def plot_tau(tau: Mapping[str, Any], size: Size = None, title: bool | str = False) -> Any:
    """The τ sweep: median delay (10–90 %) above, false-switch and detection rates below.

    The legend says over which runs the false-switch rate is (``false switches (over
    fault-free scenarios)``), as no panel title does. ``size``: a paper's column
    (``"one"``) or page (``"two"``); ``title`` True writes the report's title.
    """
    curves = tau.get("curves") or [{"scenario": "all faulted", "points": tau["points"]}]
    curves = [c for c in curves if c["points"]]
    if not curves:
        return None
    fig = _figure(6.4, 5.8, size)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 2])
    basis = ""
    false_rates: list[tuple[str, str, list[float], list[dict[str, Any]]]] = []
    for k, curve in enumerate(curves):
        color = COLORS[k % len(COLORS)]
        pts = sorted(curve["points"], key=lambda p: p["value"])
        x = [p["value"] for p in pts]
        ok = [p for p in pts if p["delay_s"]["median"] is not None]
        if ok:
            top.fill_between([p["value"] for p in ok], [p["delay_s"]["p10"] for p in ok],
                             [p["delay_s"]["p90"] for p in ok], color=color, alpha=0.2, lw=0)
            top.plot([p["value"] for p in ok], [p["delay_s"]["median"] for p in ok], "-o",
                     color=color, ms=4, label=f"{curve['scenario']}: median delay")
        for p in pts:
            if p["delay_s"]["median"] is None:
                top.plot([p["value"]], [0], "x", color=color, ms=7)
                top.annotate("never detected", (p["value"], 0), textcoords="offset points",
                             xytext=(3, 4), fontsize=7, color=color, rotation=90)
        fs = [p["false_switch"] for p in pts]
        if any(f["rate"] is not None for f in fs):
            basis = pts[0].get("false_switch_basis", "")
            xf = [xi for xi, f in zip(x, fs, strict=True) if f["rate"] is not None]
            ff = [f for f in fs if f["rate"] is not None]
            false_rates.append((str(curve["scenario"]), color, xf, ff))
        det = [(xi, p["detected"]) for xi, p in zip(x, pts, strict=True)
               if p.get("detected") and p["detected"]["rate"] is not None]
        if det:
            # hollow markers, each scenario its own shape and size: equal rates (all
            # detected) stay visible one inside the other
            bottom.plot([d[0] for d in det], [d[1]["rate"] for d in det], ":",
                        marker=MARKERS[k % len(MARKERS)], mfc="none", color=color,
                        ms=max(3.0, 8.0 - 1.5 * k), label=f"{curve['scenario']}: detected")
    # over fault-free runs the false-switch rate is one and the same for every scenario:
    # drawn once (in grey), not once per scenario with the last one hiding the others
    same = len(false_rates) > 1 and all(f[2:] == false_rates[0][2:] for f in false_rates)
    for name, color, xf, ff in false_rates[:1] if same else false_rates:
        c = "#555555" if same else color
        bottom.fill_between(xf, [f["lo"] for f in ff], [f["hi"] for f in ff],
                            color=c, alpha=0.15, lw=0)
        over = f" (over {basis})" if basis else ""
        bottom.plot(xf, [f["rate"] for f in ff], "-o", color=c, ms=4,
                    label=f"false switches{over}" if same else f"{name}: false switches{over}")
    top.set_ylabel("detection delay [s]\n(median, 10–90 %)")
    _title(top.set_title, title, f"τ sweep: {tau['path']}")
    top.grid(alpha=0.3)
    top.set_ylim(bottom=0)
    bottom.set_ylabel("rate (95 % CI)")
    bottom.set_ylim(-0.05, 1.08)
    bottom.set_xlabel(f"τ ({tau['path']})")
    bottom.grid(alpha=0.3)
    # one legend under the figure: inside the axes it covered the rates' intervals
    handles, labels = [], []
    for ax in (top, bottom):
        h, lab = ax.get_legend_handles_labels()
        handles += h
        labels += lab
    if handles:
        fig.legend(handles, labels, loc="outside lower center", fontsize=8, frameon=False,
                   ncols=2)
    return fig
