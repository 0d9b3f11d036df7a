"""Per-run CPU time of two source trees side by side (A/B/A/B, several rounds).

Each tree (a checkout or a ``git archive`` extract) runs the same adaptive simulations
of its own ``architectures/<file>``: every scenario × seed, with the MAPE-K loop. The
trees run alternately, one fresh process per tree and round, so slow phases of a shared
machine fall on both. The time of a run is ``time.process_time()`` around
``simulate(...)`` in that process (CPU time: less sensitive to other load than wall
time); each process first does one untimed warm-up run, so imports and caches are not
counted.

Each tree runs with its own interpreter. ``--setup DIR`` makes them: one throwaway venv
per tree under ``DIR`` whose third-party packages are the running interpreter's (its
site-packages linked, archself and plugins left out, so both trees use the very same
numpy, scipy, control and filterpy builds), and the tree installed into it
(``pip install --no-deps --no-build-isolation``; the packs ship in the same wheel at and
after the core/packs split, and their entry points with it). Or give ``--python-a`` /
``--python-b`` of environments made otherwise.

On a shared machine CPU time moves by ±30 % with the load of others (the runs of one
tree, taken minutes apart, did); ``--instructions`` counts the instructions a run executes
under valgrind's callgrind instead (the process with the runs minus the same process
without them, divided by the runs), which the load does not change, at about 50 times the
time.

Reported per run (scenario/seed): the median over rounds for A and B, and B/A; then the
median of the per-run ratios with its spread (min–max over runs, and the ratio of the
per-round totals, min–max over rounds).

Usage::

    python bench/per_run_ab.py /tmp/old /tmp/new --setup /tmp/ab --rounds 4
    python bench/per_run_ab.py /tmp/old /tmp/new --python-a /tmp/ab/venv_a/bin/python \\
        --python-b /tmp/ab/venv_b/bin/python --scenarios imu_drift,nominal --seeds 1-5
    python bench/per_run_ab.py /tmp/old /tmp/new --python-a ... --python-b ... \\
        --instructions --scenarios nominal,imu_drift --seeds 2
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import sysconfig
import tempfile
import venv
from pathlib import Path

#: the worker: one tree, one round; prints one JSON object {"scenario/seed": cpu_s}
WORKER = r"""
import json, sys, time
from archself.model.loader import load_architecture
from archself.runtime import MapeK
from archself.sim.run import simulate
path, warm = sys.argv[1], sys.argv[2]
scenarios = [s for s in sys.argv[3].split(",") if s]
seeds = [int(s) for s in sys.argv[4].split(",") if s]
arch = load_architecture(path).arch
simulate(arch, warm, seed=1000, adapt=MapeK(arch))  # warm-up, untimed
out = {}
for sc in scenarios:
    for seed in seeds:
        t0 = time.process_time()
        res = simulate(arch, sc, seed=seed, adapt=MapeK(arch))
        out[f"{sc}/{seed}"] = {"cpu_s": time.process_time() - t0,
                              "switches": [s["to"] for s in res.switches]}
print(json.dumps(out))
"""

#: distributions of the running interpreter that are not linked into the venvs
OWN = ("archself", "_editable_impl_archself", "__editable__", "__pycache__")


def parse_seeds(text: str) -> list[int]:
    """``"1-5"`` or ``"1,3,7"`` → list of seeds."""
    if "-" in text:
        lo, hi = text.split("-", 1)
        return list(range(int(lo), int(hi) + 1))
    return [int(s) for s in text.split(",")]


def make_venv(tree: Path, where: Path) -> Path:
    """A venv at ``where`` with this interpreter's third-party packages and ``tree`` installed.

    Returns the venv's python.
    """
    deps = where.parent / "deps"
    if not deps.exists():
        deps.mkdir(parents=True)
        for item in Path(sysconfig.get_paths()["purelib"]).iterdir():
            if not item.name.startswith(OWN):
                (deps / item.name).symlink_to(item)
    venv.EnvBuilder(with_pip=False, clear=True).create(where)
    py = where / "bin" / "python"
    site = subprocess.run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    Path(site, "zz_ab_deps.pth").write_text(f"import site; site.addsitedir({str(deps)!r})\n")
    subprocess.run([py, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                    "--no-index", str(tree)], check=True)
    return py


def run_round(py: str, tree: Path, arch_file: str, scenarios: str, seeds: str,
              valgrind: Path | None = None) -> dict:
    """One fresh process of one tree: its runs' CPU times.

    With ``valgrind`` (an output file) the process runs under callgrind and the
    instructions it executed are returned as ``{"instructions": n}``.
    """
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env.pop("PYTHONPATH", None)
    warm = scenarios.split(",")[0] or "nominal"
    cmd = [py, "-c", WORKER, str(tree / "architectures" / arch_file), warm, scenarios, seeds]
    if valgrind is not None:
        cmd = ["valgrind", "--tool=callgrind", "--cache-sim=no",
               f"--callgrind-out-file={valgrind}", *cmd]
    with tempfile.TemporaryDirectory() as cwd:  # never import a tree from the working dir
        out = subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=cwd, env=env)
    if valgrind is not None:
        for line in valgrind.read_text().splitlines():
            if line.startswith("summary:"):
                return {"instructions": int(line.split()[1])}
        raise RuntimeError(f"{valgrind}: no summary line")
    return json.loads(out.stdout.strip().splitlines()[-1])


def instructions(py: str, tree: Path, arch_file: str, scenarios: str, seeds: str,
                 where: Path) -> float:
    """Instructions per run (callgrind): (process with the runs − process without) / runs.

    Independent of the machine's load, unlike CPU time; about 50 times slower.
    """
    n = len([s for s in scenarios.split(",") if s]) * len([s for s in seeds.split(",") if s])
    base = run_round(py, tree, arch_file, scenarios.split(",")[0] + ",", "", where / "base.out")
    full = run_round(py, tree, arch_file, scenarios, seeds, where / "full.out")
    return (full["instructions"] - base["instructions"]) / n


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tree_a", type=Path)
    ap.add_argument("tree_b", type=Path)
    ap.add_argument("--python-a", help="interpreter with tree A installed")
    ap.add_argument("--python-b", help="interpreter with tree B installed")
    ap.add_argument("--setup", type=Path, help="make a venv per tree under this directory")
    ap.add_argument("--arch", default="diffdrive.yaml", help="file under architectures/")
    ap.add_argument("--scenarios", default="imu_drift,nominal")
    ap.add_argument("--seeds", default="1-5")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--json", type=Path, help="write the raw times here")
    ap.add_argument("--instructions", action="store_true",
                    help="count instructions per run under valgrind's callgrind instead of "
                    "timing (one process pair per tree; the load of the machine does not enter)")
    a = ap.parse_args()
    tree_a, tree_b = a.tree_a.resolve(), a.tree_b.resolve()
    py_a, py_b = a.python_a, a.python_b
    if a.setup:
        py_a = py_a or str(make_venv(tree_a, a.setup / "venv_a"))
        py_b = py_b or str(make_venv(tree_b, a.setup / "venv_b"))
    if not (py_a and py_b):
        ap.error("give --setup DIR or both --python-a and --python-b")
    seeds = ",".join(str(s) for s in parse_seeds(a.seeds))
    if a.instructions:
        with tempfile.TemporaryDirectory() as tmp:
            ir = {}
            for label, py, tree in (("A", py_a, tree_a), ("B", py_b, tree_b)):
                (Path(tmp) / label).mkdir()
                ir[label] = instructions(py, tree, a.arch, a.scenarios, seeds, Path(tmp) / label)
                print(f"{label}: {ir[label] / 1e9:.3f} G instructions per run", flush=True)
        print(f"B/A: {ir['B'] / ir['A']:.3f}")
        return 0
    rounds: list[dict[str, dict]] = []
    for r in range(a.rounds):
        pair = {}
        for label, py, tree in (("A", py_a, tree_a), ("B", py_b, tree_b)):
            pair[label] = run_round(py, tree, a.arch, a.scenarios, seeds)
            tot = sum(v["cpu_s"] for v in pair[label].values())
            print(f"round {r + 1} {label}: {tot:.2f} s CPU", file=sys.stderr, flush=True)
        rounds.append(pair)
    keys = list(rounds[0]["A"])
    print(f"{'run':<16} {'A median s':>10} {'B median s':>10} {'B/A':>7}  switches A | B")
    ratios = []
    for k in keys:
        ma = statistics.median(p["A"][k]["cpu_s"] for p in rounds)
        mb = statistics.median(p["B"][k]["cpu_s"] for p in rounds)
        ratios.append(mb / ma)
        sw = f"{rounds[0]['A'][k]['switches']} | {rounds[0]['B'][k]['switches']}"
        print(f"{k:<16} {ma:>10.3f} {mb:>10.3f} {mb / ma:>7.3f}  {sw}")
    tot = [sum(v["cpu_s"] for v in p["B"].values()) / sum(v["cpu_s"] for v in p["A"].values())
           for p in rounds]
    ta = statistics.median(sum(v["cpu_s"] for v in p["A"].values()) for p in rounds)
    tb = statistics.median(sum(v["cpu_s"] for v in p["B"].values()) for p in rounds)
    print(f"total per round (median): A {ta:.2f} s, B {tb:.2f} s, B/A {tb / ta:.3f} "
          f"(rounds {min(tot):.3f}–{max(tot):.3f})")
    print(f"per-run B/A: median {statistics.median(ratios):.3f} "
          f"(runs {min(ratios):.3f}–{max(ratios):.3f})")
    if a.json:
        a.json.write_text(json.dumps({"tree_a": str(tree_a), "tree_b": str(tree_b),
                                      "rounds": rounds}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
