"""Regenerate the per-seed tables of docs/hardening.md (runtime faults, issue 7 item 4).

Runs the diffdrive scenarios ``combined``, ``cascading`` and ``gps_dropout``
adaptively (``MapeK`` + ``simulate``) over seeds 0..N-1, plus the GPS faults on
the EKF (IMU drift puts the robot on a2, then the GPS drops out / freezes /
gives NaN from 90 s to 120 s; built in memory, as in
tests/test_hardening_runtime.py), and prints Markdown: switches (time, from → to,
action), final configuration, max error and the reason the runtime gave for
each unavailable module.

Usage::

    python bench/hardening_runtime.py [--seeds 10] [--jobs 2] [ARCH]
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ["combined", "cascading", "gps_dropout"]
GPS_KINDS = ["dropout", "stuck", "nan"]


def gps_variant(arch, kind: str):
    """``drift_then_gps_<kind>``: IMU drift from 10 s, a GPS fault from 90 s to 120 s."""
    data = arch.model_dump(by_alias=True)
    data["scenarios"][f"drift_then_gps_{kind}"] = {
        "description": f"IMU drift from 10 s, GPS {kind} 90-120 s",
        "duration_s": 170,
        "faults": [
            {
                "module": "imu",
                "kind": "bias_drift",
                "onset_s": 10,
                "magnitude": 7e-4,
                "signal": "heading",
            },
            {"module": "gps", "kind": kind, "onset_s": 90, "end_s": 120},
        ],
    }
    return type(arch).model_validate(data)


def run_one(job: tuple[str, str, int]) -> dict:
    from archself.model.loader import load_architecture
    from archself.runtime import MapeK
    from archself.sim.run import simulate

    path, scenario, seed = job
    arch = load_architecture(path).arch
    if scenario.startswith("drift_then_gps_"):
        arch = gps_variant(arch, scenario.rsplit("_", 1)[1])
    loop = MapeK(arch)
    res = simulate(arch, scenario, seed=seed, adapt=loop)
    reasons: dict[str, str] = {}
    for d in loop.decisions:
        for m, k in d.kappa.items():
            if not k["available"] and k.get("reason") and m not in reasons:
                reasons[m] = k["reason"].split(" for ")[0].split(" (")[0]
    return {
        "scenario": scenario,
        "seed": seed,
        "switches": [(s["t_s"], s["from"], s["to"], s["action"]) for s in res.switches],
        "final": res.final_configuration,
        "max_error": res.metrics["max_error_m"],
        "peak_t": res.metrics["peak_time_s"],
        "reasons": reasons,
    }


def _switches(rows: list) -> str:
    if not rows:
        return "none"
    return "; ".join(f"{f} → {to} at {t:g} s ({a})" for t, f, to, a in rows)


def table(results: list[dict]) -> str:
    out = [
        "| seed | switches (time, action) | final | max error (m) | at (s) "
        "| unavailable (reason) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for r in results:
        why = ", ".join(f"{m}: {w}" for m, w in sorted(r["reasons"].items())) or "—"
        out.append(
            f"| {r['seed']} | {_switches(r['switches'])} | {r['final']} | "
            f"{r['max_error']:.2f} | {r['peak_t']:.1f} | {why} |"
        )
    return "\n".join(out)


def summary(results: list[dict]) -> str:
    pats: dict[str, int] = {}
    for r in results:
        key = (
            " → ".join([r["switches"][0][1]] + [s[2] for s in r["switches"]])
            if r["switches"]
            else "none"
        )
        pats[key] = pats.get(key, 0) + 1
    errs = [r["max_error"] for r in results]
    seq = ", ".join(f"{k} on {n}/{len(results)}" for k, n in sorted(pats.items()))
    return f"Paths: {seq}; max error {min(errs):.2f}–{max(errs):.2f} m."


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("arch", nargs="?", default=str(ROOT / "architectures" / "diffdrive.yaml"))
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--variant-seeds", type=int, default=3)
    args = ap.parse_args(argv)
    jobs = [(args.arch, sc, s) for sc in SCENARIOS for s in range(args.seeds)]
    jobs += [
        (args.arch, f"drift_then_gps_{k}", s) for k in GPS_KINDS for s in range(args.variant_seeds)
    ]
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        results = list(ex.map(run_one, jobs))
    for sc in SCENARIOS + [f"drift_then_gps_{k}" for k in GPS_KINDS]:
        rows = [r for r in results if r["scenario"] == sc]
        print(f"### {sc}\n\n{table(rows)}\n\n{summary(rows)}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
