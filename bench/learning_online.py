"""Online bands and W (runtime.online) over seeds: a mis-set band corrected, and how it fails.

Cases on architectures/process_plant.yaml (docs/learning.md, "Online W and bands"):

- ``tight``: every band (``residual.nominal``) set to ``--factor`` (0.4) of the file's,
  scenario ``valve_loss`` (the valve clogs at 150 s): false alarms and false actions
  before the fault, then the fault. Runs: ``off`` (the tight bands kept) and ``bands``
  (runtime.online.bands on, ``windows`` 5 of 20 s, an update every 20 s).
- ``drift``: the file's bands, scenario ``level_drift`` made slower and later
  (transmitter A drifts at 0.05 mm/s from 300 s): the plant changes inside windows
  judged nominal (J still acceptable), so the drift is learned as noise. Runs: ``off``,
  ``bands`` (the default bounds: ×1.5 per update, ×2 in total) and ``unbounded``
  (×100 and ×100): how far the drift widens the bands, and what the bounds keep.
- ``weights``: ``valve_loss`` with runtime.online.weights on: accepted and rejected
  updates (the run's own fluctuations rarely fit W; the rejections keep it).

Per run: false-alarm cycles (a candidate before the onset), actions before the onset,
the first action after the onset (s after it), worst and RMS J after the onset, and
the band/weight updates (accepted, rejected, the last value of each band / declared).

Usage::

    python bench/learning_online.py --seeds 10 [-o results.json]
"""

from __future__ import annotations

import argparse
import copy
import json
import sys

import numpy as np

from archself.model.architecture import Architecture, Online
from archself.model.loader import load_architecture
from archself.resources import data_dir
from archself.runtime import MapeK
from archself.sim.run import simulate

BANDS = {"enabled": True, "window_s": 20.0, "every_s": 20.0}  # 10 windows (the default)
DRIFT = (300.0, 5.0e-5)  # onset (s), drift (m/s): the drift case


def variant(arch: Architecture, factor: float = 1.0, bands: dict | None = None,
            weights: dict | None = None) -> Architecture:
    """A copy of ``arch`` with its bands scaled by ``factor`` and runtime.online set.

    A deep copy, not a round trip through ``model_dump``: the dump loses the edges'
    named ports (observer_a's cross-check input).
    """
    out = copy.deepcopy(arch)
    for m in out.modules.values():
        if m.residual is not None:
            m.residual.nominal *= factor
    out.runtime.online = Online.model_validate({"bands": bands or {}, "weights": weights or {}})
    return out


def measure(arch: Architecture, scenario: str, seed: int) -> dict:
    """One adaptive run and its figures."""
    loop = MapeK(arch)
    res = simulate(arch, scenario, seed=seed, adapt=loop)
    onset = min((f.onset_s for f in arch.scenarios[scenario].faults), default=np.inf)
    t = np.asarray(res.series["t"], dtype=float)
    j = np.asarray(res.series["J"], dtype=float)
    after = t >= onset
    acts = [(d.t, d.chosen["action"]) for d in loop.decisions if d.chosen]
    first = next((ta - onset for ta, _ in acts if ta >= onset), np.inf)
    events = loop.online.events if loop.online is not None else []
    last = {}
    for e in events:
        if e["kind"] == "bands" and e["outcome"] == "accepted":
            last[e["what"]] = e["new"]
    declared = {n: m.residual.nominal for n, m in arch.modules.items() if m.residual}
    cand = [d.t for d in loop.decisions if d.candidates and d.t < onset]
    third = float(arch.scenarios[scenario].duration_s) / 3
    return {
        "false_alarm_cycles": len(cand),
        "thirds": [sum(1 for t in cand if k * third <= t < (k + 1) * third) for k in range(3)],
        "actions_before": sum(1 for ta, _ in acts if ta < onset),
        "first_action_s": float(first),
        "worst": float(np.nanmax(j[after])) if after.any() else float("nan"),
        "rms": float(np.sqrt(np.nanmean(j[after] ** 2))) if after.any() else float("nan"),
        "accepted": sum(1 for e in events if e["outcome"] == "accepted"),
        "rejected": sum(1 for e in events if e["outcome"] == "rejected"),
        "band_ratio": {n: v / declared[n] for n, v in last.items()},
    }


def drift(arch: Architecture) -> Architecture:
    """``level_drift`` slower and later: 0.05 mm/s from 300 s, after the bands have learned."""
    fault = arch.scenarios["level_drift"].faults[0]
    fault.onset_s, fault.magnitude = DRIFT
    return arch


def cases(arch: Architecture, factor: float) -> dict[str, tuple[Architecture, str]]:
    loose = dict(BANDS, max_step=100.0, max_factor=100.0)
    return {
        "tight/off": (variant(arch, factor), "nominal"),
        "tight/bands": (variant(arch, factor, bands=BANDS), "nominal"),
        "tight-fault/off": (variant(arch, factor), "valve_loss"),
        "tight-fault/bands": (variant(arch, factor, bands=BANDS), "valve_loss"),
        "drift/off": (drift(variant(arch)), "level_drift"),
        "drift/bands": (drift(variant(arch, bands=BANDS)), "level_drift"),
        "drift/unbounded": (drift(variant(arch, bands=loose)), "level_drift"),
        "weights/on": (variant(arch, 1.0, weights={"enabled": True}), "valve_loss"),
    }


def _q(v: list[float], fmt: str = "{:.3g}") -> str:
    a = np.asarray(v, dtype=float)
    fin = a[np.isfinite(a)]
    if not fin.size:
        return "—"
    s = f"{fmt.format(np.median(fin))} [{fmt.format(fin.min())}, {fmt.format(fin.max())}]"
    return s if fin.size == a.size else f"{s} ({a.size - fin.size} none)"


def summary(rows: dict[str, list[dict]]) -> str:
    head = ("| case | false-alarm cycles | actions before onset | first action after onset "
            "(s) | worst J after (m) | RMS J after (m) | updates accepted / rejected |")
    lines = [head, "| --- | --- | --- | --- | --- | --- | --- |"]
    for name, runs in rows.items():
        col = {k: [r[k] for r in runs] for k in runs[0] if k not in ("band_ratio", "thirds")}
        lines.append(
            f"| {name} | {_q(col['false_alarm_cycles'], '{:.0f}')} | "
            f"{_q(col['actions_before'], '{:.0f}')} | {_q(col['first_action_s'], '{:.0f}')} | "
            f"{_q(col['worst'])} | {_q(col['rms'])} | {np.sum(col['accepted']):.0f} / "
            f"{np.sum(col['rejected']):.0f} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--factor", type=float, default=0.4)
    ap.add_argument("--only", help="run only the cases starting with this")
    ap.add_argument("-o", "--output")
    a = ap.parse_args()
    arch = load_architecture(data_dir("architectures") / "process_plant.yaml").arch
    rows: dict[str, list[dict]] = {}
    for name, (variant_arch, scen) in cases(arch, a.factor).items():
        if a.only and not name.startswith(a.only):
            continue
        rows[name] = [measure(variant_arch, scen, s) for s in range(1, a.seeds + 1)]
        print(name, "done", file=sys.stderr)
    print(summary(rows))
    for name, runs in rows.items():
        ratios: dict[str, list[float]] = {}
        for r in runs:
            for n, v in r["band_ratio"].items():
                ratios.setdefault(n, []).append(v)
        thirds = np.array([r["thirds"] for r in runs])
        print(f"{name}: false-alarm cycles per third of the run, median [min, max]: " + ", ".join(
            _q(list(thirds[:, k]), "{:.0f}") for k in range(3)))
        if ratios:
            print(f"{name}: last band / declared: " + ", ".join(
                f"{n} {_q(v, '{:.2f}')}" for n, v in sorted(ratios.items())))
    if a.output:
        with open(a.output, "w") as f:
            json.dump(rows, f, indent=1, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
