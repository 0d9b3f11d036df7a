"""The Figures the API returns: publication settings, and a run's error over time.

Every ``plot_*`` function and ``plot()`` method of archself makes its figure with
:func:`paper_figure`: a :class:`PaperFigure` (a :class:`matplotlib.figure.Figure`
on the Agg canvas, no pyplot) that saves PDF and PostScript with TrueType fonts
(``pdf.fonttype`` 42: no Type 3 font, which publishers' checkers reject) whoever
calls ``savefig``, sized for one or two columns (``size="one"``, ``"two"``) and
without a title unless one is asked for. In a notebook it shows as a PNG.

This module imports matplotlib: import it inside the functions that draw (never at
``archself`` start-up).
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from typing import Any

import matplotlib
import numpy as np
from matplotlib.figure import Figure

__all__ = ["PAPER_RC", "SIZES", "PaperFigure", "paper_figure", "plot_run"]

#: What every saved Figure gets: TrueType (Type 42) fonts in PDF and PostScript.
PAPER_RC: dict[str, Any] = {"pdf.fonttype": 42, "ps.fonttype": 42}
#: Widths [in] of a figure in one column and across two (IEEE/ACM two-column pages).
SIZES = {"one": 3.5, "two": 7.16}
#: Colours of the runs and events, shared by every run figure.
COLORS = {"fixed": "#c0392b", "adaptive": "#1f77b4", "reference": "#222222",
          "switch": "#2ca02c", "fault": "#7f7f7f"}
LABELS = {"fixed": "fixed architecture", "adaptive": "adaptive architecture"}


class PaperFigure(Figure):
    """A Figure that saves with :data:`PAPER_RC` and shows as a PNG in notebooks."""

    def savefig(self, fname: Any, *args: Any, **kwargs: Any) -> None:
        """:meth:`matplotlib.figure.Figure.savefig` with TrueType fonts in PDF and PS."""
        with matplotlib.rc_context(PAPER_RC):  # type: ignore[arg-type]
            super().savefig(fname, *args, **kwargs)

    def _repr_png_(self) -> bytes:
        buf = io.BytesIO()
        self.savefig(buf, format="png", dpi=100, metadata={"Software": None})
        return buf.getvalue()


def paper_figure(width: float, height: float, size: str | tuple[float, float] | None = None,
                 **kwargs: Any) -> PaperFigure:
    """A :class:`PaperFigure` of ``width`` × ``height`` inches, or sized for a paper.

    Parameters
    ----------
    width, height : float
        The figure's own size [in] (what the reports use).
    size : {"one", "two"} or (float, float), optional
        ``"one"``: one column wide (3.5 in), ``"two"``: two columns (7.16 in), the
        height scaled with the width (at least 0.62 of it; 0.8 in one
        column, where a legend goes under the axes); a pair: that size in inches.
    **kwargs
        Passed to :class:`matplotlib.figure.Figure` (``dpi``; ``layout``, constrained
        by default).

    Raises
    ------
    ValueError
        If ``size`` is none of these.
    """
    if isinstance(size, str):
        if size not in SIZES:
            raise ValueError(f"size must be one of {', '.join(map(repr, SIZES))} or "
                             f"(width, height) in inches, not {size!r}")
        w = SIZES[size]
        width, height = w, w * max(height / width, 0.8 if size == "one" else 0.62)
    elif size is not None:
        width, height = (float(v) for v in size)
    kwargs.setdefault("layout", "constrained")
    return PaperFigure(figsize=(width, height), **kwargs)


def tex(s: Any) -> str:
    """Text from a file, shown as is (a ``$`` not parsed as mathtext)."""
    return str(s).replace("$", r"\$")


def switch_lines(ax: Any, switches: Sequence[dict[str, Any]], label: bool = True) -> None:
    """A dashed line and an ``a1 → a2`` label at the top of ``ax`` for every switch."""
    for k, s in enumerate(switches):
        ax.axvline(s["t_s"], color=COLORS["switch"], ls="--", lw=1.2,
                   label=("architecture switch" if label and k == 0 else None))
        ax.annotate(tex(f"{s['from']} → {s['to']}"), (s["t_s"], 1.0),
                    xycoords=("data", "axes fraction"), xytext=(3, -12),
                    textcoords="offset points", fontsize=8, color=COLORS["switch"])


def fault_lines(ax: Any, faults: Sequence[dict[str, Any]]) -> None:
    """A dotted grey line at every fault onset."""
    for k, f in enumerate(faults):
        ax.axvline(f["onset_s"], color=COLORS["fault"], ls=":", lw=1.0,
                   label=("fault onset" if k == 0 else None))


def legend_below(fig: Any, ax: Any, first: str | None = None) -> None:
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


def error_axes(ax: Any, series: dict[str, dict[str, Any]], switches: Sequence[dict[str, Any]],
               faults: Sequence[dict[str, Any]], acceptable: float, unit: str | None) -> None:
    """Fig. 6 on ``ax``: J of each run (mode → series ``t``, ``J``), switches and faults."""
    for mode, s in series.items():
        ax.plot(np.asarray(s["t"]), np.asarray(s["J"], dtype=float), color=COLORS.get(mode),
                lw=1.4, label=LABELS.get(mode, mode))
    if acceptable > 0:
        ax.axhline(acceptable, color="#555555", ls="-.", lw=0.9,
                   label=f"acceptable J_ref = {acceptable:g}")
    fault_lines(ax, faults)
    switch_lines(ax, switches)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("tracking error" + (f" [{tex(unit)}]" if unit else ""))
    ax.grid(alpha=0.3)


def plot_run(*results: Any, size: str | tuple[float, float] | None = None,
             title: bool | str = False) -> PaperFigure:
    """The objective error J of one run, or of a fixed and an adaptive run, over time.

    Switches (of the adaptive run, or of the only run) and fault onsets are marked, the
    acceptable error J_ref drawn when the file declares one; what
    :meth:`archself.RunResult.plot` returns.

    Parameters
    ----------
    *results : RunResult
        One run, or runs of one scenario in different modes.
    size : {"one", "two"} or (float, float), optional
        See :func:`paper_figure`.
    title : bool or str
        True: the scenario's name as title; a string: that title; False: none.
    """
    first = results[-1]
    adaptive = next((r for r in results if r.mode == "adaptive"), first)
    report = dict(first.meta.get("report") or {})
    fig = paper_figure(7.5, 4.2, size)
    ax = fig.add_subplot()
    error_axes(ax, {r.mode: {"t": r.series["t"], "J": r.series["J"]} for r in results},
               adaptive.switches, report.get("faults") or [],
               float(report.get("acceptable") or 0.0), first.unit)
    if title:
        ax.set_title(tex(title if isinstance(title, str) else f"Tracking error: {first.scenario}"))
    legend_below(fig, ax)
    return fig
