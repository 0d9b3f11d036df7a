"""Digest of simulation traces: a regression check for refactors.

Runs every scenario of the shipped architectures for a few seeds (adaptive) and
writes, per run, the configuration path, the switch times and a SHA-256 of the
rounded numeric series. ``--compare OLD.json`` reports the largest difference of
the objective error J between two digests and any difference in switches.

Usage::

    python bench/trace_digest.py -o /tmp/before.json
    python bench/trace_digest.py -o /tmp/after.json --compare /tmp/before.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys

import numpy as np

from archself.model.loader import load_architecture
from archself.resources import data_dir
from archself.runtime import MapeK
from archself.sim.run import simulate

ARCHS = ("diffdrive.yaml", "process_plant.yaml", "motor_drive.yaml")
SEEDS = (1, 2, 3)


def digest() -> dict[str, dict]:
    out: dict[str, dict] = {}
    for fname in ARCHS:
        arch = load_architecture(data_dir("architectures") / fname).arch
        for scen in arch.scenarios:
            for seed in SEEDS:
                res = simulate(arch, scen, seed=seed, adapt=MapeK(arch))
                j = np.asarray(res.series["J"], dtype=float)
                h = hashlib.sha256(np.round(j, 9).tobytes()).hexdigest()[:16]
                out[f"{arch.name}/{scen}/{seed}"] = {
                    "sha256_J_1e-9": h,
                    "J": j.tolist(),
                    "switches": [(round(s["t_s"], 6), s["from"], s["to"]) for s in res.switches],
                }
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--compare")
    a = ap.parse_args()
    d = digest()
    with open(a.output, "w") as f:
        json.dump(d, f)
    if not a.compare:
        for k, v in d.items():
            print(k, v["sha256_J_1e-9"], v["switches"])
        return 0
    with open(a.compare) as f:
        old = json.load(f)
    bad = 0
    for k, v in d.items():
        o = old[k]
        dj = float(np.nanmax(np.abs(np.asarray(v["J"]) - np.asarray(o["J"]))))
        same_sw = [tuple(s) for s in v["switches"]] == [tuple(s) for s in o["switches"]]
        flag = "same" if v["sha256_J_1e-9"] == o["sha256_J_1e-9"] else "differs"
        sw = "same" if same_sw else "DIFFER"
        print(f"{k:40s} {v['sha256_J_1e-9']} {flag:7s} max|dJ|={dj:.3g} switches {sw}")
        bad += (not same_sw) or dj > 1e-9
    print(f"{len(d)} runs, {bad} beyond tolerance")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
