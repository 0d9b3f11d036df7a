"""Lane-batched campaigns against the per-run path, side by side (issue 16).

Runs ``archself campaign`` on ``architectures/diffdrive.yaml`` twice in one process
tree, on the same machine and workers:

- **per run** (``--lanes 1``): ``--per-run`` adaptive runs of a scenario, one run per job;
- **lanes** (the default batching): ``--runs`` adaptive runs of the same scenario;

and prints runs/s of each, their ratio, the wall time of the lane campaign and the
peak memory of a worker (``ru_maxrss`` of the children). The rows of the seeds both
campaigns ran are compared: the same switches and errors within 1e-9.

Usage::

    python bench/lanes.py                       # 1,000 lane runs, 100 per-run runs
    python bench/lanes.py --runs 200 --per-run 40 --scenario actuator_fault

docs/benchmarks.md ("Lane-batched campaigns") shows its output.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ARCH = ROOT / "architectures" / "diffdrive.yaml"


def _campaign(out: Path, scenario: str, seeds: int, lanes: int | None, workers: int) -> float:
    cmd = [sys.executable, "-m", "archself", "campaign", str(ARCH), "-s", scenario,
           "--seeds", str(seeds), "--mode", "adaptive", "--workers", str(workers),
           "-o", str(out), "--force", "--yes"]
    if lanes is not None:
        cmd += ["--lanes", str(lanes)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    """Measure and print the comparison."""
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000, help="adaptive runs of the lane campaign")
    ap.add_argument("--per-run", type=int, default=100, help="runs of the per-run campaign")
    ap.add_argument("--scenario", default="imu_drift")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)

    import numpy as np
    import pandas as pd

    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    with tempfile.TemporaryDirectory() as tmp:
        one = Path(tmp) / "per_run.parquet"
        many = Path(tmp) / "lanes.parquet"
        t_one = _campaign(one, args.scenario, args.per_run, 1, args.workers)
        t_many = _campaign(many, args.scenario, args.runs, None, args.workers)
        a = pd.read_parquet(one).set_index("run_id").sort_index()
        b = pd.read_parquet(many).set_index("run_id").loc[a.index]
    same_switches = bool((a["configuration_path"] == b["configuration_path"]).all()
                         and (a["switch_times_s"].map(list) == b["switch_times_s"].map(list)).all())
    dev = float(np.max(np.abs(a["max_error"].to_numpy() - b["max_error"].to_numpy())))
    rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"{args.scenario}, adaptive, {args.workers} workers, load average before {load}")
    print(f"per run (--lanes 1): {args.per_run:5d} runs in {t_one:7.1f} s = "
          f"{args.per_run / t_one:6.2f} runs/s")
    print(f"lanes (default):     {args.runs:5d} runs in {t_many:7.1f} s = "
          f"{args.runs / t_many:6.2f} runs/s")
    print(f"throughput ratio: {(args.runs / t_many) / (args.per_run / t_one):.1f}x")
    print(f"the {args.per_run} seeds both ran: switches identical: {same_switches}; "
          f"max |Δ max_error| = {dev:.1e}")
    print(f"peak memory of a process (ru_maxrss): {rss:.0f} MB")


if __name__ == "__main__":
    main()
