"""The robustness matrix of the diff-drive robot: noise levels, fault sizes, wheels and onsets.

A regenerable campaign (docs/robustness.md is its output): the shipped
``architectures/diffdrive.yaml`` (calibrated bands, disturbances on) is run
adaptively in

- **nominal** cells — no fault, at GPS noise 0.2/0.3/0.4 m, encoder noise 1×/2×/4×,
  IMU noise 1×/2×/4× (one factor at a time) and all three at their worst
  together: false switches per run;
- **IMU drift** cells — bias drift ¼×/1×/4× the shipped 7·10⁻⁴ rad/s from onsets
  2/50/300 s: switches to a configuration with the EKF (the one that compensates
  a heading drift), detection delay, max tracking error;
- **wheel loss** cells — 5/20/40/50 % effectiveness loss of the left or the right
  wheel from onsets 2/50/300 s: switches to a configuration with the asymmetric
  LQR;
- **worst noise with faults** — drift 1× and left-wheel 20 % at the all-worst noise.

The fault scenarios are added to a temporary copy of the file (``m_*``), so the
matrix needs nothing the file does not already declare. Everything runs through
:func:`archself.campaign.plan_campaign` / :func:`~archself.campaign.run_campaign`
(``--executor dask --address …`` for a cluster).

Usage::

    python bench/robustness.py                      # full matrix (≈1,500 runs)
    python bench/robustness.py --seeds 4 --nominal-seeds 10 --out /tmp/rob   # quick look
    python bench/robustness.py --markdown docs/robustness_table.md

The summary is printed and written as JSON (``--out``/summary.json); the Markdown
table (``--markdown``) is what docs/robustness.md shows.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from ruamel.yaml import YAML

ROOT = Path(__file__).resolve().parents[1]
ARCH = ROOT / "architectures" / "diffdrive.yaml"

DRIFT = 7.0e-4  # rad/s, the shipped imu_drift
DRIFT_FACTORS = (0.25, 1.0, 4.0)
LOSSES = (0.05, 0.2, 0.4, 0.5)
ONSETS = (2.0, 50.0, 300.0)
GPS = "modules.gps.params.noise_m.value"
ENC = "modules.encoders.params.noise_rad_s.value"
IMU = "modules.imu.params.noise_rad.value"


def matrix_file(src: Path, dst: Path) -> dict[str, Any]:
    """Copy ``src`` with the matrix's fault scenarios ``m_*`` added; returns the base noises."""
    yaml = YAML()
    data = yaml.load(src.read_text(encoding="utf-8"))
    sc = data["scenarios"]
    sc["m_nominal"] = {"duration_s": 400, "seed": 1}
    sc["m_drift"] = {
        "duration_s": 400,
        "seed": 1,
        "faults": [
            {"module": "imu", "kind": "bias_drift", "onset_s": 50.0, "magnitude": DRIFT,
             "signal": "heading"}
        ],
    }
    for side in ("left", "right"):
        sc[f"m_wheel_{side}"] = {
            "duration_s": 400,
            "seed": 1,
            "faults": [
                {"module": f"wheel_{side}", "kind": "effectiveness_loss", "onset_s": 50.0,
                 "magnitude": 0.2}
            ],
        }
    with dst.open("w", encoding="utf-8") as fh:
        yaml.dump(data, fh)
    mods = data["modules"]
    return {
        "gps": float(mods["gps"]["params"]["noise_m"]["value"]),
        "enc": float(mods["encoders"]["params"]["noise_rad_s"]["value"]),
        "imu": float(mods["imu"]["params"]["noise_rad"]["value"]),
    }


def cells(base: dict[str, float], seeds: int, nominal_seeds: int) -> list[dict[str, Any]]:
    """The campaigns of the matrix: name, scenario, sweep specs, seeds, expected module."""
    worst = [f"{GPS}=0.4", f"{ENC}={4 * base['enc']:g}", f"{IMU}={4 * base['imu']:g}"]
    out: list[dict[str, Any]] = [
        {"block": "nominal", "scenario": "m_nominal", "sweeps": [f"{GPS}=0.2,0.3,0.4"],
         "seeds": nominal_seeds, "expect": None},
        {"block": "nominal", "scenario": "m_nominal",
         "sweeps": [f"{ENC}={2 * base['enc']:g},{4 * base['enc']:g}"],
         "seeds": nominal_seeds, "expect": None},
        {"block": "nominal", "scenario": "m_nominal",
         "sweeps": [f"{IMU}={2 * base['imu']:g},{4 * base['imu']:g}"],
         "seeds": nominal_seeds, "expect": None},
        {"block": "nominal", "scenario": "m_nominal", "sweeps": worst,
         "seeds": nominal_seeds, "expect": None},
        {"block": "imu drift", "scenario": "m_drift",
         "sweeps": [
             "scenarios.m_drift.faults[0].magnitude="
             + ",".join(f"{DRIFT * f:g}" for f in DRIFT_FACTORS),
             "scenarios.m_drift.faults[0].onset_s=" + ",".join(f"{o:g}" for o in ONSETS),
         ],
         "seeds": seeds, "expect": "ekf"},
    ]
    for side in ("left", "right"):
        out.append(
            {"block": f"{side} wheel loss", "scenario": f"m_wheel_{side}",
             "sweeps": [
                 f"scenarios.m_wheel_{side}.faults[0].magnitude="
                 + ",".join(f"{m:g}" for m in LOSSES),
                 f"scenarios.m_wheel_{side}.faults[0].onset_s="
                 + ",".join(f"{o:g}" for o in ONSETS),
             ],
             "seeds": seeds, "expect": "asym_lqr"}
        )
    out.append({"block": "worst noise + drift", "scenario": "m_drift", "sweeps": worst,
                "seeds": seeds, "expect": "ekf"})
    out.append({"block": "worst noise + left wheel 20 %", "scenario": "m_wheel_left",
                "sweeps": worst, "seeds": seeds, "expect": "asym_lqr"})
    return out


def summarize(rows: list[dict[str, Any]], cell: dict[str, Any], arch: Any) -> list[dict]:
    """One summary line per sweep point of a campaign."""
    paths = [s.split("=", 1)[0] for s in cell["sweeps"]]
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(r[p] for p in paths), []).append(r)
    lines = []
    for point, rs in sorted(groups.items()):
        ok = [r for r in rs if r["error"] is None]
        errs = [float(r["max_error"]) for r in ok]
        line: dict[str, Any] = {
            "block": cell["block"],
            "setting": {p.split(".")[-2] if p.endswith(".value") else p.split(".")[-1]: v
                        for p, v in zip(paths, point, strict=True)},
            "runs": len(rs),
            "failed": len(rs) - len(ok),
            "false_switches": sum(int(r["false_switches"] or 0) for r in ok),
            "runs_with_false_switch": sum(1 for r in ok if (r["false_switches"] or 0) > 0),
            "max_error_mean": statistics.fmean(errs) if errs else math.nan,
            "max_error_sd": statistics.pstdev(errs) if len(errs) > 1 else 0.0,
            "max_error_worst": max(errs) if errs else math.nan,
            "updates": sum(int(r.get("n_updates") or 0) for r in ok),
        }
        if cell["expect"] is not None:
            want = cell["expect"]
            right = [
                r for r in ok
                if want in arch.configurations[r["final_configuration"]].modules
                and (r["false_switches"] or 0) == 0
            ]
            delays = [r["detection_delay_s"] for r in right if r["detection_delay_s"] is not None]
            line["right_switches"] = len(right)
            line["delay_median_s"] = statistics.median(delays) if delays else None
            line["paths"] = sorted({r["configuration_path"] for r in ok})
        lines.append(line)
    return lines


def markdown(summary: dict[str, Any]) -> str:
    """The table docs/robustness.md shows."""
    out = [
        f"Matrix of {summary['runs']} adaptive runs of `{summary['file']}` in "
        f"{summary['elapsed_s']:.0f} s on {summary['workers']} local workers.",
        "",
        "| block | setting | runs | right switch | runs with a false switch | "
        "max error mean ± sd [m] | worst [m] | median delay [s] |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for ln in summary["lines"]:
        setting = ", ".join(f"{k} {v:g}" for k, v in ln["setting"].items())
        right = "—" if "right_switches" not in ln else f"{ln['right_switches']}/{ln['runs']}"
        delay = ln.get("delay_median_s")
        out.append(
            f"| {ln['block']} | {setting} | {ln['runs']} | {right} | "
            f"{ln['runs_with_false_switch']}/{ln['runs']} | "
            f"{ln['max_error_mean']:.2f} ± {ln['max_error_sd']:.2f} | "
            f"{ln['max_error_worst']:.2f} | {'—' if delay is None else f'{delay:.1f}'} |"
        )
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", type=Path, default=ARCH)
    ap.add_argument("--seeds", type=int, default=20, help="seeds per fault cell")
    ap.add_argument("--nominal-seeds", type=int, default=100, help="seeds per nominal cell")
    ap.add_argument("--out", type=Path, default=Path("robustness-out"))
    ap.add_argument("--markdown", type=Path, default=None)
    ap.add_argument("--executor", default="local")
    ap.add_argument("--address", default=None)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--only", default=None, help="run only the blocks containing this word")
    args = ap.parse_args(argv)

    from archself.campaign import parse_sweep, plan_campaign, run_campaign
    from archself.campaign.results import read_results
    from archself.loader import load_architecture

    args.out.mkdir(parents=True, exist_ok=True)
    file = args.out / "matrix.yaml"
    base = matrix_file(args.arch, file)
    arch = load_architecture(file).arch
    lines: list[dict[str, Any]] = []
    runs = 0
    t0 = time.perf_counter()
    for k, cell in enumerate(cells(base, args.seeds, args.nominal_seeds)):
        if args.only and args.only not in cell["block"]:
            continue
        sweeps = [parse_sweep(s) for s in cell["sweeps"]]
        jobs, meta = plan_campaign(file, [cell["scenario"]], cell["seeds"], sweeps,
                                   modes=("adaptive",), yes=True)
        out = args.out / f"cell{k}.parquet"
        run_campaign(jobs, meta, out, executor=args.executor, workers=args.workers,
                     address=args.address, force=True)
        rows = read_results(out)[0].to_pylist()
        runs += len(rows)
        new = summarize(rows, cell, arch)
        lines += new
        for ln in new:
            print(json.dumps(ln), flush=True)
    summary = {
        "file": str(args.arch.relative_to(ROOT) if args.arch.is_relative_to(ROOT) else args.arch),
        "runs": runs,
        "elapsed_s": time.perf_counter() - t0,
        "workers": args.workers or "all",
        "lines": lines,
    }
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    table = markdown(summary)
    if args.markdown is not None:
        args.markdown.write_text(table, encoding="utf-8")
    sys.stdout.write(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
