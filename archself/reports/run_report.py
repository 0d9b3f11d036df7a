"""``archself simulate --report DIR``: the HTML run report with the paper's figures.

Writes into ``DIR`` (created if missing):

==================  ==========================================================
``index.html``      summary, figures, decision log (``templates/run_report.html.j2``)
``trajectory.png``  Fig. 2–4: actual against reference
``error.png``       Fig. 6: tracking error, fixed and/or adaptive, switches marked
``influence.png``   Fig. 5: |z_i| per cycle, τ, warm-up, switches (adaptive runs)
``summary.json``    :meth:`archself.reports.run.RunReport.summary`, deterministic
==================  ==========================================================
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from archself.atomic import write_bytes, write_text
from archself.model import Architecture
from archself.reports.architecture import ensure_dir
from archself.reports.render import render
from archself.reports.run import RunReport, build_run_report

__all__ = ["write_run_report"]


def write_run_report(arch: Architecture, results: list[Any], out_dir: str | Path) -> RunReport:
    """Write the run report of ``results`` (one run, or fixed + adaptive) into ``out_dir``.

    Raises
    ------
    OutputError
        If the folder or a file cannot be written.
    """
    from archself.reports import figures
    from archself.sim.run import metric_rows

    out = Path(out_dir)
    ensure_dir(out)
    rep = build_run_report(arch, results)
    figs = [
        ("trajectory.png", "Trajectory against the reference (cf. paper Fig. 2–4)",
         f"{rep.objective['actual']} components {rep.objective['components']} against "
         f"{rep.objective['reference']}; dots mark architecture switches.",
         figures.trajectory_figure(rep)),
        ("error.png", "Tracking error, fixed versus adaptive (cf. paper Fig. 6)",
         "The objective error J_obs of each run; dashed green lines are architecture "
         "switches, dotted grey lines fault onsets.",
         figures.error_figure(rep)),
    ]
    if rep.adaptive is not None:
        figs.append((
            "influence.png", "Influence channels z with τ, warm-up and switches (cf. paper Fig. 5)",
            f"|z_i| of every module with a non-zero influence, per MAPE-K cycle "
            f"(every {rep.period_s:g} s); candidates: {rep.selector}. Gaps: module inactive.",
            figures.influence_figure(rep)))
    for name, _title, _caption, data in figs:
        write_bytes(out / name, data)
    write_text(out / "summary.json",
               json.dumps(rep.summary(), indent=2, ensure_ascii=False, sort_keys=True) + "\n")
    write_text(out / "index.html", render(
        "run_report.html.j2", rep=rep,
        figures=[{"file": f, "title": t, "caption": c} for f, t, c, _ in figs],
        metric_rows=[(label, key, f"%.{d}f") for label, key, d in metric_rows(rep.unit)],
    ))
    return rep
