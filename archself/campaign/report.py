"""``archself campaign-report``: what a campaign says about the adaptation loop.

The numbers come from :mod:`archself.campaign.aggregate` (correct switches,
detection delay, false switches, errors fixed versus adaptive, τ sweep, with 95 %
Wilson intervals) and the SVG figures from :mod:`archself.campaign.figures`; this
module renders them: a few lines for the terminal (:func:`summary_text`), the HTML
page from ``templates/campaign_report.html.j2`` in a sandboxed Jinja environment
(``StrictUndefined``, autoescape) and the same numbers as ``summary.json``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from archself.campaign import figures as fig
from archself.campaign.aggregate import CampaignSummary, summarize
from archself.campaign.results import read_results
from archself.io.files import write_text
from archself.io.jsondata import CampaignReportDoc, document
from archself.reports.render import environment

__all__ = ["campaign_report", "summary_text"]


def _pct(rate: Mapping[str, Any] | None) -> str:
    if not rate or rate.get("rate") is None:
        return "–"
    return f"{100 * rate['rate']:.0f} % ({rate['k']}/{rate['n']})"


def _num(x: Any, fmt: str = "{:.2f}") -> str:
    return "–" if x is None else fmt.format(x)


def summary_text(s: CampaignSummary) -> str:
    """A few lines for the terminal: per scenario the rates, delay and errors."""
    lines = [
        f"{s.meta.get('architecture', '?')}: {s.runs} runs"
        + (f", {s.failed} failed" if s.failed else "")
    ]
    unit = f" {s.unit}" if s.unit else ""
    for b in s.scenarios:
        e = b["errors"]["rms_error"]
        head = f"  {b['scenario']}{' (fault-free)' if not b['faulted'] else ''}: "
        parts = [f"correct {_pct(b['correct'])}"]
        if b["faulted"]:
            parts.append(f"median delay {_num(b['delay_s']['median'], '{:.1f}')} s")
        parts.append(f"false switches {_pct(b['false_switch'])}")
        parts.append(
            f"median RMS fixed {_num(e['fixed']['median'])}{unit}"
            f" / adaptive {_num(e['adaptive']['median'])}{unit}"
        )
        lines.append(head + ", ".join(parts))
    if s.tau:
        lines.append(f"  τ sweep ({s.tau['path']}):")
        for c in s.tau["curves"]:
            for p in c["points"]:
                lines.append(
                    f"    {c['scenario']} τ = {p['value']:g}: median delay "
                    f"{_num(p['delay_s']['median'], '{:.1f}')} s, detected "
                    f"{_pct(p['detected'])}, false switches {_pct(p['false_switch'])}"
                )
    return "\n".join(lines)


def _environment() -> Any:
    """The report templates' environment with this report's ``pct`` and ``num`` filters."""

    env = environment().overlay()
    env.filters = {**env.filters, "pct": _pct, "num": _num}  # not the shared dict
    return env


def campaign_report(
    results: str | Path,
    out_dir: str | Path,
    *,
    expect: Mapping[str, str] | None = None,
    tau_path: str | None = None,
    formats: tuple[str, ...] = ("svg",),
    dpi: int = 150,
) -> CampaignSummary:
    """Write ``index.html``, ``summary.json`` and the figures of a campaign to ``out_dir``.

    Each figure is written in every one of ``formats`` (``svg``, ``png``, ``pdf``; PNG at
    ``dpi``); the HTML shows the SVG if asked for, else the PNG (written too if neither is).

    Raises
    ------
    CampaignError
        Unreadable results, an unknown scenario in ``expect``, a bad ``tau_path``.
    OutputError
        If ``out_dir`` cannot be written.
    """
    from archself.reports.architecture import new_folder

    table, meta = read_results(results)
    summary = summarize(table, meta, expect, tau_path)
    rows = table.to_pylist()
    out = Path(out_dir)
    with new_folder(out):
        _write(out, summary, rows, results, formats, dpi)
    return summary


def _write(out: Path, summary: Any, rows: list[dict[str, Any]], results: str | Path,
           formats: tuple[str, ...], dpi: int) -> None:
    from archself.reports.figures import shown_formats, write_figure

    names = [b["scenario"] for b in summary.scenarios]
    figures: dict[str, str | None] = {}
    faulted = [b["scenario"] for b in summary.scenarios if b["faulted"]]
    specs = [
        ("delays", lambda: fig.plot_delays(rows, faulted, title=True)),
        ("rms", lambda: fig.plot_errors(rows, names, "rms_error", summary.unit, title=True)),
        ("max", lambda: fig.plot_errors(rows, names, "max_error", summary.unit, title=True)),
        ("final", lambda: fig.plot_errors(rows, names, "final_error", summary.unit,
                                          title=True)),
        ("tau", lambda: (fig.plot_tau(summary.tau, title=True) if summary.tau is not None
                         else None)),
    ]
    shown, fmts = shown_formats(formats)
    for key, draw in specs:
        figure = draw()
        figures[key] = None if figure is None else f"{key}.{shown}"
        if figure is not None:
            write_figure(out, key, figure, fmts, dpi)
    doc = document(CampaignReportDoc, summary, complete=True)
    env = _environment()
    html = env.get_template("campaign_report.html.j2").render(
        s=doc,
        figures=figures,
        results_name=Path(results).name,
    )
    write_text(out / "index.html", html)
    write_text(
        out / "summary.json",
        json.dumps(doc, indent=2, ensure_ascii=False) + "\n",
    )
