"""Offline study: a faster IMU-drift detector for the diff-drive dead reckoning.

Records fixed a1 runs of ``architectures/diffdrive.yaml`` (dead reckoning + LQR, no
adaptation) and compares residual statistics on them at one false-alarm level:

- ``trend60`` — the shipped :class:`~archself_diffdrive.estimators.InnovationTrend`
  (2-D least-squares slope of the GPS innovation over 60 s / its standard error);
- ``glrW`` — the template-matched 1-parameter GLR of
  :class:`~archself_diffdrive.drift_glr.DriftGlr` over a window of W s: a heading ramp
  ``β = ḃ (s − t0)₊`` moves dead reckoning off by ``ḃ G(t; t0)``, G known from the
  odometry's own displacements; the offset is a nuisance, t0 unknown (max over a grid).

Every statistic goes through the loop's residual filter (first-order, τ = 2 s,
sampled every 0.5 s). The threshold of each is the 99 % quantile of the per-run
maximum over the nominal runs of the envelope's worst point (p = 0.01 false alarms
per 400 s run); the plain maximum over all nominal runs is reported beside it.

Result (50 nominal seeds per envelope point, 10 per drift cell): at the loop's margin
(1.55 × the 1 % threshold) ``glr120`` detects ¼× drifts 24–38 % earlier than
``trend60``, 1× drifts 0–13 % earlier (the worst-noise cell's worst run 21 %), 4×
drifts 8 % earlier; 19 % on the sum of the median delays. At 4× the GPS noise bounds
any statistic: even a known onset and offset would gain only ~14 %. ``glr120 walk`` (the
shipped test since the walk term): the per-run maximum's q99 is 3.9 at GPS 0.2 and at
0.4 m alike (``glr120``: 4.9 and 4.2), and the 1× delays at the 1 × threshold 4–8 %
shorter (50 against 54 s from 2 s; 63 against 67 s at the noisiest point).

Usage (about 1 s per run; one process)::

    nice -n 10 python bench/drift_detector.py record --out /tmp/drift --seeds 30 --drift-seeds 10
    python bench/drift_detector.py evaluate --out /tmp/drift --markdown drift.md
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from pathlib import Path

import numpy as np

ARCH = "architectures/diffdrive.yaml"
#: the noise envelope: GPS, encoder and IMU noise, lowest and highest
ENVELOPE = {
    "modules.gps.params.noise_m.value": (0.2, 0.4),
    "modules.encoders.params.noise_rad_s.value": (0.05, 0.2),
    "modules.imu.params.noise_rad.value": (0.005, 0.02),
}
DRIFT_RATE = 7.0e-4  # rad/s at 1×
FACTORS = (0.25, 1.0, 4.0)
ONSETS = (2.0, 50.0, 300.0)
PERIOD_S = 0.5  # the MAPE-K period
SMOOTHING_S = 2.0  # the residual filter's time constant
#: the loop alarms at nominal × (1 + threshold 0.55), nominal calibrated at the q99
LOOP_MARGIN = 1.55


# ---------------------------------------------------------------------------- record
def _record_run(arch, scenario: str, seed: int) -> dict[str, np.ndarray]:
    """One fixed a1 run: the fixes' innovations, the odometry's poses, true pose, reference."""
    import archself_diffdrive.estimators as est
    from archself.sim.run import simulate

    fixes: list[tuple[float, float, float]] = []
    steps: list[tuple[float, float, float]] = []
    samples: list[tuple[float, ...]] = []
    add, step = est.InnovationTrend.add, est.Odometry.step

    def record_add(self, t, ex, ey):
        fixes.append((t, ex, ey))
        return add(self, t, ex, ey)

    def record_step(self, t, dt, inputs):
        out = step(self, t, dt, inputs)
        steps.append((t, self.x, self.y))
        return out

    def sample(system):
        o = system.outputs
        true, ref = np.asarray(o["chassis"]["pose"]), np.asarray(o["planner"]["reference"])
        samples.append((system.t, *true[:2], *ref[:2]))

    est.InnovationTrend.add, est.Odometry.step = record_add, record_step
    try:
        simulate(arch, scenario, configuration="a1", seed=seed, adapt=sample)
    finally:
        est.InnovationTrend.add, est.Odometry.step = add, step
    return {"fixes": np.array(fixes), "steps": np.array(steps), "samples": np.array(samples)}


def record(out: Path, seeds: int, drift_seeds: int) -> None:
    """Record the nominal runs over the envelope and the drift runs into ``out`` (npz)."""
    from archself.campaign.sweep import apply_values, parse_sweep
    from archself.model.loader import load_architecture

    data = load_architecture(ARCH).data
    out.mkdir(parents=True, exist_ok=True)
    paths = list(ENVELOPE)
    for point in itertools.product(*ENVELOPE.values()):
        name = "nominal_" + "_".join(f"{v:g}" for v in point)
        if (out / f"{name}.npz").exists():
            continue
        sweeps = [parse_sweep(f"{p}={v}") for p, v in zip(paths, point, strict=True)]
        arch = apply_values(data, sweeps, point)
        runs = [_record_run(arch, "nominal", s) for s in range(1, seeds + 1)]
        _save(out / f"{name}.npz", runs)
        print(name, file=sys.stderr)
    fault = "scenarios.imu_drift.faults[0]"
    for factor, onset in itertools.product(FACTORS, ONSETS):
        name = f"drift_{factor:g}_{onset:g}"
        if (out / f"{name}.npz").exists():
            continue
        sweeps = [parse_sweep(f"{fault}.magnitude=1"), parse_sweep(f"{fault}.onset_s=1")]
        arch = apply_values(data, sweeps, [DRIFT_RATE * factor, onset])
        runs = [_record_run(arch, "imu_drift", s) for s in range(1, drift_seeds + 1)]
        _save(out / f"{name}.npz", runs)
        print(name, file=sys.stderr)
    worst = [parse_sweep(f"{p}={max(v)}") for p, v in ENVELOPE.items()]
    for factor in FACTORS:  # every noise at its highest, onset 50 s
        name = f"driftworst_{factor:g}_50"
        if (out / f"{name}.npz").exists():
            continue
        point = [max(v) for v in ENVELOPE.values()] + [DRIFT_RATE * factor, 50.0]
        sweeps = [parse_sweep(f"{fault}.magnitude=1"), parse_sweep(f"{fault}.onset_s=1")]
        arch = apply_values(data, worst + sweeps, point)
        runs = [_record_run(arch, "imu_drift", s) for s in range(1, drift_seeds + 1)]
        _save(out / f"{name}.npz", runs)
        print(name, file=sys.stderr)


def _save(path: Path, runs: list[dict[str, np.ndarray]]) -> None:
    arrays = {f"{k}_{i}": v for i, run in enumerate(runs) for k, v in run.items()}
    np.savez_compressed(path, n=len(runs), **arrays)


def load(path: Path) -> list[dict[str, np.ndarray]]:
    """The runs saved by :func:`record` in one file."""
    z = np.load(path)
    keys = ("fixes", "steps", "samples")
    return [{k: z[f"{k}_{i}"] for k in keys} for i in range(int(z["n"]))]


# ------------------------------------------------------------------------ statistics
def template_moves(fixes: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Per fix, the odometry's turned displacement since the previous fix: ΔD (2), ΔM (2).

    What :meth:`~archself_diffdrive.drift_glr.DriftGlr.move` accumulates, from the
    recorded odometry positions of every step.
    """
    s = steps[1:, 0]
    d = np.diff(steps[:, 1:3], axis=0)
    turned = np.stack([d[:, 1], -d[:, 0]], axis=1)
    j = np.searchsorted(fixes[:, 0], s, side="left")
    keep = j < len(fixes)
    j, s, turned = j[keep], s[keep], turned[keep]
    prev = np.where(j > 0, fixes[np.maximum(j - 1, 0), 0], 0.0)
    out = np.zeros((len(fixes), 4))
    np.add.at(out, j, np.concatenate([turned, (s - prev)[:, None] * turned], axis=1))
    return out


def trend_stat(t: np.ndarray, e: np.ndarray, window_s: float) -> np.ndarray:
    """The shipped ``InnovationTrend`` of R runs with common fix times ``t``: (R, F)."""
    out = np.full(e.shape[:2], math.nan)
    for k in range(len(t)):
        lo = int(np.searchsorted(t, t[k] - window_s, side="right"))
        n = k + 1 - lo
        if n < 5 or t[k] - t[lo] < 0.5 * window_s:
            continue
        tt = t[lo : k + 1] - t[lo : k + 1].mean()
        stt = tt @ tt
        w = e[:, lo : k + 1]
        d = np.diff(w, axis=1)
        var = (d * d).mean((1, 2)) / 2.0
        slope = np.einsum("j,rjc->rc", tt, w - w.mean(1, keepdims=True)) / stt
        out[:, k] = np.hypot(slope[:, 0], slope[:, 1]) / np.sqrt(var / stt)
    return out


def glr_stat(t, e, moved, window_s: float, min_span_s: float, min_support_s: float,
             walk: float = 0.0):
    """:class:`~archself_diffdrive.drift_glr.DriftWindows` at every fix of R runs: (R, F)."""
    from archself_diffdrive.drift_glr import DriftWindows

    r = e.shape[0]
    lanes = np.arange(r)
    w = DriftWindows(r, window_s, min_span_s, min_support_s, walk=walk)
    out = np.empty(e.shape[:2])
    for k in range(len(t)):
        w.add(float(t[k]), lanes, e[:, k], moved[:, k])
        out[:, k] = w.value(lanes)
    return out


def smoothed(t: np.ndarray, stat: np.ndarray, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """The loop's residual filter over ``stat`` sampled every 0.5 s: sample times, (R, S)."""
    ts = np.arange(PERIOD_S, duration + 1e-9, PERIOD_S)
    k = np.searchsorted(t, ts + 1e-9, side="right") - 1
    gain = 1.0 - math.exp(-PERIOD_S / SMOOTHING_S)
    y = np.zeros(stat.shape[0])
    out = np.zeros((stat.shape[0], len(ts)))
    for i, kk in enumerate(k):
        s = stat[:, kk] if kk >= 0 else np.full(stat.shape[0], math.nan)
        y = np.where(np.isfinite(s), y + gain * (s - y), y)
        out[:, i] = y
    return ts, out


#: the statistics compared: name -> function of (t, e, moved)
CANDIDATES = {
    "trend60 (shipped)": lambda t, e, m: trend_stat(t, e, 60.0),
    "glr60": lambda t, e, m: glr_stat(t, e, m, 60.0, 20.0, 5.0),
    "glr90": lambda t, e, m: glr_stat(t, e, m, 90.0, 20.0, 5.0),
    "glr120": lambda t, e, m: glr_stat(t, e, m, 120.0, 20.0, 5.0),
    "glr180": lambda t, e, m: glr_stat(t, e, m, 180.0, 20.0, 5.0),
    # with dead reckoning's random walk in the variance (the file's 0.005 m/√s)
    "glr120 walk": lambda t, e, m: glr_stat(t, e, m, 120.0, 20.0, 5.0, walk=0.005**2),
}


def _cell(runs: list[dict[str, np.ndarray]]):
    t = runs[0]["fixes"][:, 0]
    assert all(np.array_equal(r["fixes"][:, 0], t) for r in runs), "fix times differ"
    e = np.stack([r["fixes"][:, 1:] for r in runs])
    moved = np.stack([template_moves(r["fixes"], r["steps"]) for r in runs])
    return t, e, moved


def _gumbel_q(x: np.ndarray, p: float = 0.99) -> float:
    """The p-quantile of a Gumbel fitted to ``x`` by its moments."""
    beta = np.std(x, ddof=1) * math.sqrt(6.0) / math.pi
    mu = np.mean(x) - 0.5772156649 * beta
    return float(mu - beta * math.log(-math.log(p)))


def _delays(f: Path, cache: dict, name: str, threshold: float):
    """Delays (inf: missed), worst tracking error up to detection, runs alarmed before onset."""
    onset = float(f.stem.split("_")[2])
    ts, y = cache[f"{f.stem}|ts"], cache[f"{f.stem}|{name}"]
    after = ts >= onset
    hit = (y > threshold) & after[None, :]
    early = int(((y > threshold) & ~after[None, :]).any(1).sum())
    delays, errs = [], []
    for i, r in enumerate(load(f)):
        sm = r["samples"]
        td = ts[np.argmax(hit[i])] if hit[i].any() else math.inf
        delays.append(td - onset)
        upto = sm[:, 0] <= td
        errs.append(float(np.hypot(*(sm[upto, 1:3] - sm[upto, 3:5]).T).max()))
    return np.array(delays), max(errs), early


def evaluate(out: Path, markdown: Path | None) -> None:
    """Thresholds from the nominal runs, delays and errors of the drift runs; print tables."""
    cache: dict[str, dict[str, np.ndarray]] = {}
    files = sorted(out.glob("*.npz"))
    for f in files:
        runs = load(f)
        t, e, moved = _cell(runs)
        duration = float(runs[0]["steps"][-1, 0])
        for name, fn in CANDIDATES.items():
            ts, y = smoothed(t, fn(t, e, moved), duration)
            cache[f"{f.stem}|{name}"] = y
        cache[f"{f.stem}|ts"] = ts
        print(f.stem, file=sys.stderr)
    lines = ["## False alarms (per-run max of the smoothed statistic, nominal a1 runs)", ""]
    lines.append("| statistic | " + " | ".join(f.stem[8:] for f in files if "nominal" in f.stem)
                 + " | max of all | threshold (worst Gumbel q99) |")
    lines.append("| --- " * (len([f for f in files if "nominal" in f.stem]) + 3) + "|")
    thresholds = {}
    for name in CANDIDATES:
        qs, maxes = [], []
        for f in files:
            if "nominal" not in f.stem:
                continue
            m = cache[f"{f.stem}|{name}"].max(1)
            qs.append(_gumbel_q(m))
            maxes.append(m.max())
        thresholds[name] = max(qs)
        cells = " | ".join(f"{q:.2f} ({m:.2f})" for q, m in zip(qs, maxes, strict=True))
        lines.append(f"| {name} | {cells} | {max(maxes):.2f} | {max(qs):.2f} |")
    lines += ["", "Cells: Gumbel q99 (max) per envelope point (GPS m, encoders rad/s, IMU rad).",
              "Threshold: the worst point's q99 (p = 0.01 false alarms per 400 s run)."]
    drift = [f for f in files if "drift" in f.stem]
    for margin in (1.0, LOOP_MARGIN):
        lines += ["", f"## Detection delay [s] at {margin:g} × threshold: median / worst "
                  "(worst tracking error |true − reference| up to detection [m])", ""]
        head = " | ".join(f.stem[5:] for f in drift)
        lines.append(f"| statistic | {head} | sum of finite medians |")
        lines.append("| --- " * (len(drift) + 2) + "|")
        for name in CANDIDATES:
            row, total = [], 0.0
            for f in drift:
                d, err, early = _delays(f, cache, name, margin * thresholds[name])
                total += float(np.median(d)) if np.isfinite(np.median(d)) else 0.0
                note = f" [{early} early]" if early else ""
                row.append(f"{np.median(d):.0f} / {d.max():.0f} ({err:.2f}){note}")
            lines.append(f"| {name} | " + " | ".join(row) + f" | {total:.0f} |")
    text = "\n".join(lines)
    print(text)
    if markdown:
        markdown.write_text(text + "\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record", help="record the runs")
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--seeds", type=int, default=30, help="seeds per nominal envelope point")
    r.add_argument("--drift-seeds", type=int, default=10, help="seeds per drift cell")
    e = sub.add_parser("evaluate", help="compare the statistics on recorded runs")
    e.add_argument("--out", type=Path, required=True)
    e.add_argument("--markdown", type=Path)
    args = ap.parse_args(argv)
    if args.cmd == "record":
        record(args.out, args.seeds, args.drift_seeds)
    else:
        evaluate(args.out, args.markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
