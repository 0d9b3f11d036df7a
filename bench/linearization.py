"""Cost of the whole-loop linearization (docs/stability.md) at 10^2, 10^3, 10^4 modules.

The file is ``archself generate N`` as :mod:`bench.large_cycle` prepares it
(``generic.relay`` modules, configuration ``all`` and ``alt`` without one sink,
one ``deactivate`` action to ``alt``). Reported per size:

- ``validate``: :func:`archself.check.stability.loop_table` — every configuration compiled,
  run ``runtime.stability.settle_s`` and linearized — and, of it, the
  linearizations alone (:meth:`LiveSystem.whole_loop`), with the states, the column
  groups (pairs of perturbed copies stepped) and the non-zeros of A;
- ``run-time check``: :func:`archself.runtime.stability.whole_loop_check` of the
  action on the running system (what the planner adds to an action that passed).

CPU time of this process (``time.process_time``): the figure to read on a shared
machine.

Usage::

    python bench/linearization.py 100 1000 10000 [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from large_cycle import architecture  # noqa: E402


def measure(n: int) -> dict[str, Any]:
    """The figures of one size."""
    import archself.system.linearizing as sl
    from archself.check.stability import loop_table
    from archself.runtime.stability import StabilityVerdict, whole_loop_check
    from archself.system.live import compile_system

    arch = architecture(n, path="lyapunov")
    groups: list[int] = []
    real = sl._groups

    def counted(cols, reach):
        out = real(cols, reach)
        groups.append(len(out))
        return out

    sl._groups = counted
    try:
        c0 = time.process_time()
        table = loop_table(arch)
        validate_cpu = time.process_time() - c0
        system = compile_system(arch, "all", seed=0)
        system.run(float(arch.runtime.stability.settle_s))
        c0 = time.process_time()
        loop = system.whole_loop()
        linearize_cpu = time.process_time() - c0
        c0 = time.process_time()
        worst, _, _ = loop.modes()
        modes_cpu = time.process_time() - c0
        passed = StabilityVerdict(True, "lyapunov", None, None, "passed")
        c0 = time.process_time()
        verdict = whole_loop_check(system, arch.actions[0], passed)
        check_cpu = time.process_time() - c0
    finally:
        sl._groups = real
    nnz = int(getattr(loop.A, "nnz", 0)) or int((abs(loop.A) > 0).sum())
    return {
        "modules": n,
        "states": len(loop.owners),
        "column_groups": groups[-2],
        "nnz_A": nnz,
        "max_lambda": round(worst, 6),
        "verdicts": {v.configuration: v.verdict for v in table},
        "validate_cpu_s": round(validate_cpu, 2),
        "linearize_cpu_s": round(linearize_cpu, 2),
        "modes_cpu_s": round(modes_cpu, 2),
        "runtime_check_cpu_s": round(check_cpu, 2),
        "runtime_check_ok": verdict.ok,
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("sizes", nargs="+", type=int)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = [measure(n) for n in args.sizes]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print("| modules | states | column groups | nnz(A) | max abs(λ) | validate (CPU s) | "
          "one linearization (CPU s) | eigenvalues (CPU s) | run-time check (CPU s) |")
    print("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for r in rows:
        print(f"| {r['modules']:,} | {r['states']:,} | {r['column_groups']} | {r['nnz_A']:,} | "
              f"{r['max_lambda']:.6f} | {r['validate_cpu_s']} | {r['linearize_cpu_s']} | "
              f"{r['modes_cpu_s']} | {r['runtime_check_cpu_s']} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
