"""Regenerate the calibration tables of docs/calibration.md.

Runs every (scenario, configuration) pair of the calibration fixed, over seeds
1..N, and prints Markdown: the tracking-error metrics (mean and worst over the
seeds) and the residual-signal levels the adaptive runtime's thresholds rest on.

Usage::

    python bench/calibration.py [--seeds 20] [--jobs 2] [ARCH]
"""

from __future__ import annotations

import argparse
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

CASES = [
    ("nominal", "a1"),
    ("imu_drift", "a1"),
    ("actuator_fault", "a1"),
    ("imu_drift", "a2"),
    ("actuator_fault", "a3"),
    ("nominal", "a2"),
    ("nominal", "a3"),
]
PROBE_T = (40.0, 55.0, 70.0, 100.0)


def _smooth(x: np.ndarray, tau: float, dt: float) -> np.ndarray:
    """First-order low-pass, NaN-tolerant, like the runtime's residual filter."""
    a = 1.0 if tau <= 0 else 1.0 - math.exp(-dt / tau)
    y = np.full_like(x, np.nan)
    acc = math.nan
    for i, v in enumerate(x.tolist()):
        if v == v:
            acc = v if acc != acc else acc + a * (v - acc)
        y[i] = acc
    return y


def _one(args: tuple[str, str, str, int]) -> dict:
    from archself.model.loader import load_architecture
    from archself.sim.run import simulate

    path, scenario, conf, seed = args
    arch = load_architecture(path).arch
    res = simulate(arch, scenario, configuration=conf, seed=seed)
    s = res.series
    t = s["t"]
    dt = float(arch.runtime.step_s)
    levels = {}
    for name, spec in arch.modules.items():
        key = f"residual.{name}"
        if spec.residual is None or key not in s or not np.isfinite(s[key]).any():
            continue
        raw = s[key]
        sm = _smooth(raw, spec.residual.smoothing_s, dt)
        late = t >= 25.0
        levels[name] = {
            "raw_mean": float(np.nanmean(raw[late])),
            "smooth_max": float(np.nanmax(sm[late])),
            "at": [float(sm[min(len(t) - 1, int(round(p / dt)) - 1)]) for p in PROBE_T],
        }
    return {
        "scenario": scenario,
        "conf": conf,
        "seed": seed,
        "metrics": res.metrics,
        "levels": levels,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "arch",
        nargs="?",
        default=str(Path(__file__).resolve().parents[1] / "architectures" / "diffdrive.yaml"),
    )
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    ns = ap.parse_args(argv)
    jobs = [(ns.arch, sc, c, seed) for sc, c in CASES for seed in range(1, ns.seeds + 1)]
    with ProcessPoolExecutor(max_workers=ns.jobs) as ex:
        results = list(ex.map(_one, jobs))
    print(f"Tracking error over seeds 1..{ns.seeds} (fixed architecture; m, s)\n")
    print(
        "| scenario | config | max error mean | max error worst | peak time mean "
        "| final error mean | final worst | RMS mean |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for sc, c in CASES:
        rs = [r for r in results if r["scenario"] == sc and r["conf"] == c]
        m = {k: np.array([r["metrics"][k] for r in rs]) for k in rs[0]["metrics"]}
        print(
            f"| {sc} | {c} | {m['max_error_m'].mean():.2f} | {m['max_error_m'].max():.2f} "
            f"| {m['peak_time_s'].mean():.0f} | {m['final_error_m'].mean():.2f} "
            f"| {m['final_error_m'].max():.2f} | {m['rms_error_m'].mean():.2f} |"
        )
    print(
        "\nResidual signals (raw mean after 25 s; max of the smoothed signal after 25 s, "
        "mean/worst over seeds; smoothed value at t = "
        + ", ".join(f"{p:.0f}" for p in PROBE_T)
        + " s, mean [min])\n"
    )
    print("| scenario | config | module | raw mean | smoothed max (mean / worst) | smoothed at t |")
    print("|---|---|---|---|---|---|")
    for sc, c in CASES:
        rs = [r for r in results if r["scenario"] == sc and r["conf"] == c]
        for mod in rs[0]["levels"]:
            raw = np.array([r["levels"][mod]["raw_mean"] for r in rs])
            smx = np.array([r["levels"][mod]["smooth_max"] for r in rs])
            at = np.array([r["levels"][mod]["at"] for r in rs])
            pairs = zip(at.mean(0), at.min(0), strict=True)
            at_s = " / ".join(f"{a:.3g} [{b:.3g}]" for a, b in pairs)
            print(
                f"| {sc} | {c} | {mod} | {raw.mean():.3g} | {smx.mean():.3g} / {smx.max():.3g} "
                f"| {at_s} |"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
