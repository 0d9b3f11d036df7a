"""Campaign speed with runtime.learning off: this checkout against another, side by side.

Runs one small adaptive campaign (``run_campaign`` in-process, executor ``inline``:
diffdrive ``imu_drift`` and process_plant ``valve_loss``, ``--seeds`` seeds each) in a
fresh process per round, alternating between the checkout this script is in and
``--base`` (a folder with another version's ``archself/``, ``packs/`` and
``architectures/``, e.g. ``git archive COMMIT archself packs architectures | tar -x -C
DIR``), so that both see the same load. Prints each round's wall time and CPU time (the
round's process, which a shared machine's load disturbs less) and the ratio of the
medians (learning is off in the shipped files: the hooks' cost alone).

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
from archself.resources import single_thread_blas
single_thread_blas()
from archself.campaign.plan import plan_campaign
from archself.campaign.driver import run_campaign
import archself
t0, c0 = time.perf_counter(), time.process_time()
for name, scen in (("diffdrive", "imu_drift"), ("process_plant", "valve_loss")):
    arch = "{root}/architectures/" + name + ".yaml"
    jobs, meta = plan_campaign(arch, [scen], {seeds}, modes=("adaptive",))
    run_campaign(jobs, meta, tempfile.mktemp(suffix=".parquet"), executor="inline")
print(time.perf_counter() - t0, time.process_time() - c0, archself.__file__)
"""


def _round(code_root: Path, seeds: int) -> tuple[float, float]:
    env = dict(os.environ, PYTHONPATH=str(code_root))
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([sys.executable, "-c", _ROUND.format(root=code_root, seeds=seeds)],
                             env=env, cwd=tmp, capture_output=True, text=True, check=True)
    seconds, cpu, where = out.stdout.split()
    assert where.startswith(str(code_root)), f"{where} is not under {code_root}"
    return float(seconds), float(cpu)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", required=True, type=Path)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=8)
    a = ap.parse_args()
    times: dict[str, list[tuple[float, float]]] = {"base": [], "this": []}
    for k in range(a.rounds):
        for label, root in (("base", a.base.resolve()), ("this", ROOT)):
            times[label].append(_round(root, a.seeds))
            wall, cpu = times[label][-1]
            print(f"round {k + 1} {label}: wall {wall:.2f} s, cpu {cpu:.2f} s", flush=True)
    for i, what in enumerate(("wall", "cpu")):
        mb = statistics.median(t[i] for t in times["base"])
        mt = statistics.median(t[i] for t in times["this"])
        print(f"{what}: median base {mb:.2f} s, this {mt:.2f} s: this/base = {mt / mb:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
