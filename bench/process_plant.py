"""Per-seed results of the process-plant architecture, through the CLI.

For every scenario of ``architectures/process_plant.yaml`` and every seed, runs

    archself simulate architectures/process_plant.yaml --scenario S --seed K \\
        --compare --json --trace TMP/trace.json

(in-process, through the typer app, so exactly the CLI's code path), and prints
Markdown tables for docs/process_plant.md: the switches of the adaptive run (time,
configuration, action), the dominant channel of z at the first switch, and the
maximum level error of the fixed and the adaptive run.

Usage::

    python bench/process_plant.py [--seeds 20] [--jobs 4] [--scenario S ...] [ARCH]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_ARCH = ROOT / "architectures" / "process_plant.yaml"
SCENARIOS = ["nominal", "level_drift", "valve_loss", "valve_flicker", "drift_then_valve"]


def run_one(arch: str, scenario: str, seed: int) -> dict:
    """One seed of one scenario through ``archself simulate --compare --json --trace``."""
    from typer.testing import CliRunner

    from archself.cli import app

    with tempfile.TemporaryDirectory() as tmp:
        trace = Path(tmp) / "trace.json"
        args = [
            "simulate",
            arch,
            "--scenario",
            scenario,
            "--seed",
            str(seed),
            "--compare",
            "--json",
            "--trace",
            str(trace),
        ]
        res = CliRunner().invoke(app, args)
        if res.exit_code != 0:
            raise RuntimeError(f"{' '.join(args)} exited {res.exit_code}: {res.output}")
        fixed, adaptive = json.loads(res.stdout)["runs"]
        decisions = json.loads(trace.read_text())["decisions"]
    dominant = None
    if adaptive["switches"]:
        t0 = adaptive["switches"][0]["t_s"]
        rec = next((d for d in decisions if abs(d["t"] - t0) < 1e-6), None)
        if rec is not None and rec.get("z"):
            name, z = max(rec["z"].items(), key=lambda kv: abs(kv[1] or 0.0))
            dominant = (name, z)
    return {
        "scenario": scenario,
        "seed": seed,
        "fixed_max": fixed["metrics"]["max_error_m"],
        "adaptive_max": adaptive["metrics"]["max_error_m"],
        "final": adaptive["final_configuration"],
        "switches": adaptive["switches"],
        "updates": [
            {"t_s": d["t"], "action": d["chosen"]["action"]}
            for d in decisions
            if d.get("chosen") and d["chosen"].get("kind") == "parameter_update"
        ],
        "dominant": dominant,
    }


def _switch_text(r: dict) -> str:
    parts = [f"{s['t_s']:.0f} s → {s['to']} ({s['action']})" for s in r["switches"]]
    parts += [f"{u['t_s']:.0f} s update ({u['action']})" for u in r["updates"]]
    return "; ".join(sorted(parts, key=lambda p: float(p.split()[0]))) or "none"


def table(rows: list[dict]) -> str:
    """Markdown table of one scenario's seeds plus a summary line."""
    out = [
        "| seed | adaptive run: switches / updates | dominant z at 1st switch | "
        "max error fixed [m] | max error adaptive [m] |",
        "| ---: | --- | --- | ---: | ---: |",
    ]
    for r in rows:
        dom = f"{r['dominant'][0]} ({r['dominant'][1]:.1f})" if r["dominant"] else "–"
        out.append(
            f"| {r['seed']} | {_switch_text(r)} | {dom} | {r['fixed_max']:.3f} | "
            f"{r['adaptive_max']:.3f} |"
        )
    fx = [r["fixed_max"] for r in rows]
    ad = [r["adaptive_max"] for r in rows]
    t1 = [r["switches"][0]["t_s"] for r in rows if r["switches"]]
    finals = sorted({r["final"] for r in rows})
    when = f"first switch {min(t1):.0f}–{max(t1):.0f} s" if t1 else "no switch on any seed"
    out.append("")
    out.append(
        f"Summary over {len(rows)} seeds: {when}; final configuration {', '.join(finals)}; "
        f"max error fixed {min(fx):.3f}–{max(fx):.3f} m, adaptive {min(ad):.3f}–{max(ad):.3f} m."
    )
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("arch", nargs="?", default=str(DEFAULT_ARCH))
    ap.add_argument("--seeds", type=int, default=20, help="seeds 1..N (default 20)")
    ap.add_argument("--jobs", type=int, default=4)
    ap.add_argument("--scenario", action="append", help="only these scenarios")
    ns = ap.parse_args(argv)
    scenarios = ns.scenario or SCENARIOS
    jobs = [(ns.arch, s, k) for s in scenarios for k in range(1, ns.seeds + 1)]
    with ProcessPoolExecutor(max_workers=max(1, ns.jobs)) as pool:
        results = list(pool.map(run_one, *zip(*jobs, strict=True)))
    for s in scenarios:
        print(f"### {s}\n")
        print(table([r for r in results if r["scenario"] == s]))
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
