"""``archself simulate --report DIR`` and ``archself report --trace``: the HTML run report.

Writes into ``DIR`` (created if missing), each figure in every ``--format`` asked for
(``png`` by default; ``svg``, ``pdf``):

=====================  =======================================================
``index.html``         summary, figures, decision log (``templates/run_report.html.j2``)
``trajectory.<fmt>``   Fig. 2–4: actual against reference
``error.<fmt>``        Fig. 6: tracking error, fixed and/or adaptive, switches marked
``influence.<fmt>``    Fig. 5: |z_i| per cycle, τ, warm-up, switches, why cycles were
                       rejected (adaptive runs)
``qualities.<fmt>``    the quality attributes over time and the trade-off (a file
                       with ``qualities``)
``summary.json``       :meth:`archself.reports.run.RunReport.summary`, deterministic
=====================  =======================================================
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from archself.io.files import write_text
from archself.model.architecture import Architecture
from archself.reports.architecture import new_folder
from archself.reports.render import render
from archself.reports.run import RunReport, build_run_report
from archself.sim.result import metric_rows

__all__ = ["write_run_report"]


def write_run_report(arch: Architecture | None, results: list[Any], out_dir: str | Path,
                     formats: tuple[str, ...] = ("png",), dpi: int = 150) -> RunReport:
    """Write the run report of ``results`` (one run, or fixed + adaptive) into ``out_dir``.

    ``arch`` None takes the file's settings from the runs' ``meta`` (traces read back
    with :func:`archself.read_trace`). Each figure is written in every one of
    ``formats`` (``png``, ``svg``, ``pdf``; PNG at ``dpi``); the HTML shows the SVG if
    asked for, else the PNG (written too when neither is asked for).

    Raises
    ------
    OutputError
        If the folder or a file cannot be written (a folder it created is removed).
    """
    out = Path(out_dir)
    with new_folder(out):
        return _write(arch, results, out, formats, dpi)


def _write(arch: Architecture | None, results: list[Any], out: Path,
           formats: tuple[str, ...], dpi: int) -> RunReport:
    from archself.reports import figures

    rep = build_run_report(arch, results)
    shown, fmts = figures.shown_formats(formats)
    figs = [
        ("trajectory", "Trajectory against the reference (cf. paper Fig. 2–4)",
         f"{rep.objective['actual']} components {rep.objective['components']} against "
         f"{rep.objective['reference']}; dots mark architecture switches.",
         figures.plot_trajectory),
        ("error", "Tracking error, fixed versus adaptive (cf. paper Fig. 6)",
         "The objective error J_obs of each run; dashed green lines are architecture "
         "switches, dotted grey lines fault onsets.",
         figures.plot_error),
    ]
    if rep.adaptive is not None:
        figs.append((
            "influence", "Influence channels z with τ, warm-up and switches (cf. paper Fig. 5)",
            f"|z_i| of every module with a non-zero influence, per MAPE-K cycle "
            f"(every {rep.period_s:g} s); candidates: {rep.selector}. Gaps: module inactive.",
            figures.plot_influence))
    if rep.qualities is not None:
        figs.append((
            "qualities", "Quality attributes over time and the trade-off",
            "Left: each attribute's utility and the weighted utility U of the configuration "
            "each run was in (preferences as weights). Right: the configurations at their "
            "attribute values, labelled with U, and the path the adaptive run took.",
            figures.plot_qualities))
    for stem, _title, _caption, plot in figs:
        figures.write_figure(out, stem, plot(rep, title=True), fmts, dpi)
    write_text(out / "summary.json",
               json.dumps(rep.summary(), indent=2, ensure_ascii=False, sort_keys=True) + "\n")
    write_text(out / "index.html", render(
        "run_report.html.j2", rep=rep,
        figures=[{"file": f"{stem}.{shown}", "title": t, "caption": c,
                  "others": [f"{stem}.{x}" for x in fmts if x != shown]}
                 for stem, t, c, _ in figs],
        metric_rows=[(label, key, f"%.{d}f") for label, key, d in metric_rows(rep.unit)],
    ))
    return rep
