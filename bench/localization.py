"""Root-cause localization: the paper's z against the source estimate ê (docs/localization.md).

Two parts:

- ``--fits``: the estimators on synthetic residuals. Random weighted graphs (chains and
  random DAGs with feedback edges, a share of modules hidden: no residual), one or two
  local faults, residuals ``r = max(0, (I − Wᵀ)⁻¹ (e·m) + noise − band)`` with a
  per-edge mismatch ``m`` between the true propagation and the declared W. Reported:
  how often the largest value is at a true fault (top-1) for z, the clipped inverse ê
  (:class:`archself.runtime.influence.SourceEstimator`), NNLS
  (:func:`~archself.runtime.influence.source_nnls`) and a sparse L1-penalized fit; the
  time per estimate at 10^3–10^5 modules.
- ``--campaign``: adaptive campaigns of every shipped system (and the chain fixture)
  with ``runtime.localization`` influence and source, the same seeds; the expected final
  configuration per scenario (as in the systems' docs) is "correct".
- ``--hidden``: the hidden-source comparison (z, the clipped inverse, the fit) with W
  exact and ±40 % off the true propagation.
- ``--multihop``: the shipped ``architectures/heated_chain.yaml`` (the heater, without a
  residual, at the head of a loop; a cheap faster-PI action downstream), seeds 0…N−1,
  the fit against its ablation z = r (``ablation.propagation: false``), the paper's z
  and the clipped inverse, with and without the faster PI: runs that end compensated at
  the source, first switch, switches in nominal, worst error.
- ``--paired SYSTEM BLOCK VALUE ONSET``: one cell of the robustness matrix
  (bench/robustness.py), influence against the fit on the same seeds (paired).

Usage::

    python bench/localization.py --fits
    python bench/localization.py --campaign --seeds 10 --workers 2 --out /tmp/loc
    python bench/localization.py --hidden
    python bench/localization.py --multihop --seeds 20 --workers 2
    python bench/localization.py --paired diffdrive "right wheel loss" 0.05 50 --seeds 20
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import scipy.optimize
import scipy.sparse

from archself.runtime.influence import (
    SourceEstimator,
    SourceFit,
    influence,
    propagation_matrix,
    source_nnls,
    weight_matrix,
)

ROOT = Path(__file__).resolve().parents[1]

#: file, scenarios and the expected final configuration (the systems' docs)
SYSTEMS: dict[str, dict[str, Any]] = {
    "diffdrive": {
        "file": "architectures/diffdrive.yaml",
        "expect": {"nominal": "a1", "imu_drift": "a2", "actuator_fault": "a3"},
    },
    "process_plant": {
        "file": "architectures/process_plant.yaml",
        "expect": {"nominal": "p1", "level_drift": "p2", "valve_loss": "p3",
                   "drift_then_valve": "p4"},
    },
    "motor_drive": {
        "file": "architectures/motor_drive.yaml",
        "expect": {"nominal": "m1", "tacho_drift": "m2", "drive_loss": "m3",
                   "drift_then_drive": "m4", "both_drives_weak": "m3"},
    },
    "heated_chain": {
        "file": "architectures/heated_chain.yaml",
        "expect": {"nominal": "c1", "heater_loss": "c3", "sensor_drift": "c2"},
    },
    "chain_fixture": {
        "file": "tests/fixtures/valid/heated_chain.yaml",
        "expect": {"nominal": "c1", "heater_loss": "c3", "sensor_drift": "c2"},
    },
}


# --------------------------------------------------------------------------- fits
def sparse_fit(P: np.ndarray, r: np.ndarray, lam: float) -> np.ndarray:
    """``argmin_{e ≥ 0} ½‖P e − r‖² + λ Σ e`` (L-BFGS-B; a non-negative lasso)."""
    n = P.shape[1]

    def fun(e: np.ndarray) -> tuple[float, np.ndarray]:
        res = P @ e - r
        return 0.5 * float(res @ res) + lam * float(e.sum()), P.T @ res + lam

    out = scipy.optimize.minimize(fun, np.zeros(n), jac=True, method="L-BFGS-B",
                                  bounds=[(0, None)] * n)
    return np.asarray(out.x)


def synthetic_case(rng: np.random.Generator, n: int, shape: str) -> dict[str, Any]:
    """One graph, its faults and noisy residuals."""
    if shape == "chain":
        edges = [(i, i + 1) for i in range(n - 1)] + [(n - 1, 0)]  # a loop-closing edge
    else:
        edges = [(i, j) for i in range(n) for j in range(i + 1, n) if rng.random() < 2.5 / n]
        edges += [(j, i) for i, j in edges if rng.random() < 0.1]  # some feedback
    w = {e: rng.uniform(0.3, 0.9) for e in edges}
    if shape == "chain":
        w[(n - 1, 0)] = 0.15
    names = [str(k) for k in range(n)]
    W = weight_matrix(names, [(str(a), str(b), v) for (a, b), v in w.items()]).toarray()
    rho = max(abs(np.linalg.eigvals(W))) if W.any() else 0.0
    if rho >= 0.9:
        W *= 0.9 / rho
    observed = rng.random(n) < 0.6
    observed[0] = True
    k = 1 if rng.random() < 0.7 else 2
    cand = np.flatnonzero(observed)
    faults = rng.choice(cand, size=min(k, cand.size), replace=False)
    if shape == "chain":
        faults = np.array([0])
    e = np.zeros(n)
    e[faults] = rng.uniform(2.0, 6.0, faults.size)
    mismatch = W * rng.uniform(0.6, 1.4, W.shape)  # the true propagation differs from W
    r_true = influence(mismatch, e)
    r = np.maximum(0.0, r_true + rng.normal(0, 0.3, n) - 0.3)  # band: r ≥ 0, noise
    r[~observed] = 0.0
    return {"W": W, "observed": observed, "faults": set(faults.tolist()), "r": r}


def compare_fits(cases: int = 400, seed: int = 0) -> dict[str, Any]:
    """Top-1 hit rates of z, ê, NNLS and the sparse fit on synthetic residuals."""
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {}
    for shape, n in (("chain", 6), ("chain", 12), ("random", 20), ("random", 60)):
        hits = {"z": 0, "source (clipped inverse)": 0, "NNLS": 0, "sparse L1": 0, "fit": 0}
        done = 0
        for _ in range(cases):
            c = synthetic_case(rng, n, shape)
            if not c["r"].any():
                continue
            done += 1
            W, obs, r = c["W"], c["observed"], c["r"]
            P = propagation_matrix(W)
            o = np.flatnonzero(obs)
            sp = np.zeros(n)
            sp[o] = sparse_fit(P[np.ix_(o, o)], r[o], lam=0.5)
            est = {
                "z": np.where(obs, influence(W, r), 0.0),
                "source (clipped inverse)": SourceEstimator(W, obs).estimate(r),
                "NNLS": source_nnls(W, r, obs),
                "sparse L1": sp,
            }
            for name, v in est.items():
                hits[name] += int(int(np.argmax(v)) in c["faults"])
            fit = SourceFit(W, obs)
            fit.estimate(r)
            hits["fit"] += int(bool(fit.classes) and bool(c["faults"] & set(fit.classes[0])))
        out[f"{shape} n={n}"] = {k: v / done for k, v in hits.items()} | {"cases": done}
    return out


def hidden_case(rng: np.random.Generator, n: int, shape: str, k: int,
                off: float = 0.4) -> dict[str, Any]:
    """A case whose faults may sit on hidden modules (issue 34).

    ``chain``: 0 → 1 → … → n−1 with a loop-closing edge back to 0; the head (the fault,
    with ``k = 2`` a second one further down) is hidden, as are a third of the others.
    ``random``: a random DAG with some feedback, 40 % hidden, the ``k`` faults drawn
    among all modules with a path to an observed one. The true propagation is W with
    each edge ``± off`` (uniform) off.
    """
    if shape == "chain":
        edges = [(i, i + 1) for i in range(n - 1)] + [(n - 1, 0)]
    else:
        edges = [(i, j) for i in range(n) for j in range(i + 1, n) if rng.random() < 2.5 / n]
        edges += [(j, i) for i, j in edges if rng.random() < 0.1]
    w = {e: rng.uniform(0.5, 1.2) for e in edges}
    if shape == "chain":
        w[(n - 1, 0)] = 0.15
    names = [str(i) for i in range(n)]
    W = weight_matrix(names, [(str(a), str(b), v) for (a, b), v in w.items()]).toarray()
    rho = max(abs(np.linalg.eigvals(W))) if W.any() else 0.0
    if rho >= 0.9:
        W *= 0.9 / rho
    observed = rng.random(n) < (0.67 if shape == "chain" else 0.6)
    if shape == "chain":
        observed[0] = False
        observed[n - 1] = True
        faults = [0] + ([int(rng.integers(n // 2, n))] if k == 2 else [])
    else:
        P = propagation_matrix(W)
        seen = np.flatnonzero(np.any(P[observed] != 0, axis=0))
        faults = rng.choice(seen, size=min(k, seen.size), replace=False).tolist()
    e = np.zeros(n)
    e[faults] = rng.uniform(2.0, 6.0, len(faults))
    true_W = W * rng.uniform(1.0 - off, 1.0 + off, W.shape)  # W ±40 % off by default
    r = np.maximum(0.0, influence(true_W, e) + rng.normal(0, 0.3, n) - 0.3)
    r[~observed] = 0.0
    return {"W": W, "observed": observed, "faults": set(faults), "r": r}


def _ranked_sets(values: np.ndarray) -> list[list[int]]:
    """Modules by decreasing value, one per rank (z, ê), non-zero only."""
    order = np.argsort(-values, kind="stable")
    return [[int(i)] for i in order if values[i] > 0]


def compare_hidden(cases: int = 200, seed: int = 0, off: float = 0.4) -> dict[str, Any]:
    """Top-1/top-2 of z, today's ê and the source fit with hidden faults.

    A rank of the fit is an equivalence class (modules the data cannot tell apart):
    top-1 counts a hit when the first class holds a true fault, and the mean size of
    that class is reported beside it (1 = identified). ``off``: how far each edge of the
    true propagation is from W (0.4: ±40 %; 0: W exact).
    """
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {}
    for shape, n in (("chain", 6), ("chain", 12), ("random", 20), ("random", 60)):
        for k in (1, 2):
            tally = {m: [0, 0] for m in ("z", "ê (clipped inverse)", "fit")}
            size, done = 0, 0
            for _ in range(cases):
                c = hidden_case(rng, n, shape, k, off)
                if not c["r"].any():
                    continue
                done += 1
                W, obs, r, f = c["W"], c["observed"], c["r"], c["faults"]
                fit = SourceFit(W, obs)
                fit.estimate(r)
                ranks = {
                    "z": _ranked_sets(influence(W, r)),
                    "ê (clipped inverse)": _ranked_sets(SourceEstimator(W, obs).estimate(r)),
                    "fit": fit.classes,
                }
                for m, sets in ranks.items():
                    tally[m][0] += int(bool(sets) and bool(f & set(sets[0])))
                    tally[m][1] += int(bool(f & {j for s in sets[:2] for j in s}))
                size += len(fit.classes[0]) if fit.classes else 0
            out[f"{shape} n={n}, {k} fault{'s' if k > 1 else ''}"] = {
                **{f"{m} top-1": v[0] / done for m, v in tally.items()},
                **{f"{m} top-2": v[1] / done for m, v in tally.items()},
                "fit class size": size / done,
                "cases": done,
            }
    return out


def timing(sizes: tuple[int, ...] = (1_000, 10_000, 100_000)) -> dict[int, dict[str, float]]:
    """Seconds to build and apply the clipped inverse and the fit on a sparse random DAG.

    40 % hidden; the fit on the residuals of two faults (its candidates are their
    ancestors).
    """
    rng = np.random.default_rng(1)
    out = {}
    for n in sizes:
        m = 3 * n
        rows = rng.integers(0, n, m)
        cols = rng.integers(0, n, m)
        keep = rows < cols
        W = scipy.sparse.csr_matrix(
            (rng.uniform(0.1, 0.5, keep.sum()), (rows[keep], cols[keep])), shape=(n, n)
        )
        observed = rng.random(n) < 0.6
        r = np.where(observed, rng.random(n), 0.0)
        t0 = time.perf_counter()
        est = SourceEstimator(W, observed)
        t1 = time.perf_counter()
        for _ in range(10):
            est.estimate(r)
        t2 = time.perf_counter()
        e = np.zeros(n)
        e[rng.choice(np.flatnonzero(observed), 2)] = 3.0  # two faults' echoes
        r_fit = np.where(observed, influence(W, e), 0.0)
        t3 = time.perf_counter()
        fit = SourceFit(W, observed)
        t4 = time.perf_counter()
        fit.estimate(r_fit)  # first: the candidates' columns are solved and cached
        t5 = time.perf_counter()
        for _ in range(10):
            fit.estimate(r_fit)
        t6 = time.perf_counter()
        out[n] = {"build_s": t1 - t0, "estimate_s": (t2 - t1) / 10,
                  "fit_build_s": t4 - t3, "fit_first_s": t5 - t4, "fit_estimate_s": (t6 - t5) / 10}
    return out


# --------------------------------------------------------------------------- campaigns
def _with_localization(src: Path, dst: Path, mode: str) -> None:
    text = src.read_text(encoding="utf-8")
    head, sep, tail = text.rpartition("\nruntime:\n")
    if not sep:
        raise SystemExit(f"{src}: no top-level runtime block")
    dst.write_text(f"{head}{sep}  localization: {mode}\n{tail}", encoding="utf-8")


def campaign(out: Path, seeds: int, workers: int, systems: list[str]) -> dict[str, Any]:
    """Adaptive campaigns, influence vs source, summarized per scenario."""
    out.mkdir(parents=True, exist_ok=True)
    exe = Path(sys.executable).parent / "archself"
    summary: dict[str, Any] = {}
    for name in systems:
        spec = SYSTEMS[name]
        for mode in ("influence", "source"):
            arch = out / f"{name}_{mode}.yaml"
            _with_localization(ROOT / spec["file"], arch, mode)
            table = out / f"{name}_{mode}.parquet"
            cmd = [str(exe), "campaign", str(arch), "--seeds", str(seeds), "--mode", "adaptive",
                   "--workers", str(workers), "--root-seed", "1", "-o", str(table), "--force",
                   "--yes"]
            for s in spec["expect"]:
                cmd += ["-s", s]
            t0 = time.time()
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
            rep = [str(exe), "campaign-report", str(table), "-o", str(out / f"{name}_{mode}"),
                   "--json"]
            for s, conf in spec["expect"].items():
                rep += ["--expect", f"{s}={conf}"]
            res = subprocess.run(rep, check=True, capture_output=True, text=True)
            summary[f"{name}/{mode}"] = {"seconds": time.time() - t0,
                                        "report": json.loads(res.stdout)}
            print(f"{name} {mode}: {time.time() - t0:.0f} s", file=sys.stderr)
    (out / "summary.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    return summary


# --------------------------------------------------------------------------- multi-hop
#: the variants of the multi-hop study: (localization, propagation, keep the faster PI)
MULTIHOP: dict[str, tuple[str, bool, bool]] = {
    "fit (default)": ("fit", True, True),
    "fit, z = r (no propagation)": ("fit", False, True),
    "influence (paper's z)": ("influence", True, True),
    "source (clipped ê)": ("source", True, True),
    "fit, no faster PI": ("fit", True, False),
    "fit, z = r, no faster PI": ("fit", False, False),
    "influence, no faster PI": ("influence", True, False),
}


#: the "late" error is the largest |J| from this long after the onset (past the transient)
LATE_S = 30.0


def _multihop_run(job: tuple[str, str, int]) -> dict[str, Any]:
    """One run of the multi-hop study: variant, scenario, seed."""
    from archself.model.loader import load_architecture
    from archself.runtime import MapeK
    from archself.sim.run import simulate

    variant, scenario, seed = job
    mode, propagate, faster = MULTIHOP[variant]
    arch = load_architecture(ROOT / SYSTEMS["heated_chain"]["file"]).arch
    arch.runtime.localization = mode
    arch.runtime.ablation.propagation = propagate
    if not faster:
        arch.actions = [a for a in arch.actions if a.id != "faster_pi"]
    loop = MapeK(arch)
    res = simulate(arch, scenario, seed=seed, adapt=loop)
    onset = min((f.onset_s for f in arch.scenarios[scenario].faults), default=None)
    t, J = np.asarray(res.series["t"]), np.abs(np.asarray(res.series["J"], dtype=float))
    late = J[t >= (onset or 0.0) + LATE_S]
    return {
        "variant": variant, "scenario": scenario, "seed": seed,
        "at_source": "heater_b" in arch.configurations[res.final_configuration].modules,
        "final": res.final_configuration,
        "first": loop.switches[0]["action"] if loop.switches else None,
        "first_t": loop.switches[0]["t_s"] - (onset or 0.0) if loop.switches else None,
        "switches": len(loop.switches), "updates": len(loop.updates),
        "max_error": float(res.metrics["max_error"]), "rms_error": float(res.metrics["rms_error"]),
        "late_max_error": float(late.max()) if late.size else 0.0,
    }


def multihop(seeds: int, workers: int) -> dict[str, Any]:
    """The multi-hop study on architectures/heated_chain.yaml (docs/localization.md).

    heater_loss: runs that end in a configuration with the backup heater (compensated
    at the source), the first switch's action and delay after the onset, the worst and
    mean max error, the worst |J| from :data:`LATE_S` after the onset; nominal: runs with
    any switch or parameter update (false).
    """
    from concurrent.futures import ProcessPoolExecutor

    jobs = [(v, s, k) for v in MULTIHOP for s in ("heater_loss", "nominal") for k in range(seeds)]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        runs = list(pool.map(_multihop_run, jobs, chunksize=4))
    out: dict[str, Any] = {}
    for v in MULTIHOP:
        loss = [r for r in runs if r["variant"] == v and r["scenario"] == "heater_loss"]
        nom = [r for r in runs if r["variant"] == v and r["scenario"] == "nominal"]
        firsts: dict[str, int] = {}
        for r in loss:
            firsts[str(r["first"])] = firsts.get(str(r["first"]), 0) + 1
        delays = sorted(r["first_t"] for r in loss if r["first_t"] is not None)
        out[v] = {
            "at_source": sum(r["at_source"] for r in loss), "runs": len(loss),
            "first_switch": firsts,
            "first_delay_median_s": delays[len(delays) // 2] if delays else None,
            "pi_updates": sum(r["updates"] for r in loss),
            "max_error_worst": max(r["max_error"] for r in loss),
            "max_error_mean": float(np.mean([r["max_error"] for r in loss])),
            "rms_error_mean": float(np.mean([r["rms_error"] for r in loss])),
            "late_max_error_worst": max(r["late_max_error"] for r in loss),
            "nominal_false": sum((r["switches"] + r["updates"]) > 0 for r in nom),
            "nominal_runs": len(nom),
        }
    return out


def paired(system: str, block: str, value: float, onset: float, seeds: int,
           workers: int, out: Path) -> dict[str, Any]:
    """One robustness-matrix cell, influence against fit on the same seeds (paired).

    The cell is the matrix's (bench/robustness.py: its file copy, root seed 1, so the
    same seeds as the matrix's cell). Reported: right switches, false switches, the
    per-seed max errors, their paired differences (fit − influence: mean, sd, how many
    seeds better/worse) and the detection delays.
    """
    sys.path.insert(0, str(ROOT / "bench"))
    import robustness as rb
    from ruamel.yaml import YAML

    from archself.campaign import parse_sweep, plan_campaign, run_campaign
    from archself.campaign.results import read_results
    from archself.model.loader import load_architecture

    spec = rb.SYSTEMS[system]
    out.mkdir(parents=True, exist_ok=True)
    slug = rb._slug(block)
    sweeps = [parse_sweep(f"scenarios.{slug}.faults[0].magnitude={value:g}"),
              parse_sweep(f"scenarios.{slug}.faults[0].onset_s={onset:g}")]
    want = spec["faults"][block]["expect"]
    res: dict[str, Any] = {}
    for mode in ("influence", "fit"):
        file = out / f"{system}_{mode}.yaml"
        rb.matrix_file(spec, ROOT / spec["file"], file)
        yaml = YAML()
        data = yaml.load(file.read_text(encoding="utf-8"))
        data["runtime"]["localization"] = mode
        with file.open("w", encoding="utf-8") as fh:
            yaml.dump(data, fh)
        arch = load_architecture(file).arch
        jobs, meta = plan_campaign(file, [slug], seeds, sweeps, modes=("adaptive",),
                                   root_seed=1, yes=True)
        table = out / f"{system}_{mode}.parquet"
        run_campaign(jobs, meta, table, workers=workers, force=True)
        rows = sorted(read_results(table)[0].to_pylist(), key=lambda r: r["seed"])
        res[mode] = {
            "seeds": [r["seed"] for r in rows],
            "max_error": [float(r["max_error"]) for r in rows],
            "delay": [r["detection_delay_s"] for r in rows],
            "right": sum(want in arch.configurations[r["final_configuration"]].modules
                         and not r["false_switches"] for r in rows),
            "false_switches": sum(int(r["false_switches"] or 0) for r in rows),
            "paths": sorted({r["configuration_path"] for r in rows}),
        }
    a, b = res["influence"], res["fit"]
    assert a["seeds"] == b["seeds"]
    d = np.array(b["max_error"]) - np.array(a["max_error"])
    res["paired"] = {
        "diff_mean": float(d.mean()), "diff_sd": float(d.std(ddof=1)) if d.size > 1 else 0.0,
        "fit_better": int((d < -1e-9).sum()), "fit_worse": int((d > 1e-9).sum()),
        "worst": [max(a["max_error"]), max(b["max_error"])],
        "mean": [float(np.mean(a["max_error"])), float(np.mean(b["max_error"]))],
    }
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fits", action="store_true", help="synthetic comparison and timing")
    ap.add_argument("--campaign", action="store_true", help="campaigns of the shipped systems")
    ap.add_argument("--hidden", action="store_true",
                    help="hidden sources only, W exact and ±40 %% off")
    ap.add_argument("--multihop", action="store_true", help="the shipped heated_chain study")
    ap.add_argument("--paired", nargs=4, metavar=("SYSTEM", "BLOCK", "VALUE", "ONSET"),
                    help="one robustness cell, influence vs fit on the same seeds")
    ap.add_argument("--systems", nargs="*", default=list(SYSTEMS))
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("/tmp/localization"))
    args = ap.parse_args(argv)
    if args.fits:
        print(json.dumps(compare_fits(), indent=1))
        print(json.dumps(compare_hidden(), indent=1))
        print(json.dumps(timing(), indent=1))
    if args.hidden:
        print(json.dumps({f"W ±{off:.0%} off": compare_hidden(off=off) for off in (0.0, 0.4)},
                         indent=1))
    if args.campaign:
        campaign(args.out, args.seeds, args.workers, args.systems)
    if args.multihop:
        print(json.dumps(multihop(args.seeds, args.workers), indent=1))
    if args.paired:
        system, block, value, onset = args.paired
        print(json.dumps(paired(system, block, float(value), float(onset), args.seeds,
                                args.workers, args.out), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
