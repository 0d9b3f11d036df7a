"""Learning from outcomes over seeds: process_plant's level_b_drift before and after.

Three runs per seed (docs/learning.md): ``off`` (runtime.learning off: the loop as
shipped), ``first`` (learning on, empty table) and ``next`` (learning on, the table
the ``first`` run of the same seed saved). Per run: the worst objective error after
the fault's onset, the time to recovery (from the onset until the loop has made its
last switch and J stays within ``objective.acceptable`` to the end; ``never`` if J
ends outside it or the loop still switches in the last ``learning.settle_s``) and
the switches.

Usage::

    python bench/learning.py --seeds 20 [-o results.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from archself.model.loader import load_architecture
from archself.resources import data_dir
from archself.runtime import MapeK
from archself.runtime.knowledge import OutcomeTable
from archself.sim.run import simulate

SCENARIO = "level_b_drift"


def _measure(res, onset: float, acceptable: float, settle_s: float) -> dict:
    t = np.asarray(res.series["t"], dtype=float)
    j = np.asarray(res.series["J"], dtype=float)
    after = t >= onset
    bad = np.flatnonzero(after & (j > acceptable))
    last = max([onset, *(s["t_s"] for s in res.switches)])
    if bad.size:
        last = max(last, float(t[min(bad[-1] + 1, len(t) - 1)]))
    ended = (bad.size and bad[-1] == len(j) - 1) or last > float(t[-1]) - settle_s
    recovery = math.inf if ended else last - onset
    return {"worst": float(np.nanmax(j[after])), "recovery_s": recovery,
            "switches": [(s["t_s"], s["action"]) for s in res.switches]}


def run_seed(arch, seed: int) -> dict:
    scen = arch.scenarios[SCENARIO]
    onset = min(f.onset_s for f in scen.faults)
    acceptable = arch.runtime.objective.acceptable
    settle = arch.runtime.learning.settle_s
    out = {}
    off = simulate(arch, SCENARIO, seed=seed, adapt=MapeK(arch))
    out["off"] = _measure(off, onset, acceptable, settle)
    loop = MapeK(arch, learned=OutcomeTable())
    first = simulate(arch, SCENARIO, seed=seed, adapt=loop)
    out["first"] = _measure(first, onset, acceptable, settle)
    saved = OutcomeTable.from_dict(loop.learning.table.to_dict())
    nxt = MapeK(arch, learned=saved)
    out["next"] = _measure(simulate(arch, SCENARIO, seed=seed, adapt=nxt), onset, acceptable,
                           settle)
    return out


def _summary(rows: list[dict]) -> str:
    lines = ["| run | worst error (m): median [min, max] | recovered | recovery (s): median "
             "[min, max] of recovered | switches: median |", "| --- | --- | --- | --- | --- |"]
    for mode in ("off", "first", "next"):
        w = np.array([r[mode]["worst"] for r in rows])
        rec = np.array([r[mode]["recovery_s"] for r in rows])
        fin = rec[np.isfinite(rec)]
        sw = np.array([len(r[mode]["switches"]) for r in rows])
        rtxt = (f"{np.median(fin):.0f} [{fin.min():.0f}, {fin.max():.0f}]" if fin.size else "—")
        lines.append(f"| {mode} | {np.median(w):.3f} [{w.min():.3f}, {w.max():.3f}] | "
                     f"{fin.size}/{len(rows)} | {rtxt} | {np.median(sw):.0f} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("-o", "--output")
    a = ap.parse_args()
    arch = load_architecture(data_dir("architectures") / "process_plant.yaml").arch
    rows = [run_seed(arch, seed) for seed in range(1, a.seeds + 1)]
    print(_summary(rows))
    if a.output:
        with open(a.output, "w") as f:
            json.dump(rows, f, indent=1, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
