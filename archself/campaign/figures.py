"""The campaign report's figures (SVG): detection delays, errors fixed vs adaptive, τ sweep.

Drawn with matplotlib's object-oriented API (:class:`matplotlib.figure.Figure`, no
pyplot), imported inside the functions: only ``campaign-report`` loads matplotlib.
The SVG files are deterministic (fixed hash salt, no date). Each ``fig_*`` writes
its file and returns False when there is nothing to draw.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["fig_delays", "fig_errors", "fig_tau"]


def _figure(width: float = 6.4, height: float = 3.6) -> Any:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    return fig


def _save(fig: Any, path: Path) -> None:
    import io

    import matplotlib

    from archself.atomic import write_bytes

    buf = io.BytesIO()
    with matplotlib.rc_context({"svg.hashsalt": "archself", "svg.fonttype": "none"}):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    write_bytes(path, buf.getvalue())


def fig_delays(rows: list[dict[str, Any]], names: list[str], path: Path) -> bool:
    data = [
        [
            r["detection_delay_s"]
            for r in rows
            if r["scenario"] == n
            and r["mode"] == "adaptive"
            and r.get("error") is None
            and r["detection_delay_s"] is not None
        ]
        for n in names
    ]
    if not any(data):
        return False
    fig = _figure()
    ax = fig.add_subplot()
    for n, d in zip(names, data, strict=True):
        if d:
            ax.hist(d, bins=min(30, max(5, len(d) // 3)), alpha=0.6, label=f"{n} (n = {len(d)})")
    ax.set_xlabel("detection delay [s]")
    ax.set_ylabel("runs")
    ax.legend(frameon=False)
    ax.set_title("Detection delay: first switch after the fault onset")
    _save(fig, path)
    return True


def fig_errors(
    rows: list[dict[str, Any]], names: list[str], metric: str, path: Path, unit: str | None = None
) -> bool:
    fig = _figure(max(6.4, 1.6 * len(names) + 2), 3.8)
    ax = fig.add_subplot()
    data, labels, colors = [], [], []
    for n in names:
        for mode, color in (("fixed", "#999999"), ("adaptive", "#1f77b4")):
            v = [
                r[metric]
                for r in rows
                if r["scenario"] == n
                and r["mode"] == mode
                and r.get("error") is None
                and r[metric] is not None
                and math.isfinite(r[metric])
            ]
            if v:
                data.append(v)
                labels.append(f"{n}\n{mode}")
                colors.append(color)
    if not data:
        return False
    parts = ax.boxplot(data, patch_artist=True, showfliers=True)
    ax.set_xticks(range(1, len(labels) + 1), labels)
    for patch, c in zip(parts["boxes"], colors, strict=True):
        patch.set_facecolor(c)
        patch.set_alpha(0.6)
    ax.set_ylabel(metric.replace("_", " ") + (f" [{unit}]" if unit else ""))
    ax.set_yscale("log" if min(min(d) for d in data) > 0 else "linear")
    title = {"rms_error": "RMS", "max_error": "Maximum", "final_error": "Final"}[metric]
    ax.set_title(f"{title} error, fixed vs adaptive (paired seeds)")
    _save(fig, path)
    return True


def fig_tau(tau: Mapping[str, Any], path: Path) -> bool:
    """One curve per faulted scenario: false-switch rate (x) against median delay (y) over τ."""
    curves = tau.get("curves") or [{"scenario": "all faulted", "points": tau["points"]}]
    fig = _figure(6.0, 4.4)
    ax = fig.add_subplot()
    colors = ["#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2"]
    drawn = False
    xs_all: list[float] = []
    basis = ""
    for c, curve in enumerate(curves):
        color = colors[c % len(colors)]
        pts = [p for p in curve["points"] if p["false_switch"]["rate"] is not None]
        ok = [p for p in pts if p["delay_s"]["median"] is not None]
        if not pts:
            continue
        basis = pts[0]["false_switch_basis"]
        xs_all += [p["false_switch"]["rate"] for p in pts]
        if ok:
            drawn = True
            x = [p["false_switch"]["rate"] for p in ok]
            y = [p["delay_s"]["median"] for p in ok]
            ax.plot(x, y, "-o", color=color, label=str(curve["scenario"]))
            for k, (p, xi, yi) in enumerate(zip(ok, x, y, strict=True)):
                ax.plot(
                    [xi, xi],
                    [p["delay_s"]["p10"], p["delay_s"]["p90"]],
                    color=color,
                    alpha=0.35,
                    lw=3,
                )
                ax.plot(
                    [p["false_switch"]["lo"], p["false_switch"]["hi"]],
                    [yi, yi],
                    color=color,
                    alpha=0.35,
                    lw=1,
                )
                # the ends of the curve are labelled; when both sit on one spot (every τ
                # detects in the first cycle, say) one label gives the range
                together = len(ok) > 1 and x[0] == x[-1] and abs(y[0] - y[-1]) < 1.0
                label = None
                if together and k == 0:
                    label = f"τ={ok[0]['value']:g}…{ok[-1]['value']:g}"
                elif not together and k in (0, len(ok) - 1):
                    label = f"τ={p['value']:g}"
                if label is not None:
                    ax.annotate(
                        label,
                        (xi, yi),
                        textcoords="offset points",
                        xytext=(6, 2),
                        fontsize=7,
                        color=color,
                    )
        for p in pts:
            if p["delay_s"]["median"] is None:
                drawn = True
                ax.axvline(p["false_switch"]["rate"], color=color, ls=":", lw=1)
                ax.annotate(
                    f"{curve['scenario']}, τ={p['value']:g}: never detected",
                    (p["false_switch"]["rate"], 0),
                    fontsize=7,
                    color=color,
                    rotation=90,
                    va="bottom",
                )
    if not drawn:
        return False
    ax.set_xlabel(f"false-switch rate ({basis})")
    ax.set_ylabel("detection delay [s] (median, 10–90 %)")
    ax.set_title(f"τ sweep: {tau['path']}")
    ax.set_xlim(-0.03, max(1.0, max(xs_all)) + 0.03)
    ax.legend(frameon=False, fontsize=8)
    _save(fig, path)
    return True
