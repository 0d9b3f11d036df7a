"""Property tests of the whole MAPE-K loop on generated and mutated architecture files.

:func:`adaptive_architectures` draws small valid files that reach every stage of
Algorithm 1: ``generic.relay`` modules (some noisy, so their residual r_i and the
influence z are non-zero and candidates appear) plus a few input-less registered
types (``model.tank``, ``planner.setpoint``, ...), a hub-and-spoke graph with extra
forward edges and at most one weak backward edge (every column of W sums to ≤ 0.9,
so ρ(W) ≤ 0.9), 2–4 configurations, actions of every kind between them
(substitute / activate / deactivate / rewire, matched to the change, and
parameter updates) with the three Δ estimates, budgets, a scenario with one or two
faults the relays accept, and random runtime settings (selector τ, top-k or
hysteresis, normalization, warm-up, dwell, λ, stability margins, ρ limit).

Properties: every generated file checks without error; compiling it and a short
adaptive simulation never raise, switch only between declared configurations and
are deterministic per seed; small mutations of valid files (the generated ones and
architectures/process_plant.yaml on a short horizon) that still validate also
simulate adaptively without raising. The examples are derandomized and no database
is kept, so CI runs the same examples every time.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

from hypothesis import Phase, event, find, given, settings
from hypothesis import strategies as st

from archself.check import check, has_errors
from archself.errors import ArchselfError
from archself.model.architecture import Action, Architecture
from archself.model.loader import load_data, load_text
from archself.runtime import MapeK
from archself.sim.run import RunResult, simulate

ROOT = Path(__file__).resolve().parents[1]
PLANT = ROOT / "architectures" / "process_plant.yaml"

FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None)

RELAY_FAULTS = ["bias", "bias_drift", "effectiveness_loss", "noise_increase", "dropout", "stuck"]
# registered types without inputs or required parameters: (type, kind, output)
EXTRAS = [
    ("model.tank", "model", "tank_model"),
    ("planner.setpoint", "functional", "setpoint"),
    ("model.actuator", "model", "actuation"),
    ("model.diffdrive_kinematics", "model", "kinematics"),
]


def _f(draw: Any, lo: float, hi: float) -> float:
    """A float in [lo, hi] rounded to 4 digits (short, readable failing examples)."""
    return round(draw(st.floats(lo, hi, allow_nan=False, allow_infinity=False)), 4)


def _improvement(draw: Any, module: str) -> dict[str, Any]:
    method = draw(st.sampled_from(["sensitivity", "sensitivity", "table", "rollout"]))
    worse = draw(st.integers(0, 5)) == 0  # now and then an action that makes things worse
    if method == "sensitivity":
        return {"method": "sensitivity",
                "delta_theta": _f(draw, 0.0, 0.5) if worse else _f(draw, -1.0, -0.1)}
    if method == "table":
        return {"method": "table", "values": {module: _f(draw, -0.5, 0.0) if worse else
                                              _f(draw, 0.1, 2.0)},
                "default": _f(draw, -0.5, 0.5)}
    return {"method": "rollout", "horizon_s": _f(draw, 0.1, 0.6)}


def _change(src: dict[str, Any], dst: dict[str, Any]) -> str | None:
    """The structural action kind that leads from ``src`` to ``dst`` (archself.check's rule)."""
    added = set(dst["modules"]) - set(src["modules"])
    removed = set(src["modules"]) - set(dst["modules"])
    if added and removed:
        return "substitute"
    if added:
        return "activate"
    if removed:
        return "deactivate"
    off_src = {tuple(p) for p in src.get("disabled_edges", [])}
    off_dst = {tuple(p) for p in dst.get("disabled_edges", [])}
    return "rewire" if off_src != off_dst else None


@st.composite
def adaptive_architectures(draw: Any) -> dict[str, Any]:
    """Plain data of a small valid architecture file that exercises the whole loop."""
    n = draw(st.integers(3, 6))
    relays = [f"m{i}" for i in range(n)]
    hub, out = relays[0], relays[-1]  # objective: reference m0.signal, actual m{n-1}.signal
    extras = draw(st.lists(st.sampled_from(EXTRAS), max_size=2, unique=True))
    modules: dict[str, Any] = {}
    noisy = draw(st.sampled_from(relays))  # at least one relay whose r_i exceeds its nominal
    for i, m in enumerate(relays):
        spec: dict[str, Any] = {"kind": "physical" if i == 0 else "functional",
                                "type": "generic.relay"}
        noise = _f(draw, 0.3, 1.0) if m == noisy else draw(st.sampled_from([0.0, 0.0, 0.05, 0.3]))
        spec["params"] = {"gain": {"value": _f(draw, 0.5, 1.5), "min": 0.0, "max": 2.0},
                          "noise": {"value": noise, "min": 0.0, "max": 1.0}}
        if m == noisy or draw(st.booleans()):
            spec["residual"] = {"signal": "deviation", "nominal": _f(draw, 0.05, 0.2),
                                "sensitivity": _f(draw, 0.5, 2.0),
                                "smoothing_s": draw(st.sampled_from([0.0, 0.0, 0.5, 2.0]))}
        if draw(st.integers(0, 3)) == 0:
            spec["resources"] = {"power_w": _f(draw, 0.0, 5.0)}
        if i > 0 and draw(st.integers(0, 4)) == 0:
            spec["constraints"] = {"requires": [hub]}  # the hub is in every configuration
        modules[m] = spec
    for j, (typ, kind, _out) in enumerate(extras):
        modules[f"x{j}"] = {"kind": kind, "type": typ}

    # edges: hub -> every relay (connectivity of any configuration holding the hub),
    # extra forward edges, at most one weak backward edge; extras feed the hub
    raw: list[list[Any]] = [[hub, m, _f(draw, 0.05, 1.0), "signal"] for m in relays[1:]]
    for i in range(2, n):
        for j in range(1, i):
            if draw(st.integers(0, 2)) == 0:
                raw.append([relays[j], relays[i], _f(draw, 0.05, 1.0), "signal"])
    if n > 2 and draw(st.booleans()):
        i = draw(st.integers(2, n - 1))
        j = draw(st.integers(1, i - 1))
        raw.append([relays[i], relays[j], _f(draw, 0.01, 0.3), "signal"])
    for j, (_typ, _kind, output) in enumerate(extras):
        raw.append([f"x{j}", hub, _f(draw, 0.05, 0.5), output])
    incoming: dict[str, float] = {}
    for _s, t, w, _c in raw:
        incoming[t] = incoming.get(t, 0.0) + w
    edges = []
    for s, t, w, c in raw:  # every column of W sums to ≤ 0.9, so ρ(W) ≤ 0.9
        scaled = w * min(1.0, 0.9 / incoming[t])
        edges.append({"from": s, "to": t, "weight": math.floor(scaled * 1e4) / 1e4, "carries": c})
    optional = [m for m in modules if m not in (hub, out)]
    spare = [(e["from"], e["to"]) for e in edges if e["from"] != hub and e["from"] in relays]

    # configurations: c0 (initial), then each derived from an earlier one by dropping,
    # adding or swapping modules or by switching edges off or on
    def make(active: set[str], off: list[list[str]]) -> dict[str, Any]:
        conf: dict[str, Any] = {"modules": [m for m in modules if m in active]}
        off = [p for p in off if p[0] in active and p[1] in active]
        if off:
            conf["disabled_edges"] = off
        return conf

    c0 = make({hub, out, noisy, *draw(st.lists(st.sampled_from(optional), unique=True))}, [])
    confs: dict[str, dict[str, Any]] = {"c0": {"initial": True, **c0}}
    for k in range(1, draw(st.integers(2, 4))):
        base = confs[draw(st.sampled_from(sorted(confs)))]
        have = set(base["modules"])
        off = [list(p) for p in base.get("disabled_edges", [])]
        present = [m for m in optional if m in have]
        absent = [m for m in optional if m not in have]
        live = [p for p in spare if p[0] in have and p[1] in have]
        ops = [op for op, ok in (("drop", present), ("add", absent),
                                 ("swap", present and absent), ("rewire", live)) if ok]
        op = draw(st.sampled_from(ops))
        if op == "drop":
            have -= set(draw(st.lists(st.sampled_from(present), min_size=1, unique=True)))
        elif op == "add":
            have |= set(draw(st.lists(st.sampled_from(absent), min_size=1, unique=True)))
        elif op == "swap":
            have = (have - {draw(st.sampled_from(present))}) | {draw(st.sampled_from(absent))}
        else:
            flip = [list(p) for p in draw(st.lists(st.sampled_from(live), min_size=1,
                                                   unique=True))]
            off = [p for p in off if p not in flip] + [p for p in flip if p not in off]
        confs[f"c{k}"] = make(have, off)
    names = list(confs)

    actions: list[dict[str, Any]] = []
    pairs = [(a, b) for a in names for b in names if a != b and _change(confs[a], confs[b])]
    chosen_pairs = draw(st.lists(st.sampled_from(pairs), max_size=5, unique=True)) if pairs else []
    first = [p for p in pairs if p[0] == "c0"]  # one leaves the initial configuration
    if first:
        chosen_pairs = list(dict.fromkeys([draw(st.sampled_from(first)), *chosen_pairs]))
    for a, b in chosen_pairs:
        src, dst = confs[a], confs[b]
        gone = [m for m in src["modules"] if m not in dst["modules"]]
        pool = gone or src["modules"]
        module = noisy if noisy in pool and draw(st.booleans()) else draw(st.sampled_from(pool))
        actions.append({"id": f"{a}_to_{b}", "module": module, "kind": _change(src, dst),
                        "to": b, "applies_in": [a], "cost": _f(draw, 0.0, 1.0),
                        "improvement": _improvement(draw, module)})
    for k in range(draw(st.integers(0, 2))):
        m = noisy if draw(st.booleans()) else draw(st.sampled_from(relays))
        values = {"noise": draw(st.sampled_from([0.0, 0.01, 0.5]))}
        if draw(st.booleans()):
            values["gain"] = _f(draw, 0.0, 2.0)
        act = {"id": f"tune{k}", "module": m, "kind": "parameter_update", "set": values,
               "cost": _f(draw, 0.0, 0.5), "improvement": _improvement(draw, m)}
        where = [c for c in names if m in confs[c]["modules"]]
        if where and draw(st.booleans()):
            act["applies_in"] = draw(st.lists(st.sampled_from(where), min_size=1, unique=True))
        actions.append(act)

    duration = draw(st.sampled_from([2.0, 3.0, 4.0]))
    faults = []
    placed = [m for m in relays if any(m in c["modules"] for c in confs.values())]
    for _ in range(draw(st.integers(1, 2))):  # a fault acts on a module of some configuration
        fault: dict[str, Any] = {"module": draw(st.sampled_from(placed or relays)),
                                 "kind": draw(st.sampled_from(RELAY_FAULTS)),
                                 "onset_s": _f(draw, 0.0, duration / 2),
                                 "magnitude": _f(draw, -2.0, 2.0)}
        if draw(st.integers(0, 3)) == 0:
            fault["end_s"] = round(fault["onset_s"] + _f(draw, 0.1, duration), 4)
        if draw(st.booleans()):
            fault["signal"] = "signal"
        faults.append(fault)

    step = draw(st.sampled_from([0.05, 0.1, 0.2]))
    runtime: dict[str, Any] = {
        "step_s": step,
        "period_s": round(step * draw(st.integers(1, 4)), 4),
        "objective": {"actual": f"{out}.signal", "reference": f"{hub}.signal",
                      # J_ref² is the floor of the Lyapunov test: a large J_ref lets it pass
                      "acceptable": _f(draw, 0.0, 0.5) if draw(st.booleans()) else
                      _f(draw, 2.0, 10.0)},
        "normalization": draw(st.sampled_from(["nominal", "nominal", "none"])),
        "warmup_steps": draw(st.integers(0, 3)),
        "dwell_s": draw(st.sampled_from([0.0, 0.0, 0.5, 2.0])),
        "cost_weight": _f(draw, 0.0, 2.0),
        "stability": {"margin": _f(draw, 1e-4, 0.1), "lyapunov_alpha": _f(draw, 1e-4, 0.1),
                      "horizon_steps": draw(st.integers(1, 20))},
        "max_spectral_radius": _f(draw, 0.91, 0.99),
    }
    selector = draw(st.sampled_from(["threshold", "top_k", "hysteresis"]))
    if selector == "threshold":
        runtime["threshold"] = _f(draw, 0.1, 3.0)
    elif selector == "top_k":
        runtime["top_k"] = draw(st.integers(1, n))
    else:
        on = _f(draw, 0.2, 3.0)
        runtime["hysteresis"] = {"on": on, "off": round(on * _f(draw, 0.0, 0.9), 4)}
    data: dict[str, Any] = {
        "archself": 1,
        "name": "fuzz",
        "modules": modules,
        "edges": edges,
        "configurations": confs,
        "actions": actions,
        "scenarios": {"s": {"duration_s": duration, "seed": draw(st.integers(0, 2**16)),
                            "faults": faults}},
        "runtime": runtime,
    }
    if draw(st.booleans()):
        data["constraints"] = [{"resource": "power_w", "max": _f(draw, 2.0, 20.0)}]
    return data


def _load(data: dict[str, Any], file: str = "fuzz.yaml") -> Architecture:
    """Load and check the JSON text of ``data`` (JSON is YAML 1.2); fail on error findings."""
    loaded = load_text(json.dumps(data), file)
    findings = check(loaded)
    assert not has_errors(findings), [str(f) for f in findings]
    return loaded.arch


def _run(arch: Architecture, scenario: str, seed: int | None = None) -> tuple[RunResult, MapeK]:
    loop = MapeK(arch)
    return simulate(arch, scenario, seed=seed, adapt=loop), loop


def _assert_sane(arch: Architecture, res: RunResult, loop: MapeK) -> None:
    confs = set(arch.configurations)
    assert isinstance(res.decisions, list)
    assert len(res.decisions) == loop.cycle
    assert res.final_configuration in confs
    for s in res.switches:
        assert s["from"] in confs and s["to"] in confs and s["from"] != s["to"], s
    json.dumps(res.trace(), allow_nan=False)  # the trace is plain JSON


# ------------------------------------------------------------------ generated files
@FUZZ
@given(adaptive_architectures())
def test_generated_files_check_without_errors(data: dict[str, Any]) -> None:
    arch = _load(data)
    assert len(arch.configurations) >= 2 and arch.scenarios["s"].faults


@FUZZ
@given(adaptive_architectures())
def test_adaptive_simulation_of_generated_file(data: dict[str, Any]) -> None:
    arch = _load(data)
    seed = arch.scenarios["s"].seed
    res, loop = _run(arch, "s", seed)
    _assert_sane(arch, res, loop)
    event(f"switches: {min(len(res.switches), 2)}, updates: {min(len(loop.updates), 2)}")
    assert len(res.series["t"]) == round(arch.scenarios["s"].duration_s / arch.runtime.step_s)
    again, _ = _run(_load(data), "s", seed)  # a fresh loop and system, the same seed
    assert again.switches == res.switches
    assert json.dumps(again.trace()) == json.dumps(res.trace())


def _executes(data: dict[str, Any], what: str) -> bool:
    arch = _load(data)
    _, loop = _run(arch, "s")
    return bool(loop.switches if what == "switch" else loop.updates)


def test_generated_files_reach_plan_and_execute() -> None:
    """The strategy reaches Execute: a structural switch and a parameter update happen."""
    quick = settings(max_examples=80, phases=[Phase.generate], database=None, derandomize=True)
    for what in ("switch", "update"):
        find(adaptive_architectures(), lambda d, w=what: _executes(d, w), settings=quick)


def test_scalar_objective_error_is_finite() -> None:
    """Regression (found by this fuzzing): J of scalar objective signals (relays).

    ``LiveSystem.state_error`` indexed the 0-d array of a scalar signal, so
    ``objective_error`` raised IndexError: the Monitor logged J_obs = NaN, every
    rollout estimate failed and every Lyapunov test failed closed, so the loop of a
    file with scalar objective signals could never make a structural change.
    """
    from archself.model.generate import generate_architecture
    from archself.runtime.planner import rollout_improvement
    from archself.system.live import compile_system

    arch = load_text(generate_architecture(4, seed=1)).arch
    system = compile_system(arch, arch.initial_configuration(), seed=0)
    system.step()
    assert system.state_error().shape == (1,)
    assert math.isfinite(system.objective_error())
    tune = Action(id="t", module="m1", kind="parameter_update", set={"gain": 0.5}, cost=0.0,
                  improvement={"method": "rollout", "horizon_s": 0.3})
    assert math.isfinite(rollout_improvement(system, tune, 0.3))


# ------------------------------------------------------------------ mutations
def _short_plant() -> dict[str, Any]:
    """process_plant.yaml on a 30 s horizon: onsets scaled into it, warm-up and dwell cut."""
    data, _ = load_data(PLANT.read_text(encoding="utf-8"), str(PLANT))
    for sc in data["scenarios"].values():
        scale = 30.0 / sc["duration_s"]
        sc["duration_s"] = 30.0
        for f in sc.get("faults", []):
            f["onset_s"] = round(f["onset_s"] * scale, 3)
            if "end_s" in f:
                f["end_s"] = round(f["end_s"] * scale, 3)
    data["runtime"].update(warmup_steps=3, dwell_s=5.0)
    return data


PLANT_DATA = _short_plant()


def _numbers(node: Any, prefix: tuple = ()) -> list[tuple]:
    """Paths of the numbers (not booleans) the mutations may change."""
    if isinstance(node, dict):
        return [p for k, v in node.items() for p in _numbers(v, (*prefix, k))]
    if isinstance(node, list):
        return [p for i, v in enumerate(node) for p in _numbers(v, (*prefix, i))]
    return [prefix] if isinstance(node, (int, float)) and not isinstance(node, bool) else []


def _mutable(path: tuple) -> bool:
    """Weights, thresholds and runtime settings, fault magnitudes/onsets, nominal levels."""
    last = path[-1]
    return (
        path[0] == "runtime" or last in ("weight", "magnitude", "onset_s", "end_s", "cost",
                                         "nominal", "delta_theta", "horizon_s", "duration_s")
    )


@st.composite
def mutated(draw: Any, base: dict[str, Any]) -> dict[str, Any]:
    data = copy.deepcopy(base)
    paths = [p for p in _numbers(data) if _mutable(p)]
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["scale", "scale", "set", "drop_action", "drop_fault"]))
        if op == "drop_action" and data.get("actions"):
            del data["actions"][draw(st.integers(0, len(data["actions"]) - 1))]
            paths = [p for p in _numbers(data) if _mutable(p)]
            continue
        if op == "drop_fault":
            sc = data["scenarios"][draw(st.sampled_from(sorted(data["scenarios"])))]
            if sc.get("faults"):
                del sc["faults"][draw(st.integers(0, len(sc["faults"]) - 1))]
                paths = [p for p in _numbers(data) if _mutable(p)]
            continue
        if not paths:
            continue
        path = draw(st.sampled_from(paths))
        parent: Any = data
        for p in path[:-1]:
            parent = parent[p]
        old = parent[path[-1]]
        if isinstance(old, int) and not isinstance(old, bool) and path[-1] not in (
            "weight", "magnitude", "onset_s", "end_s", "cost", "nominal", "duration_s"
        ):
            parent[path[-1]] = max(0, old + draw(st.integers(-3, 3)))
        elif op == "scale":
            parent[path[-1]] = round(old * _f(draw, 0.0, 3.0), 6)
        else:
            parent[path[-1]] = _f(draw, -1.0, 0.0) if draw(st.integers(0, 4)) == 0 else _f(
                draw, 0.0, 5.0)
    for sc in data["scenarios"].values():  # a short horizon, whatever the mutation did
        sc["duration_s"] = min(max(float(sc["duration_s"]), 0.5), 30.0)
    return data


def _simulate_if_valid(data: dict[str, Any], scenario: str) -> None:
    try:
        loaded = load_text(json.dumps(data), "mutated.yaml")
    except ArchselfError:
        event("mutant refused by the loader")
        return  # the mutation broke the file: the loader said so in its own words
    if has_errors(check(loaded)):
        event("mutant refused by check")
        return
    arch = loaded.arch
    res, loop = _run(arch, scenario, seed=1)
    _assert_sane(arch, res, loop)
    event(f"mutant simulated; switches: {len(res.switches)}, updates: {len(loop.updates)}")


@settings(max_examples=40, deadline=None, derandomize=True, database=None)
@given(st.data())
def test_mutated_process_plant_simulates(data: st.DataObject) -> None:
    mutant = data.draw(mutated(PLANT_DATA), label="mutant")
    scenario = data.draw(st.sampled_from(sorted(mutant["scenarios"])), label="scenario")
    _simulate_if_valid(mutant, scenario)


@FUZZ
@given(st.data())
def test_mutated_generated_files_simulate(data: st.DataObject) -> None:
    base = data.draw(adaptive_architectures(), label="base")
    _simulate_if_valid(data.draw(mutated(base), label="mutant"), "s")
