"""One MAPE-K cycle with a candidate action and its stability test on a generated graph.

The file is ``archself generate N`` (``generic.relay`` modules, one configuration
``all``) plus what a cycle needs to reach the stability filter: noise on one
module (so its residual stands out), a configuration ``alt`` without one sink
module, and one ``deactivate`` action to it keyed to each of the cycle's
candidates (``table`` improvement: Δ costs nothing, the stability test is what is
measured). Two paths of the filter (:mod:`archself.runtime.stability`):

- ``lyapunov``: ``generic.relay`` gives no linear model, so the action is checked
  by the Lyapunov rollout (Eq. 22–24);
- ``eigenvalue``: the relays are replaced by ``bench.linear_relay``, a relay that
  gives its linear model (``x⁺ = gain·mean(inputs)``), so the filter computes the
  closed-loop A of ``alt`` and its eigenvalues (Eq. 21).

Reported per size: compile (``compile_system``), the cycle that evaluates the
action (CPU time of this process, ``time.process_time``, and wall time), the
peak of Python allocations during that cycle (``tracemalloc``, a second run of
the same cycle) and the process's peak RSS (``resource.getrusage``). CPU time is
the figure to read on a shared machine.

Usage::

    python bench/large_cycle.py 10000 100000 [--path lyapunov|eigenvalue|both]
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
import tracemalloc
from typing import Any

from archself.resources import single_thread_blas

single_thread_blas()

import numpy as np  # noqa: E402

from archself.modules.base import LinearModel  # noqa: E402
from archself_blocks.relay import Relay  # noqa: E402


class LinearRelay(Relay):
    """``generic.relay`` with its linear model: ``x⁺ = gain · mean(signal inputs)``."""

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        ports = inputs.get("signal") or []
        k = len(ports)
        g = float(self.params["gain"])
        return LinearModel(
            [[0.0]],
            [[g / k] * k] if k else np.zeros((1, 0)),
            [[1.0]],
            [[0.0] * k] if k else np.zeros((1, 0)),
            inputs=[("signal", 1, i) for i in range(k)],
            outputs=[("signal", 1)],
            dt=dt,
        )


def _register() -> None:
    from archself import registry

    if registry.lookup("bench.linear_relay") is None:
        registry.add("bench.linear_relay", LinearRelay)


def architecture(n: int, *, path: str = "lyapunov"):
    """The generated file with noise on one module, configuration ``alt`` and an action."""
    from archself.model.generate import generate_architecture
    from archself.model.loader import load_text

    text = generate_architecture(n, seed=1)
    data = json.loads(text.split("\n", 1)[1])
    mods = data["modules"]
    objective_module = data["runtime"]["objective"]["actual"].split(".")[0]
    # noise on a source of the objective module: V of the rollout is not 0
    noisy = next(e["from"] for e in data["edges"] if e["to"] == objective_module)
    mods[noisy]["params"] = {"noise": {"value": 1.0}}
    if path == "eigenvalue":
        _register()
        for m in mods.values():
            m["type"] = "bench.linear_relay"
    sources = {e["from"] for e in data["edges"]}
    objective = {data["runtime"]["objective"]["actual"].split(".")[0], "m0"}
    sink = next(f"m{i}" for i in range(n - 1, -1, -1)
                if f"m{i}" not in sources and f"m{i}" not in objective)
    everything = data["configurations"]["all"]["modules"]
    data["configurations"]["alt"] = {"modules": [m for m in everything if m != sink]}
    rt = data["runtime"]
    rt["localization"] = "source"  # the noisy module is a candidate (ê is largest there)
    rt["warmup_s"] = 3.0  # the measured cycle is not the first (W factorized, plans made)
    data["actions"] = [
        {"id": f"drop_{sink}", "module": noisy, "kind": "deactivate", "to": "alt", "cost": 0.1,
         "improvement": {"method": "table", "values": {noisy: 1.0}}}
    ]
    return load_text(json.dumps(data)).arch


def _run(arch, *, trace: bool) -> dict[str, Any]:
    """Compile, then cycle until the first cycle that evaluates an action; measure it."""
    from archself.runtime import MapeK
    from archself.system.live import compile_system

    c0, w0 = time.process_time(), time.perf_counter()
    system = compile_system(arch, arch.initial_configuration(), seed=0)
    out: dict[str, Any] = {
        "compile_cpu_s": time.process_time() - c0,
        "compile_wall_s": time.perf_counter() - w0,
    }
    loop = MapeK(arch)
    steps = int(round(arch.runtime.period_s / arch.runtime.step_s))
    for _ in range(100):
        for _ in range(steps):
            system.step()
        if trace:
            tracemalloc.start()
        c0, w0 = time.process_time(), time.perf_counter()
        loop(system)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        if trace:
            out["cycle_peak_alloc_mb"] = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
        rec = loop.decisions[-1]
        if rec.evaluations:
            out.update(
                cycle=rec.cycle,
                cycle_cpu_s=cpu,
                cycle_wall_s=wall,
                stability=[e.stability for e in rec.evaluations],
                rejected=[e.rejected for e in rec.evaluations],
                chosen=(rec.chosen or {}).get("action"),
            )
            return out
    raise RuntimeError("no action evaluated in 100 cycles")


def measure(n: int, path: str) -> dict[str, Any]:
    """Figures of one size and path (see the module docstring)."""
    arch = architecture(n, path=path)
    timed = _run(arch, trace=False)
    traced = _run(arch, trace=True)
    assert traced["cycle"] == timed["cycle"]
    return {
        "n": n,
        "path": path,
        **timed,
        "cycle_peak_alloc_mb": round(traced["cycle_peak_alloc_mb"], 1),
        "max_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("sizes", nargs="+", type=int)
    ap.add_argument("--path", choices=["lyapunov", "eigenvalue", "both"], default="both")
    a = ap.parse_args()
    paths = ["lyapunov", "eigenvalue"] if a.path == "both" else [a.path]
    for n in a.sizes:
        for p in paths:
            print(json.dumps(measure(n, p)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
