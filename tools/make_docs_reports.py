#!/usr/bin/env python3
"""Regenerate docs/reports/: the diffdrive architecture report and the three scenarios' run reports.

    python tools/make_docs_reports.py            # writes docs/reports/
    python tools/make_docs_reports.py --out DIR  # somewhere else (the docs test does this)

Equivalent to::

    A=architectures/diffdrive.yaml; R=docs/reports
    archself report $A -o $R/diffdrive
    archself simulate $A -s nominal --compare --report $R/runs/nominal
    archself simulate $A -s imu_drift --compare --report $R/runs/imu_drift
    archself simulate $A -s actuator_fault --compare --report $R/runs/actuator_fault

plus docs/reports/README.md (``templates/docs_reports.md.j2``). The report folders are
emptied first so that no stale file survives. Text outputs (DSM CSV/Markdown, DOT,
summary.json, README.md) are deterministic; tests/test_reports_docs.py checks that the
committed ones are current.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ARCH = ROOT / "architectures" / "diffdrive.yaml"
SCENARIOS = ("nominal", "imu_drift", "actuator_fault")


def build(
    out: Path, *, runs: bool = True, render: bool = True, arch_path: Path = ARCH
) -> list[Path]:
    """Write the docs reports under ``out``; return the report folders written."""
    from archself.io.files import write_text
    from archself.model.loader import load_architecture
    from archself.reports.architecture import write_architecture_report
    from archself.reports.render import render as render_template
    from archself.reports.render import unique_slugs
    from archself.reports.run_report import write_run_report
    from archself.runtime import MapeK
    from archself.sim.run import simulate

    arch = load_architecture(arch_path).arch
    out.mkdir(parents=True, exist_ok=True)
    folders = [out / "diffdrive"] + ([out / "runs" / s for s in SCENARIOS] if runs else [])
    for f in folders:
        if f.exists():
            shutil.rmtree(f)
    write_architecture_report(arch, out / "diffdrive", dot=render)
    summaries = []
    if runs:
        for sc in SCENARIOS:
            results = [simulate(arch, sc), simulate(arch, sc, adapt=MapeK(arch))]
            rep = write_run_report(arch, results, out / "runs" / sc)
            summaries.append(rep.summary())
        write_text(out / "README.md", render_template(
            "docs_reports.md.j2", arch=arch, summaries=summaries,
            confs=list(unique_slugs(list(arch.configurations)).items())))
    return folders


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "reports")
    ap.add_argument("--no-render", action="store_true", help="DOT only (no SVG/PNG)")
    ap.add_argument("--arch", type=Path, default=ARCH, help="the diffdrive file")
    args = ap.parse_args()
    for f in build(args.out, render=not args.no_render, arch_path=args.arch):
        print(f)


if __name__ == "__main__":
    main()
