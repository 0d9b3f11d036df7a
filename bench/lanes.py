"""Lane-batched campaigns against the per-run path, side by side (issue 16).

Runs ``archself campaign`` on ``architectures/diffdrive.yaml`` twice in one process
tree, on the same machine and workers:

- **per run** (``--lanes 1``): ``--per-run`` adaptive runs of a scenario, one run per job;
- **lanes** (the default batching): ``--runs`` adaptive runs of the same scenario;

and prints runs/s of each, their ratio, the wall time of the lane campaign and its
peak resident memory (all its processes, and the largest). The rows of the seeds both
campaigns ran are compared: the same switches and errors within 1e-9.

Usage::

    python bench/lanes.py                       # 1,000 lane runs, 100 per-run runs
    python bench/lanes.py --runs 200 --per-run 40 --scenario actuator_fault
    python bench/lanes.py --equal architectures/*.yaml --per-run 100   # every scenario

docs/benchmarks.md ("Lane-batched campaigns") shows its output.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
ARCH = ROOT / "architectures" / "diffdrive.yaml"


def _tree_rss(pid: int) -> tuple[int, int]:
    """(sum, largest) resident bytes of ``pid`` and its descendants (Linux /proc)."""
    kids: dict[int, list[int]] = {}
    rss: dict[int, int] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            status = (d / "status").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        kids.setdefault(ppid, []).append(int(d.name))
        for line in status.splitlines():
            if line.startswith("VmRSS:"):
                rss[int(d.name)] = int(line.split()[1]) * 1024
    todo, seen = [pid], []
    while todo:
        p = todo.pop()
        seen.append(p)
        todo.extend(kids.get(p, []))
    sizes = [rss.get(p, 0) for p in seen]
    return sum(sizes), max(sizes, default=0)


def _campaign(
    out: Path, scenarios: list[str], seeds: int, lanes: int | None, workers: int,
    arch: Path = ARCH,
) -> tuple[float, int, int]:
    """Wall time and peak (sum, largest process) memory of one campaign."""
    cmd = [sys.executable, "-m", "archself", "campaign", str(arch),
           *(a for sc in scenarios for a in ("-s", sc)),
           "--seeds", str(seeds), "--mode", "adaptive", "--workers", str(workers),
           "-o", str(out), "--force", "--yes"]
    if lanes is not None:
        cmd += ["--lanes", str(lanes)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
    peak_sum = peak_one = 0
    while proc.poll() is None:
        total, one = _tree_rss(proc.pid)
        peak_sum, peak_one = max(peak_sum, total), max(peak_one, one)
        time.sleep(0.25)
    if proc.returncode:
        raise SystemExit(f"campaign failed with exit code {proc.returncode}")
    return time.perf_counter() - t0, peak_sum, peak_one


def _compare(a: Any, b: Any) -> tuple[bool, float]:
    """Whether the rows of ``a`` (per run) and ``b`` (lanes) switch alike and report the
    same module faults, and max |Δ error|."""
    import numpy as np

    b = b.loc[a.index]
    same = bool((a["configuration_path"] == b["configuration_path"]).all()
                and (a["switch_times_s"].map(list) == b["switch_times_s"].map(list)).all()
                and (a["module_faults"] == b["module_faults"]).all())
    dev = float(np.max(np.abs(a["max_error"].to_numpy() - b["max_error"].to_numpy())))
    return same, dev


def main(argv: list[str] | None = None) -> None:
    """Measure and print the comparison."""
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000, help="adaptive runs of the lane campaign")
    ap.add_argument("--per-run", type=int, default=100, help="runs of the per-run campaign")
    ap.add_argument("--scenario", default="imu_drift")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--equal", type=Path, nargs="*", default=None, metavar="ARCH",
                    help="instead: every scenario of these files, --per-run seeds each, "
                         "per run and as lanes: the switches and errors compared")
    args = ap.parse_args(argv)

    import pandas as pd

    if args.equal is not None:
        from archself.model.loader import load_architecture

        for path in args.equal or [ARCH]:
            scenarios = list(load_architecture(path).arch.scenarios)
            with tempfile.TemporaryDirectory() as tmp:
                one, many = Path(tmp) / "one.parquet", Path(tmp) / "many.parquet"
                t1, _, _ = _campaign(one, scenarios, args.per_run, 1, args.workers, path)
                t2, _, _ = _campaign(many, scenarios, args.per_run, None, args.workers, path)
                a = pd.read_parquet(one).set_index("run_id").sort_index()
                b = pd.read_parquet(many).set_index("run_id")
            for sc in scenarios:
                rows = a[a["scenario"] == sc]
                same, dev = _compare(rows, b)
                faulted = int((rows["module_faults"] != "").sum())
                print(f"{path.name:20} {sc:18} {len(rows):4d} runs ({faulted} with module "
                      f"faults): switches and faults identical {same}, "
                      f"max |Δ max_error| = {dev:.1e}")
            print(f"{path.name}: per run {t1:.1f} s, lanes {t2:.1f} s ({t1 / t2:.1f}x)")
        return

    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    with tempfile.TemporaryDirectory() as tmp:
        one = Path(tmp) / "per_run.parquet"
        many = Path(tmp) / "lanes.parquet"
        t_one, _, _ = _campaign(one, [args.scenario], args.per_run, 1, args.workers)
        t_many, mem_sum, mem_one = _campaign(many, [args.scenario], args.runs, None,
                                             args.workers)
        a = pd.read_parquet(one).set_index("run_id").sort_index()
        b = pd.read_parquet(many).set_index("run_id")
    same, dev = _compare(a, b)
    print(f"{args.scenario}, adaptive, {args.workers} workers, load average before {load}")
    print(f"per run (--lanes 1): {args.per_run:5d} runs in {t_one:7.1f} s = "
          f"{args.per_run / t_one:6.2f} runs/s")
    print(f"lanes (default):     {args.runs:5d} runs in {t_many:7.1f} s = "
          f"{args.runs / t_many:6.2f} runs/s")
    print(f"throughput ratio: {(args.runs / t_many) / (args.per_run / t_one):.1f}x")
    print(f"the {args.per_run} seeds both ran: switches identical: {same}; "
          f"max |Δ max_error| = {dev:.1e}")
    print(f"lane campaign peak memory: {mem_sum / 2**20:.0f} MB in all its processes, "
          f"{mem_one / 2**20:.0f} MB the largest (resident, sampled every 0.25 s)")


if __name__ == "__main__":
    main()
