"""Whole-process CPU of ``archself simulate`` against its run in one process (issue 38.4).

Per round, interleaved: the CPU (user + system, ``os.wait4``) of a fresh
``archself simulate FILE --scenario S`` process, then, in another fresh process,
``archself.load`` and ``simulate(..., adapt=MapeK(arch))`` (``--fixed``: ``adapt=None``)
three times, timed with ``time.process_time()``: the run is the median of the last two
(imports and the first run's caches not counted). The design cache
(``ARCHSELF_CACHE_DIR``, else the user's) is warmed by one untimed process first.
Prints per round and the medians; the ratio is whole / run.

The same process times what comes before the run: the interpreter's start, the
mandated stack (numpy, pydantic, typer, ruamel.yaml), archself's imports (the CLI's
modules, the runtime, the driver), load + check (as the CLI does) and the first
run's extra (its caches, late imports); the rest of whole − run is the CLI's own
work and the process's exit. Two floor processes per round: ``python -c pass`` and
one importing the mandated stack only; ``floor ratio`` is (stack floor + run) / run,
the best whole / run the mandated stack leaves.

``--tree DIR`` (repeatable) measures source trees side by side (a ``git archive``
extract: the processes run in ``DIR``, with ``DIR`` and ``DIR/packs`` first on
``PYTHONPATH``), one round of each in turn; default: the installed archself.

Usage::

    python bench/startup.py [--rounds 5] [--file architectures/diffdrive.yaml]
                            [--scenario imu_drift] [--fixed] [--tree /tmp/old --tree .]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

STACK = "import numpy, pydantic, typer, ruamel.yaml"
RUN = """
import time
t0 = time.process_time()
import numpy, pydantic, typer, ruamel.yaml
t1 = time.process_time()
import json, pathlib, statistics, sys
import archself.cli.base, archself.cli.runs
from archself.runtime import MapeK
from archself.sim.run import simulate
t2 = time.process_time()
arch = archself.cli.base._load(pathlib.Path(sys.argv[1]))
t3 = time.process_time()
times = []
for _ in range(3):
    t = time.process_time()
    simulate(arch, sys.argv[2], adapt=None if sys.argv[3:] else MapeK(arch))
    times.append(time.process_time() - t)
run = statistics.median(times[1:])
print(json.dumps({"run": run, "interpreter": t0, "stack": t1 - t0, "archself imports": t2 - t1,
                  "load + check": t3 - t2, "first run's extra": times[0] - run}))
"""
PHASES = ("interpreter", "stack", "archself imports", "load + check", "first run's extra")


def _env(tree: str | None) -> dict[str, str]:
    if tree is None:
        return dict(os.environ)
    path = [str(Path(tree).resolve()), str(Path(tree).resolve() / "packs")]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(path)}


def whole(argv: list[str], tree: str | None) -> float:
    """CPU seconds (user + system) of one process running ``argv`` in ``tree``."""
    with open(os.devnull, "wb") as null:
        proc = subprocess.Popen(argv, stdout=null, stderr=null, cwd=tree or ROOT, env=_env(tree))
        _, status, usage = os.wait4(proc.pid, 0)
    if status:
        raise SystemExit(f"{argv}: exit status {status}")
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--file", default="architectures/diffdrive.yaml")
    ap.add_argument("--scenario", default="imu_drift")
    ap.add_argument("--tree", action="append", help="source tree (repeatable)")
    ap.add_argument("--fixed", action="store_true", help="the fixed run, no MAPE-K")
    args = ap.parse_args()
    fixed = ["--fixed"] if args.fixed else []
    cli = [sys.executable, "-m", "archself", "simulate", args.file, "--scenario", args.scenario,
           *fixed]
    trees = args.tree or [None]
    wholes: dict = {t: [] for t in trees}
    parts: dict = {t: [] for t in trees}
    floors: dict = {"python -c pass": [], "mandated stack": []}
    for t in trees:
        whole(cli, t)  # warm the design cache and the bytecode
    for k in range(args.rounds):
        for t in trees:
            wholes[t].append(whole(cli, t))
            out = subprocess.run([sys.executable, "-c", RUN, args.file, args.scenario, *fixed],
                                 cwd=t or ROOT, env=_env(t), capture_output=True, text=True,
                                 check=True)
            parts[t].append(json.loads(out.stdout))
            run = parts[t][-1]["run"]
            print(f"round {k + 1} {t or ''}: whole {wholes[t][-1]:.3f} s, run {run:.3f} s, "
                  f"ratio {wholes[t][-1] / run:.2f}", flush=True)
        floors["python -c pass"].append(whole([sys.executable, "-c", "pass"], None))
        floors["mandated stack"].append(whole([sys.executable, "-c", STACK], None))
    floor = {name: statistics.median(v) for name, v in floors.items()}
    for t in trees:
        w = statistics.median(wholes[t])
        r = statistics.median(p["run"] for p in parts[t])
        print(f"median {t or ''}: whole {w:.3f} s ({min(wholes[t]):.3f}-{max(wholes[t]):.3f}), "
              f"run {r:.3f} s, whole / run {w / r:.2f}; "
              f"floor ratio {(floor['mandated stack'] + r) / r:.2f}")
        med = {name: statistics.median(p[name] for p in parts[t]) for name in PHASES}
        rest = w - r - sum(med.values())
        print("  whole - run " + f"{w - r:.3f} s: "
              + ", ".join(f"{name} {v:.3f}" for name, v in [*med.items(), ("rest", rest)]))
    print("floors: " + ", ".join(f"{name} {v:.3f} s" for name, v in floor.items())
          + f"; load {os.getloadavg()[0]:.1f}")

if __name__ == "__main__":
    main()
