"""The run report's figures (paper Fig. 2–6) with matplotlib, headless.

This module imports matplotlib: it is imported inside the functions that draw (never
at ``archself`` start-up). Figures are :class:`archself.sim.plot.PaperFigure` objects on the
Agg canvas: no pyplot, no global backend switch, no display needed; TrueType fonts in
a saved PDF, no title unless ``title`` asks for one, ``size="one"``/``"two"`` for a
paper's column or page width. ``plot_*`` return the Figure,
:func:`figure_bytes` its bytes (no date or software metadata, so the bytes depend only
on the data and the matplotlib version). Legends sit where they cover no label: outside
the axes wherever switch labels ("a1 → a2") are drawn at the top of the axes.

Text from the architecture file (module names) is passed through :func:`_tex`
so that a ``$`` in a name is shown, not parsed as mathtext.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from archself.io.files import write_bytes
from archself.reports.run import RunReport
from archself.sim.plot import (
    COLORS,
    LABELS,
    PaperFigure,
    error_axes,
    fault_lines,
    legend_below,
    paper_figure,
    switch_lines,
)
from archself.sim.plot import tex as _tex

#: A paper size: ``"one"`` column, ``"two"`` columns, (width, height) in inches, or None
#: (the report's own size); see :func:`archself.sim.plot.paper_figure`.
Size = str | tuple[float, float] | None

__all__ = [
    "FORMATS",
    "figure_bytes",
    "shown_formats",
    "write_figure",
    "plot_error",
    "plot_influence",
    "plot_qualities",
    "plot_trajectory",
]


def _figure(w: float = 7.5, h: float = 4.2, size: Size = None) -> PaperFigure:
    return paper_figure(w, h, size, dpi=100)


def _title(ax: Any, title: bool | str, default: str) -> None:
    """The title asked for: ``default`` for True, the string given, none for False."""
    if title:
        ax.set_title(_tex(title if isinstance(title, str) else default))


#: Figure formats :func:`figure_bytes` writes, and the metadata each gets (no date, no
#: software version: the bytes depend only on the data and the matplotlib version).
FORMATS = {
    "png": {"Software": None},
    "svg": {"Date": None},
    "pdf": {"CreationDate": None, "Producer": None},
}


#: Saves :func:`figure_bytes` makes at most until two agree.
SETTLE = 4


def figure_bytes(fig: Any, fmt: str = "png", dpi: int = 150) -> bytes:
    """``fig`` saved as ``png``, ``svg`` or ``pdf``: deterministic bytes.

    ``dpi`` matters for PNG (and for images inside a vector file); SVG keeps its text
    as text (``svg.fonttype: none``) so a paper's fonts apply, and a fixed hash salt.
    The figure is saved until two saves agree (at most :data:`SETTLE` times): the
    constrained layout settles over a few draws at a new resolution (the first PDF after
    a PNG differed from the next in the 10th digit of a clip box).
    """
    import matplotlib

    if fmt not in FORMATS:
        raise ValueError(f"unknown figure format {fmt!r}; known: {', '.join(FORMATS)}")
    rc: dict[str, Any] = {"svg.hashsalt": "archself", "svg.fonttype": "none",
                          "pdf.fonttype": 42}
    last = b""
    with matplotlib.rc_context(rc):  # type: ignore[arg-type]
        for _ in range(SETTLE):
            buf = io.BytesIO()
            fig.savefig(buf, format=fmt, dpi=dpi, metadata=FORMATS[fmt])
            if buf.getvalue() == last:
                break
            last = buf.getvalue()
    return last


def shown_formats(formats: Sequence[str]) -> tuple[str, tuple[str, ...]]:
    """The format a report's HTML shows (SVG if asked for, else PNG) and every one to write."""
    shown = "svg" if "svg" in formats else "png"
    return shown, tuple(dict.fromkeys((*formats, shown)))


def write_figure(out: Path, stem: str, fig: Any, formats: Sequence[str], dpi: int) -> None:
    """``fig`` as ``out/stem.<format>`` in every one of ``formats`` (atomic files)."""

    for fmt in formats:
        write_bytes(out / f"{stem}.{fmt}", figure_bytes(fig, fmt, dpi))


def _comp(arr: np.ndarray, c: int) -> np.ndarray:
    a = np.asarray(arr, dtype=float)
    return a if a.ndim == 1 else a[:, c]


def _unit(rep: RunReport) -> str:
    return f" [{_tex(rep.unit)}]" if rep.unit else ""


def plot_trajectory(rep: RunReport, size: Size = None, title: bool | str = False) -> PaperFigure:
    """Fig. 2–4: the objective's actual signal against its reference (x–y, or vs. t).

    Two or more components: an x–y plot at equal aspect (a metre is as long on both
    axes), axes in the objective's unit; one component: against time. The reference is
    drawn last, dashed and on top, so it stays visible where a run follows it closely.
    """
    comps = rep.objective["components"]
    fig = _figure(7.5, 5.0, size)
    ax = fig.add_subplot()
    first = next(iter(rep.series.values()))
    xy = len(comps) >= 2 and "reference" in first and np.ndim(first["reference"]) == 2

    def curve(s: dict[str, Any], key: str) -> tuple[np.ndarray, np.ndarray]:
        """x and y of the series ``key``: its first two components, or the first against t."""
        if xy:
            return _comp(s[key], comps[0]), _comp(s[key], comps[1])
        return np.asarray(s["t"]), _comp(s[key], comps[0])

    for mode, s in rep.series.items():
        if "actual" not in s:
            continue
        x, y = curve(s, "actual")
        ax.plot(x, y, color=COLORS.get(mode), lw=2.0, alpha=0.85, zorder=2,
                label=LABELS.get(mode, mode))
        if xy and mode == "adaptive":
            t = np.asarray(s["t"])
            for k, sw in enumerate(rep.switches):
                i = int(np.searchsorted(t, sw["t_s"]))
                if i < len(t):
                    ax.plot(x[i], y[i], "o", color="#2ca02c", ms=7, zorder=5,
                            mec="white", mew=0.8, label=("switch" if k == 0 else None))
    if "reference" in first:
        ax.plot(*curve(first, "reference"), color=COLORS["reference"], ls=(0, (4, 3)), lw=1.1,
                zorder=4, label="reference")
    actual = rep.objective["actual"]
    if xy:
        ax.set_xlabel(_tex(f"{actual}[{comps[0]}]") + _unit(rep))
        ax.set_ylabel(_tex(f"{actual}[{comps[1]}]") + _unit(rep))
        ax.set_aspect("equal", adjustable="datalim")
    else:
        switch_lines(ax, rep.switches, label=False)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(_tex(f"{actual}[{comps[0]}]") + _unit(rep))
    _title(ax, title, f"Trajectory: {rep.scenario}")
    ax.grid(alpha=0.3)
    legend_below(fig, ax, first="reference")  # outside: it hides no curve at any size
    return fig


def plot_error(rep: RunReport, size: Size = None, title: bool | str = False) -> PaperFigure:
    """Fig. 6: tracking error ‖actual − reference‖ of each run, switches and faults marked."""
    fig = _figure(size=size)
    ax = fig.add_subplot()
    error_axes(ax, rep.series, rep.switches, rep.faults, rep.acceptable, rep.unit)
    _title(ax, title, f"Tracking error: {rep.scenario}")
    legend_below(fig, ax)
    return fig


#: Colours of Fig. 5's channels: matplotlib's tab10 and tab20 without green (the switch
#: lines) and grey (the fault onsets), so no channel looks like an event line.
Z_COLORS = ("#1f77b4", "#ff7f0e", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22",
            "#17becf", "#393b79", "#ad494a", "#8c6d31", "#7b4173", "#3182bd", "#e6550d")
#: Colours of the rejection reasons in Fig. 5's strip (most frequent first).
REJECTION_COLORS = ("#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")


def plot_influence(rep: RunReport, size: Size = None, title: bool | str = False) -> PaperFigure:
    """Fig. 5: |z_i| per module per MAPE-K cycle, τ, the warm-up and the switch events.

    Under the channels, a strip marks the cycles whose candidates changed nothing, one
    row per reason (the action and the planner's verdict, e.g. ``compensate_left_wheel:
    not applicable (only in a1, a2)``: the fault was already compensated), with the
    number of cycles; the legend under the figure says the reason in full.

    The time axis spans what happened (:func:`_span`: faults, switches, rejected cycles,
    channels near τ), not the whole run when that is mostly quiet; the legend names
    the few channels that matter (:func:`_channels`), the others are grey.
    """
    rej = rep.rejections[: len(REJECTION_COLORS)]
    if rej:
        fig = _figure(9.0, 5.4 + 0.25 * len(rej), size)
        ax, strip = fig.subplots(2, 1, sharex=True,
                                 height_ratios=[4.0, 0.45 + 0.35 * len(rej)])
    else:
        fig = _figure(9.0, 4.6, size)
        ax, strip = fig.add_subplot(), None
    if rep.warmup_s > 0:
        ax.axvspan(0, rep.warmup_s, color="#bbbbbb", alpha=0.35,
                   label=f"warm-up ({rep.warmup_s:g} s)")
    shown, rest = _channels(rep)
    for k, name in enumerate(shown):
        ax.plot(rep.z_t, rep.z[name], lw=1.3, color=Z_COLORS[k % len(Z_COLORS)],
                label=_tex(f"|z| {name}"), zorder=3)
    for k, name in enumerate(rest):
        ax.plot(rep.z_t, rep.z[name], lw=0.8, color="#aaaaaa", zorder=2,
                label=(f"|z| of {len(rest)} other modules" if k == 0 else None))
    for k, (label, value) in enumerate(rep.tau):
        ax.axhline(value, color="#000000", ls="--" if k == 0 else ":", lw=1.0,
                   label=f"{label} = {value:g}")
    fault_lines(ax, rep.faults)
    switch_lines(ax, rep.switches)
    if not rep.z:
        ax.text(0.5, 0.5, "no module influence above zero", ha="center",
                transform=ax.transAxes, color="#777777")
    if strip is None:
        ax.set_xlabel("t [s]")
    ax.set_ylabel("|z_i| (Eq. 14)")
    _title(ax, title, f"Influence channels: {rep.scenario}")
    ax.grid(alpha=0.3)
    if strip is None and fig.get_figwidth() < 5:  # a column: the legend under the axes
        legend_below(fig, ax)
    else:
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    span = _span(rep)
    if span is not None:
        ax.set_xlim(*span)
    if strip is not None:
        _rejection_strip(fig, strip, rep, rej)
    return fig


#: Channels drawn in colour and named in the legend: at most this many, each reaching at
#: least :data:`SHOWN_SHARE` of the largest |z|; the others are grey, one legend entry.
SHOWN_MAX = 5
SHOWN_SHARE = 0.25


def _channels(rep: RunReport) -> tuple[list[str], list[str]]:
    """The channels named in the legend (largest peak first) and the others (file order)."""
    peaks = {n: float(np.nanmax(z, initial=0.0)) for n, z in rep.z.items()}
    top = max(peaks.values(), default=0.0)
    ranked = sorted(peaks, key=lambda n: -peaks[n])
    shown = [n for n in ranked[:SHOWN_MAX] if peaks[n] >= SHOWN_SHARE * top]
    return shown, [n for n in rep.z if n not in shown]


def _span(rep: RunReport) -> tuple[float, float] | None:
    """The time span around what happened, or None for the whole run.

    What happened: fault onsets, switches, rejected cycles and every cycle where a
    channel reached a tenth of τ (of the largest |z| without τ). The span reaches a
    sixth of its length (at least five cycles) beyond them; None when that is most
    of the run anyway.
    """
    t = np.asarray(rep.z_t, dtype=float)
    if t.size < 2 or not rep.z:
        return None
    level = 0.1 * (rep.tau[0][1] if rep.tau else
                   max(float(np.nanmax(z, initial=0.0)) for z in rep.z.values()))
    z = np.vstack([np.nan_to_num(np.asarray(v, dtype=float)) for v in rep.z.values()])
    near = t[(z >= level).any(axis=0)] if level > 0 else t[:0]
    events = [*near.tolist(),
              *(f["onset_s"] for f in rep.faults), *(s["t_s"] for s in rep.switches),
              *(x for r in rep.rejections for x in r.t)]
    if not events:
        return None
    lo, hi = min(events), max(events)
    period = rep.period_s if rep.period_s == rep.period_s and rep.period_s > 0 else 1.0
    pad = max((hi - lo) / 6, 5 * period)
    lo, hi = max(float(t[0]), lo - pad), min(float(t[-1]), hi + pad)
    return (lo, hi) if hi - lo < 0.6 * (t[-1] - t[0]) else None


def _rejection_strip(fig: Any, ax: Any, rep: RunReport, rej: list[Any]) -> None:
    """One row per rejection reason: a bar over every cycle it turned down."""
    width = rep.period_s if rep.period_s == rep.period_s and rep.period_s > 0 else 1.0
    total = sum(len(r.t) for r in rep.rejections)
    for k, r in enumerate(rej):
        ax.broken_barh([(t - width, width) for t in r.t], (k - 0.35, 0.7),
                       color=REJECTION_COLORS[k],
                       label=_tex(f"{len(r.t)} cycles: {r.label}"))
    ax.set_yticks(range(len(rej)), [_tex(f"{r.reason} ({len(r.t)})") for r in rej],
                  fontsize=7)
    ax.set_ylim(len(rej) - 0.5, -0.5)
    ax.set_xlabel("t [s]")
    ax.set_title(f"cycles with candidates that changed nothing: {total}", fontsize=8,
                 loc="left")
    ax.grid(axis="x", alpha=0.3)
    for s in rep.switches:
        ax.axvline(s["t_s"], color="#2ca02c", ls="--", lw=1.2)
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower left", fontsize=7, frameon=False,
               title="why (action: verdict of the planner)", title_fontsize=7)


def _steps(rep: RunReport, mode: str, key: Any) -> tuple[np.ndarray, np.ndarray]:
    """A step curve over run ``mode``: ``key(configuration)`` from each switch on."""
    line = rep.timeline(mode)
    t_end = float(np.asarray(rep.series[mode]["t"])[-1])
    t = np.array([t for t, _ in line] + [t_end])
    y = np.array([key(c) for _, c in line] + [key(line[-1][1])], dtype=float)
    return t, y


def plot_qualities(rep: RunReport, size: Size = None, title: bool | str = False) -> PaperFigure:
    """The quality attributes over time and the trade-off the loop made (one figure).

    Left: the utility of each attribute (thin) and the weighted utility U (thick) of the
    configuration each run was in, over time (the fixed run dashed); switches marked.
    Right: the trade-off: every configuration at its values of the two attributes the
    preferences weigh most (one attribute: its value against U), labelled with U, and
    the adaptive run's path through them (arrows, with the switch times).
    """
    q = rep.qualities
    assert q is not None
    confs, prefs = q["configurations"], q["preferences"]
    names = sorted(prefs, key=lambda n: -prefs[n])
    fig = _figure(11.0, 4.6, size)
    ax, tr = fig.subplots(1, 2, width_ratios=[1.5, 1.0])
    main = "adaptive" if rep.adaptive is not None else rep.runs[0].mode
    for mode in [r.mode for r in rep.runs]:
        ls = "--" if mode == "fixed" else "-"
        t, u = _steps(rep, mode, lambda c: confs[c]["U"])
        ax.step(t, u, where="post", color=COLORS.get(mode, "#1f77b4"), lw=2.4, ls=ls,
                label=f"U ({LABELS.get(mode, mode)})")
        if mode != main:
            continue
        for k, n in enumerate(names):
            t, u = _steps(rep, mode, lambda c, n=n: confs[c]["attributes"][n]["utility"])
            ax.step(t, u, where="post", lw=1.1, color=Z_COLORS[(k + 1) % len(Z_COLORS)],
                    label=_tex(f"u {n} (weight {prefs[n]:g})"))
    switch_lines(ax, rep.switches, label=False)
    ax.set_ylim(-0.05, 1.12)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("utility (0..1)")
    _title(ax, title, f"Quality attributes: {rep.scenario}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower left")
    _trade_off(tr, rep, names)
    return fig


def _trade_off(ax: Any, rep: RunReport, names: list[str]) -> None:
    """Configurations in the space of the two heaviest attributes; the run's path."""
    q = rep.qualities
    assert q is not None
    confs, units = q["configurations"], q["units"]

    def xy(c: str) -> tuple[float, float]:
        attrs = confs[c]["attributes"]
        y = attrs[names[1]]["value"] if len(names) > 1 else confs[c]["U"]
        return float(attrs[names[0]]["value"]), float(y)

    at: dict[tuple[float, float], list[str]] = {}  # configurations at one point: one label
    for c in confs:
        at.setdefault(xy(c), []).append(f"{c} (U {confs[c]['U']:.2f})")
    for (x, y), labels in at.items():
        ax.plot(x, y, "o", color="#7f7f7f", ms=7, zorder=3)
        ax.annotate(_tex(", ".join(labels)), (x, y), xytext=(5, 4),
                    textcoords="offset points", fontsize=8)
    main = "adaptive" if rep.adaptive is not None else rep.runs[0].mode
    line = rep.timeline(main)
    for (_, a), (t, b) in zip(line, line[1:], strict=False):
        ax.annotate("", xy(b), xy(a), arrowprops={"arrowstyle": "->", "color": "#2ca02c",
                                                  "lw": 1.6})
        (xa, ya), (xb, yb) = xy(a), xy(b)
        ax.annotate(f"{t:g} s", ((xa + xb) / 2, (ya + yb) / 2), fontsize=7, color="#2ca02c")
    x0, y0 = xy(line[0][1])
    ax.plot(x0, y0, "s", color=COLORS.get(main), ms=9, zorder=4, label="start")
    x1, y1 = xy(line[-1][1])
    ax.plot(x1, y1, "*", color=COLORS.get(main), ms=13, zorder=5, label="end")

    def label(n: str) -> str:
        return _tex(n + (f" [{units[n]}]" if units.get(n) else ""))

    ax.set_xlabel(label(names[0]))
    ax.set_ylabel(label(names[1]) if len(names) > 1 else "U")
    ax.set_title("Trade-off: configurations and the path taken", fontsize=9)
    ax.grid(alpha=0.3)
    ax.margins(0.25)
    ax.legend(fontsize=7, loc="best")
