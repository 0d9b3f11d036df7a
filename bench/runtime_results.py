"""Regenerate the per-seed results table of docs/runtime.md (issue 4).

Runs the diffdrive scenarios ``imu_drift``, ``actuator_fault`` and ``nominal``
adaptively (``MapeK`` + ``simulate``) over seeds 0..N-1, and ``imu_drift`` and
``actuator_fault`` also fixed (the initial configuration, no loop), and prints
Markdown: the settings line, one table row per seed (switches, the two largest z
at the actuator fault's switching cycle, max errors adaptive and fixed) and the
summary line.

Usage::

    python bench/runtime_results.py [--seeds 20] [--jobs 2] [ARCH]

tests/test_runtime_results_doc.py recomputes one row through :func:`seed_row`
and checks that docs/runtime.md still shows it.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DIFFDRIVE = str(ROOT / "architectures" / "diffdrive.yaml")
DRIFT, ACTUATOR, NOMINAL = "imu_drift", "actuator_fault", "nominal"
#: (scenario, adaptive) runs per seed: what one table row needs.
RUNS = [(DRIFT, True), (DRIFT, False), (ACTUATOR, True), (ACTUATOR, False), (NOMINAL, True)]
HEADER = (
    "| seed | imu_drift: switch | max error (m) | fixed max (m) | actuator_fault: switch "
    "| z dominant | max error (m) | fixed max (m) | nominal: switches | max error (m) |\n"
    "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
)


def _arch(path: str):
    from archself.model.loader import load_architecture

    return load_architecture(path).arch


def run_one(job: tuple[str, str, bool, int]) -> dict:
    """One simulation: switches, max error, z at the first switch, largest adaptive |z|."""
    from archself.runtime import MapeK
    from archself.sim.run import simulate

    path, scenario, adaptive, seed = job
    arch = _arch(path)
    loop = MapeK(arch) if adaptive else None
    res = simulate(arch, scenario, seed=seed, adapt=loop)
    z_switch: list[tuple[str, float]] = []
    max_z = 0.0
    if loop is not None:
        first = next((d for d in loop.decisions if d.chosen and d.chosen.get("to")), None)
        if first is not None:
            z_switch = sorted(first.z.items(), key=lambda kv: -abs(kv[1]))[:2]
        zs = [abs(v) for d in loop.decisions if d.phase == "adapt" for _, v in d.z.items()]
        max_z = max(zs, default=0.0)
    return {
        "scenario": scenario,
        "adaptive": adaptive,
        "seed": seed,
        "switches": [(s["t_s"], s["from"], s["to"]) for s in res.switches],
        "max_error": res.metrics["max_error_m"],
        "z_switch": z_switch,
        "max_z": max_z,
    }


def jobs_for(path: str, seeds: Iterable[int]) -> list[tuple[str, str, bool, int]]:
    return [(path, sc, ad, s) for s in seeds for sc, ad in RUNS]


def _switches(sw: list) -> str:
    return "; ".join(f"{f} → {to} at {t:g} s" for t, f, to in sw) or "none"


def _z(z: list[tuple[str, float]]) -> str:
    if not z:
        return "—"
    head = f"{z[0][0]} {z[0][1]:.2f}"
    return head + (f" (next {z[1][0]} {z[1][1]:.2f})" if len(z) > 1 else "")


def _by_key(results: Iterable[dict]) -> dict[tuple[str, bool, int], dict]:
    return {(r["scenario"], r["adaptive"], r["seed"]): r for r in results}


def row(seed: int, results: Iterable[dict]) -> str:
    """The Markdown table row of one seed (``results`` holds that seed's :data:`RUNS`)."""
    by = _by_key(results)
    d, df = by[DRIFT, True, seed], by[DRIFT, False, seed]
    a, af = by[ACTUATOR, True, seed], by[ACTUATOR, False, seed]
    n = by[NOMINAL, True, seed]
    return (
        f"| {seed} | {_switches(d['switches'])} | {d['max_error']:.2f} | {df['max_error']:.1f} "
        f"| {_switches(a['switches'])} | {_z(a['z_switch'])} | {a['max_error']:.2f} "
        f"| {af['max_error']:.1f} | {len(n['switches'])} | {n['max_error']:.3f} |"
    )


def seed_row(seed: int, path: str = DIFFDRIVE) -> str:
    """Compute one seed's row serially (what the doc test calls)."""
    return row(seed, [run_one(j) for j in jobs_for(path, [seed])])


def table(results: list[dict]) -> str:
    seeds = sorted({r["seed"] for r in results})
    return "\n".join([HEADER] + [row(s, results) for s in seeds])


def _range(xs: list[float], fmt: str) -> str:
    lo, hi = format(min(xs), fmt), format(max(xs), fmt)
    return lo if lo == hi else f"{lo}–{hi}"


def _paths(rows: list[dict]) -> str:
    pats: dict[str, int] = {}
    for r in rows:
        sw = r["switches"]
        key = " → ".join([sw[0][1]] + [s[2] for s in sw]) if sw else "no switch"
        pats[key] = pats.get(key, 0) + 1
    return ", ".join(f"{k} on {n}/{len(rows)} seeds" for k, n in sorted(pats.items()))


def summary(results: list[dict], arch) -> str:
    by = _by_key(results)
    seeds = sorted({r["seed"] for r in results})
    parts = []
    for sc in (DRIFT, ACTUATOR):
        ad = [by[sc, True, s] for s in seeds]
        fixed = [by[sc, False, s]["max_error"] for s in seeds]
        t0 = [r["switches"][0][0] for r in ad if r["switches"]]
        text = f"{sc} {_paths(ad)}"
        if t0:
            text += f", switch at {_range(t0, 'g')} s"
        if sc == ACTUATOR:
            faulty = {f.module for f in arch.scenarios[sc].faults}
            dom = sum(1 for r in ad if r["z_switch"] and r["z_switch"][0][0] in faulty)
            text += f", {'/'.join(sorted(faulty))} channel dominant on {dom}/{len(ad)}"
        text += (
            f", adaptive max error {_range([r['max_error'] for r in ad], '.2f')} m "
            f"(fixed {_range(fixed, '.1f')} m)"
        )
        parts.append(text)
    nom = [by[NOMINAL, True, s] for s in seeds]
    quiet = sum(1 for r in nom if not r["switches"])
    total = sum(len(r["switches"]) for r in nom)
    text = f"{NOMINAL}: 0 switches on {quiet}/{len(nom)} seeds"
    if total:
        text += f" ({total} switches in all)"
    rt = arch.runtime
    sel = f"τ = {rt.threshold:g}" if rt.threshold is not None else "no threshold"
    text += f", the largest z in any adaptive cycle is {max(r['max_z'] for r in nom):.2f} ({sel})"
    parts.append(text)
    return "Summary: " + "; ".join(parts) + "."


def settings(arch) -> str:
    """The runtime settings line (from the file)."""
    rt = arch.runtime
    sel = (
        f"τ = {rt.threshold:g}"
        if rt.threshold is not None
        else (f"top-k = {rt.top_k}" if rt.top_k is not None else f"hysteresis {rt.hysteresis}")
    )
    return (
        f"Settings as in the file: {sel}, warm-up {rt.warmup_time_s:g} s, "
        f"`min_confidence` {rt.min_confidence:g}, "
        f"`period_s` {rt.period_s:g} s, T_min = {rt.dwell_s:g} s, λ = {rt.cost_weight:g}, "
        f"ε = {rt.stability.margin:g}."
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("arch", nargs="?", default=DIFFDRIVE)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    jobs = jobs_for(args.arch, range(args.seeds))
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        results = list(ex.map(run_one, jobs))
    arch = _arch(args.arch)
    print(f"{settings(arch)}\n\n{table(results)}\n\n{summary(results, arch)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
