"""The run report's figures (paper Fig. 2–6) with matplotlib, headless.

matplotlib is imported inside the functions (never at ``archself`` start-up) and
used through :class:`matplotlib.figure.Figure` with the Agg canvas: no pyplot,
no global backend switch, no display needed. ``plot_*`` return the Figure,
:func:`figure_bytes` its bytes (no date or software metadata, so the bytes depend only
on the data and the matplotlib version). Legends sit where they cover no label: outside
the axes wherever switch labels ("a1 → a2") are drawn at the top of the axes.

Text from the architecture file (module names) is passed through :func:`_tex`
so that a ``$`` in a name is shown, not parsed as mathtext.
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np

from archself.reports.run import RunReport

__all__ = [
    "FORMATS",
    "figure_bytes",
    "plot_error",
    "plot_influence",
    "plot_qualities",
    "plot_trajectory",
]

COLORS = {"fixed": "#c0392b", "adaptive": "#1f77b4", "reference": "#222222"}
LABELS = {"fixed": "fixed architecture", "adaptive": "adaptive architecture"}


def _tex(s: Any) -> str:
    return str(s).replace("$", r"\$")


def _figure(w: float = 7.5, h: float = 4.2) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), dpi=100, layout="constrained")


#: Figure formats :func:`figure_bytes` writes, and the metadata each gets (no date, no
#: software version: the bytes depend only on the data and the matplotlib version).
FORMATS = {
    "png": {"Software": None},
    "svg": {"Date": None},
    "pdf": {"CreationDate": None, "Producer": None},
}


def figure_bytes(fig: Any, fmt: str = "png", dpi: int = 150) -> bytes:
    """``fig`` saved as ``png``, ``svg`` or ``pdf``: deterministic bytes.

    ``dpi`` matters for PNG (and for images inside a vector file); SVG keeps its text
    as text (``svg.fonttype: none``) so a paper's fonts apply, and a fixed hash salt.
    """
    import matplotlib

    if fmt not in FORMATS:
        raise ValueError(f"unknown figure format {fmt!r}; known: {', '.join(FORMATS)}")
    buf = io.BytesIO()
    rc: dict[str, Any] = {"svg.hashsalt": "archself", "svg.fonttype": "none",
                          "pdf.fonttype": 42}
    with matplotlib.rc_context(rc):  # type: ignore[arg-type]
        fig.savefig(buf, format=fmt, dpi=dpi, metadata=FORMATS[fmt])
    return buf.getvalue()


def _comp(arr: np.ndarray, c: int) -> np.ndarray:
    a = np.asarray(arr, dtype=float)
    return a if a.ndim == 1 else a[:, c]


def _legend_below(fig: Any, ax: Any, first: str | None = None) -> None:
    """The legend under the axes, outside them: it can hide neither a curve nor a label.

    The switch labels ("a1 → a2") sit at the top of the axes, where a legend inside
    the axes (``upper left``, or ``best``, which ignores text) may cover them; an x–y
    trajectory fills its axes at equal aspect. ``first``: the label listed first.
    """
    handles, labels = ax.get_legend_handles_labels()
    order = sorted(range(len(labels)), key=lambda i: labels[i] != first)
    handles, labels = [handles[i] for i in order], [labels[i] for i in order]
    if handles:
        fig.legend(handles, labels, loc="outside lower center", fontsize=8,
                   ncols=min(2, len(handles)), frameon=False)


def _switch_lines(ax: Any, rep: RunReport, label: bool = True) -> None:
    for k, s in enumerate(rep.switches):
        ax.axvline(s["t_s"], color="#2ca02c", ls="--", lw=1.2,
                   label=("architecture switch" if label and k == 0 else None))
        ax.annotate(_tex(f"{s['from']} → {s['to']}"), (s["t_s"], 1.0),
                    xycoords=("data", "axes fraction"), xytext=(3, -12),
                    textcoords="offset points", fontsize=8, color="#2ca02c")


def _fault_lines(ax: Any, rep: RunReport) -> None:
    for k, f in enumerate(rep.faults):
        ax.axvline(f["onset_s"], color="#7f7f7f", ls=":", lw=1.0,
                   label=("fault onset" if k == 0 else None))


def _unit(rep: RunReport) -> str:
    return f" [{_tex(rep.unit)}]" if rep.unit else ""


def plot_trajectory(rep: RunReport) -> Any:
    """Fig. 2–4: the objective's actual signal against its reference (x–y, or vs. t).

    Two or more components: an x–y plot at equal aspect (a metre is as long on both
    axes), axes in the objective's unit; one component: against time. The reference is
    drawn last, dashed and on top, so it stays visible where a run follows it closely.
    """
    comps = rep.objective["components"]
    fig = _figure(7.5, 5.0)
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
        _switch_lines(ax, rep, label=False)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(_tex(f"{actual}[{comps[0]}]") + _unit(rep))
    ax.set_title(_tex(f"Trajectory: {rep.scenario}"))
    ax.grid(alpha=0.3)
    _legend_below(fig, ax, first="reference")  # outside: it hides no curve at any size
    return fig


def plot_error(rep: RunReport) -> Any:
    """Fig. 6: tracking error ‖actual − reference‖ of each run, switches and faults marked."""
    fig = _figure()
    ax = fig.add_subplot()
    for mode, s in rep.series.items():
        ax.plot(np.asarray(s["t"]), np.asarray(s["J"], dtype=float), color=COLORS.get(mode),
                lw=1.4, label=LABELS.get(mode, mode))
    if rep.acceptable > 0:
        ax.axhline(rep.acceptable, color="#555555", ls="-.", lw=0.9,
                   label=f"acceptable J_ref = {rep.acceptable:g}")
    _fault_lines(ax, rep)
    _switch_lines(ax, rep)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("tracking error" + _unit(rep))
    ax.set_title(_tex(f"Tracking error: {rep.scenario}"))
    ax.grid(alpha=0.3)
    _legend_below(fig, ax)
    return fig


#: Colours of Fig. 5's channels: matplotlib's tab10 and tab20 without green (the switch
#: lines) and grey (the fault onsets), so no channel looks like an event line.
Z_COLORS = ("#1f77b4", "#ff7f0e", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22",
            "#17becf", "#393b79", "#ad494a", "#8c6d31", "#7b4173", "#3182bd", "#e6550d")
#: Colours of the rejection reasons in Fig. 5's strip (most frequent first).
REJECTION_COLORS = ("#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")


def plot_influence(rep: RunReport) -> Any:
    """Fig. 5: |z_i| per module per MAPE-K cycle, τ, the warm-up and the switch events.

    Under the channels, a strip marks the cycles whose candidates changed nothing, one
    row per reason (the action and the planner's verdict, e.g. ``compensate_left_wheel:
    not applicable (only in a1, a2)``: the fault was already compensated), with the
    number of cycles; the legend under the figure says the reason in full.
    """
    rej = rep.rejections[: len(REJECTION_COLORS)]
    if rej:
        fig = _figure(9.0, 5.4 + 0.25 * len(rej))
        ax, strip = fig.subplots(2, 1, sharex=True,
                                 height_ratios=[4.0, 0.45 + 0.35 * len(rej)])
    else:
        fig = _figure(9.0, 4.6)
        ax, strip = fig.add_subplot(), None
    if rep.warmup_s > 0:
        ax.axvspan(0, rep.warmup_s, color="#bbbbbb", alpha=0.35,
                   label=f"warm-up ({rep.warmup_s:g} s)")
    for k, (name, z) in enumerate(rep.z.items()):
        ax.plot(rep.z_t, z, lw=1.3, color=Z_COLORS[k % len(Z_COLORS)],
                label=_tex(f"|z| {name}"))
    for k, (label, value) in enumerate(rep.tau):
        ax.axhline(value, color="#000000", ls="--" if k == 0 else ":", lw=1.0,
                   label=f"{label} = {value:g}")
    _fault_lines(ax, rep)
    _switch_lines(ax, rep)
    if not rep.z:
        ax.text(0.5, 0.5, "no module influence above zero", ha="center",
                transform=ax.transAxes, color="#777777")
    if strip is None:
        ax.set_xlabel("t [s]")
    ax.set_ylabel("|z_i| (Eq. 14)")
    ax.set_title(_tex(f"Influence channels: {rep.scenario}"))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    if strip is not None:
        _rejection_strip(fig, strip, rep, rej)
    return fig


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


def plot_qualities(rep: RunReport) -> Any:
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
    fig = _figure(11.0, 4.6)
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
    _switch_lines(ax, rep, label=False)
    ax.set_ylim(-0.05, 1.12)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("utility (0..1)")
    ax.set_title(_tex(f"Quality attributes: {rep.scenario}"))
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
