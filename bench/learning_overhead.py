"""Campaign speed with runtime.learning off: this checkout against another, side by side.

Runs one small adaptive campaign (``run_campaign``, one worker: diffdrive ``imu_drift``
and process_plant ``valve_loss``, ``--seeds`` seeds each) in a fresh process per round,
alternating between the checkout this script is in and ``--base`` (a folder with
another version's ``archself/``, ``packs/`` and ``architectures/``, e.g.
``git archive COMMIT archself packs architectures | tar -x -C DIR``), so that both see
the same load. Prints each round's wall time and the ratio of
the medians (learning is off in the shipped files: the hooks' cost alone).

Usage::

    python bench/learning_overhead.py --base /tmp/base --rounds 3 --seeds 8
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_ROUND = """
import sys, time, tempfile
from archself.campaign.executors import single_thread_blas
single_thread_blas()
from archself.campaign.plan import plan_campaign
from archself.campaign.driver import run_campaign
import archself
t0 = time.perf_counter()
for name, scen in (("diffdrive", "imu_drift"), ("process_plant", "valve_loss")):
    arch = "{root}/architectures/" + name + ".yaml"
    jobs, meta = plan_campaign(arch, [scen], {seeds}, modes=("adaptive",))
    run_campaign(jobs, meta, tempfile.mktemp(suffix=".parquet"), workers=1)
print(time.perf_counter() - t0, archself.__file__)
"""


def _round(code_root: Path, seeds: int) -> float:
    env = dict(os.environ, PYTHONPATH=str(code_root))
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([sys.executable, "-c", _ROUND.format(root=code_root, seeds=seeds)],
                             env=env, cwd=tmp, capture_output=True, text=True, check=True)
    seconds, where = out.stdout.split()
    assert where.startswith(str(code_root)), f"{where} is not under {code_root}"
    return float(seconds)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", required=True, type=Path)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=8)
    a = ap.parse_args()
    times: dict[str, list[float]] = {"base": [], "this": []}
    for k in range(a.rounds):
        for label, root in (("base", a.base.resolve()), ("this", ROOT)):
            times[label].append(_round(root, a.seeds))
            print(f"round {k + 1} {label}: {times[label][-1]:.2f} s", flush=True)
    mb, mt = statistics.median(times["base"]), statistics.median(times["this"])
    print(f"median base {mb:.2f} s, this {mt:.2f} s: this/base = {mt / mb:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
