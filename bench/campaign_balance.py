"""Campaign balance: the CPU of each worker of one campaign (issue 38, item 5).

Runs ``archself campaign architectures/diffdrive.yaml`` with adaptive runs of
``imu_drift`` and ``actuator_fault`` on ``--workers`` processes, samples the CPU time
(user + system, /proc) of every process of its tree while it runs, and prints the
wall time, the CPU of each worker (the busiest descendants) and the spread
``(max − min) / max`` between them. (A worker's CPU keeps growing a little after its
last run — the pool's watchdog thread — so when it went idle is not read from it.)

Usage::

    python bench/campaign_balance.py                  # 500 seeds × 2 scenarios = 1,000 runs
    python bench/campaign_balance.py --seeds 100      # 200 runs

docs/benchmarks.md ("Campaign balance") shows its output.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ARCH = ROOT / "architectures" / "diffdrive.yaml"
TICK = os.sysconf("SC_CLK_TCK")


def _tree_cpu(pid: int) -> dict[int, float]:
    """CPU seconds (user + system) of ``pid`` and each of its descendants (Linux /proc)."""
    kids: dict[int, list[int]] = {}
    cpu: dict[int, float] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        kids.setdefault(int(fields[1]), []).append(int(d.name))
        cpu[int(d.name)] = (int(fields[11]) + int(fields[12])) / TICK
    todo, out = [pid], {}
    while todo:
        p = todo.pop()
        out[p] = cpu.get(p, 0.0)
        todo.extend(kids.get(p, []))
    return out


def campaign_cpu(seeds: int, workers: int, scenarios: list[str]) -> tuple[float, list[float]]:
    """Wall time and the CPU of the ``workers`` busiest processes of one campaign."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "archself", "campaign", str(ARCH),
               *(a for sc in scenarios for a in ("-s", sc)), "--seeds", str(seeds),
               "--mode", "adaptive", "--workers", str(workers),
               "-o", str(Path(tmp) / "out.parquet"), "--force", "--yes"]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
        seen: dict[int, float] = {}
        while proc.poll() is None:
            for p, c in _tree_cpu(proc.pid).items():
                seen[p] = max(seen.get(p, 0.0), c)
            time.sleep(0.2)
        wall = time.perf_counter() - t0
        if proc.returncode:
            raise SystemExit(f"campaign failed with exit code {proc.returncode}")
    seen.pop(proc.pid, None)  # the driver
    return wall, sorted(seen.values(), reverse=True)[:workers]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--seeds", type=int, default=500, help="seeds per scenario")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scenario", action="append", default=None)
    args = ap.parse_args(argv)
    scenarios = args.scenario or ["imu_drift", "actuator_fault"]
    load = os.getloadavg()[0]
    wall, cpu = campaign_cpu(args.seeds, args.workers, scenarios)
    runs = args.seeds * len(scenarios)
    spread = (max(cpu) - min(cpu)) / max(cpu)
    print(f"{runs} adaptive runs ({', '.join(scenarios)}) on {args.workers} workers: "
          f"wall {wall:.1f} s, worker CPU " + " / ".join(f"{c:.1f}" for c in cpu)
          + f" s (total {sum(cpu):.1f} s), spread {100 * spread:.1f} % "
          f"(load {load:.1f} before, {os.getloadavg()[0]:.1f} after)")


if __name__ == "__main__":
    main()
