"""The robustness matrix of a shipped system: noise levels, fault sizes and onsets.

A regenerable campaign (docs/robustness.md shows its output) of the shipped file
(calibrated bands, disturbances on), run adaptively in

- **nominal** cells — no fault, each noise parameter of :data:`SYSTEMS` at 1×–4× of
  its file value (one at a time) and all at their worst together: runs with a false
  switch;
- **fault** cells — each fault at ¼×–4× its shipped size (or a list of sizes), from
  early, middle and late onsets: right switches (a configuration holding the module
  that compensates the fault, no switch before the onset), detection delay, mean, spread
  and worst of the max tracking error;
- **worst noise with faults** — each fault at its shipped size at the worst noise.

The diff-drive robot: GPS 0.2/0.3/0.4 m, encoders and IMU 2×/4×; IMU drift ¼×/1×/4× of
7·10⁻⁴ rad/s; 5/20/40/50 % loss of either wheel; onsets 0/2/50/300 s (0: a fault present
at start-up). The tank: both level transmitters and the flow meter 2×/4×; transmitter
drift ¼×/1×/4× of 0.5 mm/s; 10/25/40/60 % valve loss; onsets 2/150/400 s. The DC-motor
drive (built from the generic blocks, written without knowledge of this matrix):
tachogenerator, encoder and voltage meter 2×/4×; tacho drift ¼×/1×/4× of 0.05 rad/s²;
10/25/40/60 % loss of drive A; onsets 2/50/120 s.

The fault scenarios are added to a temporary copy of the file (``m_*``), so the matrix
needs nothing the file does not already declare. Its seeds are children of
``SeedSequence(1)`` (``--root-seed``); ``archself calibrate`` draws from
``SeedSequence(0)``, so no nominal run of the matrix is one the bands were fitted to.
Everything runs through :func:`archself.campaign.plan_campaign` /
:func:`~archself.campaign.run_campaign` (``--executor dask --address …`` for a cluster).

Usage::

    python bench/robustness.py --system diffdrive --markdown docs/robustness_diffdrive.md
    python bench/robustness.py --system process_plant --markdown docs/robustness_plant.md
    python bench/robustness.py --seeds 3 --nominal-seeds 5 --out /tmp/rob   # quick look

The summary is printed and written as JSON (``--out``/summary.json); the Markdown table
(``--markdown``) is what docs/robustness.md includes.
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

#: The matrix of each shipped system: its noise parameters (1× is the file's value), the
#: faults (module, kind, shipped magnitude, factors, signal), the onsets, and which module a
#: configuration must hold to compensate each fault (the "right switch").
SYSTEMS: dict[str, dict[str, Any]] = {
    "diffdrive": {
        "file": "architectures/diffdrive.yaml",
        "duration_s": 400,
        "noise": {
            "gps": ("modules.gps.params.noise_m.value", (1.0, 1.5, 2.0)),  # 0.2, 0.3, 0.4 m
            "encoders": ("modules.encoders.params.noise_rad_s.value", (2.0, 4.0)),
            "imu": ("modules.imu.params.noise_rad.value", (2.0, 4.0)),
        },
        "faults": {
            "imu drift": {"module": "imu", "kind": "bias_drift", "magnitude": 7.0e-4,
                          "signal": "heading", "factors": (0.25, 1.0, 4.0), "expect": "ekf"},
            "left wheel loss": {"module": "wheel_left", "kind": "effectiveness_loss",
                                "values": (0.05, 0.2, 0.4, 0.5), "expect": "asym_lqr"},
            "right wheel loss": {"module": "wheel_right", "kind": "effectiveness_loss",
                                 "values": (0.05, 0.2, 0.4, 0.5), "expect": "asym_lqr"},
        },
        "onsets": (0.0, 2.0, 50.0, 300.0),
        "worst_faults": {"imu drift": 7.0e-4, "left wheel loss": 0.2},
    },
    "process_plant": {
        "file": "architectures/process_plant.yaml",
        "duration_s": 600,
        "noise": {
            "level_a": ("modules.level_a.params.noise_m.value", (2.0, 4.0)),
            "level_b": ("modules.level_b.params.noise_m.value", (2.0, 4.0)),
            "flow_meter": ("modules.flow_meter.params.noise_m3_s.value", (2.0, 4.0)),
        },
        "faults": {
            "level drift": {"module": "level_a", "kind": "bias_drift", "magnitude": 5.0e-4,
                            "signal": "level_measured", "factors": (0.25, 1.0, 4.0),
                            "expect": "observer_b"},
            "valve loss": {"module": "valve", "kind": "effectiveness_loss", "signal": "inflow",
                           "values": (0.1, 0.25, 0.4, 0.6), "expect": "ff_pi"},
        },
        "onsets": (2.0, 150.0, 400.0),
        "worst_faults": {"level drift": 5.0e-4, "valve loss": 0.4},
    },
    # the third example, built from the generic blocks only: the matrix was not known
    # when it was written and calibrated
    "motor_drive": {
        "file": "architectures/motor_drive.yaml",
        "duration_s": 200,
        "noise": {
            "tacho": ("modules.tacho.params.noise.value", (2.0, 4.0)),
            "encoder": ("modules.encoder.params.noise.value", (2.0, 4.0)),
            "volt_meter": ("modules.volt_meter.params.noise.value", (2.0, 4.0)),
        },
        "faults": {
            "tacho drift": {"module": "tacho", "kind": "bias_drift", "magnitude": 0.05,
                            "signal": "measurement", "factors": (0.25, 1.0, 4.0),
                            "expect": "kf_encoder"},
            "drive loss": {"module": "drive_a", "kind": "effectiveness_loss", "signal": "u",
                           "values": (0.1, 0.25, 0.4, 0.6), "expect": "drive_b"},
        },
        "onsets": (2.0, 50.0, 120.0),
        "worst_faults": {"tacho drift": 0.05, "drive loss": 0.4},
    },
}


def _slug(name: str) -> str:
    return "m_" + name.replace(" ", "_")


def matrix_file(system: dict[str, Any], src: Path, dst: Path) -> dict[str, float]:
    """Copy ``src`` with the matrix's scenarios ``m_*`` added; returns the 1× noise values."""
    yaml = YAML()
    data = yaml.load(src.read_text(encoding="utf-8"))
    sc = data["scenarios"]
    dur = system["duration_s"]
    sc["m_nominal"] = {"duration_s": dur, "seed": 1}
    for name, f in system["faults"].items():
        fault = {"module": f["module"], "kind": f["kind"], "onset_s": 50.0,
                 "magnitude": f.get("magnitude", f.get("values", (0.0,))[0])}
        if f.get("signal"):
            fault["signal"] = f["signal"]
        sc[_slug(name)] = {"duration_s": dur, "seed": 1, "faults": [fault]}
    with dst.open("w", encoding="utf-8") as fh:
        yaml.dump(data, fh)

    def value(path: str) -> float:
        cur: Any = data
        for key in path.split("."):
            cur = cur[key]
        return float(cur)

    return {k: value(path) for k, (path, _) in system["noise"].items()}


def cells(system: dict[str, Any], base: dict[str, float], seeds: int, nominal_seeds: int
          ) -> list[dict[str, Any]]:
    """The campaigns of the matrix: block, scenario, sweep specs, seeds, expected module."""
    noise = system["noise"]
    out: list[dict[str, Any]] = []
    for k, (path, factors) in noise.items():
        vals = ",".join(f"{base[k] * f:g}" for f in factors)
        out.append({"block": "nominal", "scenario": "m_nominal", "sweeps": [f"{path}={vals}"],
                    "seeds": nominal_seeds, "expect": None})
    worst = [f"{path}={base[k] * max(factors):g}" for k, (path, factors) in noise.items()]
    out.append({"block": "nominal, all noises worst", "scenario": "m_nominal", "sweeps": worst,
                "seeds": nominal_seeds, "expect": None})
    onsets = ",".join(f"{o:g}" for o in system["onsets"])
    for name, f in system["faults"].items():
        slug = _slug(name)
        values = f.get("values") or tuple(f["magnitude"] * x for x in f["factors"])
        out.append({
            "block": name, "scenario": slug, "expect": f["expect"], "seeds": seeds,
            "sweeps": [
                f"scenarios.{slug}.faults[0].magnitude=" + ",".join(f"{v:g}" for v in values),
                f"scenarios.{slug}.faults[0].onset_s={onsets}",
            ],
        })
    for name, magnitude in system["worst_faults"].items():
        slug = _slug(name)
        out.append({"block": f"all noises worst + {name}", "scenario": slug,
                    "expect": system["faults"][name]["expect"], "seeds": seeds,
                    "sweeps": worst + [f"scenarios.{slug}.faults[0].magnitude={magnitude:g}"]})
    return out


def _label(path: str) -> str:
    """``modules.gps.params.noise_m.value`` -> ``gps.noise_m``; a fault's field by its name."""
    parts = path.split(".")
    if parts[0] == "modules" and len(parts) >= 4:
        return f"{parts[1]}.{parts[3]}"
    return parts[-1]


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
            "setting": {_label(p): v for p, v in zip(paths, point, strict=True)},
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
        f"{summary['elapsed_s']:.0f} s on {summary['workers']} local workers "
        f"(root seed {summary.get('root_seed', 0)}).",
        "",
        "| block | setting | runs | right switch | runs with a false switch | "
        f"max error mean ± sd [{summary['unit']}] | worst [{summary['unit']}] | "
        "median delay [s] |",
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
    ap.add_argument("--system", choices=sorted(SYSTEMS), default="diffdrive")
    ap.add_argument("--arch", type=Path, default=None, help="default: the system's file")
    ap.add_argument("--seeds", type=int, default=20, help="seeds per fault cell")
    ap.add_argument("--nominal-seeds", type=int, default=100, help="seeds per nominal cell")
    ap.add_argument("--out", type=Path, default=Path("robustness-out"))
    ap.add_argument("--markdown", type=Path, default=None)
    ap.add_argument("--executor", default="local")
    ap.add_argument("--address", default=None)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--only", default=None, help="run only the blocks containing this word")
    ap.add_argument("--root-seed", type=int, default=1,
                    help="root of the seed sequence (default 1: `archself calibrate` uses 0, "
                         "so the nominal cells are runs the bands were not fitted to)")
    args = ap.parse_args(argv)

    from archself.campaign import parse_sweep, plan_campaign, run_campaign
    from archself.campaign.results import read_results
    from archself.model.loader import load_architecture

    system = SYSTEMS[args.system]
    if args.arch is None:
        args.arch = ROOT / system["file"]
    args.out.mkdir(parents=True, exist_ok=True)
    file = args.out / "matrix.yaml"
    base = matrix_file(system, args.arch, file)
    arch = load_architecture(file).arch
    lines: list[dict[str, Any]] = []
    runs = 0
    t0 = time.perf_counter()
    for k, cell in enumerate(cells(system, base, args.seeds, args.nominal_seeds)):
        if args.only and args.only not in cell["block"]:
            continue
        sweeps = [parse_sweep(s) for s in cell["sweeps"]]
        jobs, meta = plan_campaign(file, [cell["scenario"]], cell["seeds"], sweeps,
                                   modes=("adaptive",), root_seed=args.root_seed, yes=True)
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
        "root_seed": args.root_seed,
        "unit": arch.runtime.objective.unit or "",
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
