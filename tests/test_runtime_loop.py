"""The MAPE-K loop (Algorithm 1) against a fake live system: safety, dwell, budgets, log."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_runtime_fakes import FakeSystem, high, make_arch, run_loop

import archself.runtime as runtime_pkg
from archself.runtime import InfluenceSolver, MapeK, explain
from archself.runtime.knowledge import Knowledge
from archself.runtime.monitor import Monitor, filter_gain, module_residual
from archself.runtime.planner import (
    budget_violations,
    constraint_violations,
    estimate_improvement,
)
from archself.runtime.stability import eigenvalue_margin, lyapunov_decrease

STABLE = [[-1.0, 0.0], [0.0, -2.0]]
UNSTABLE = [[0.5, 0.0], [0.0, -2.0]]


def lin(**by_conf):
    base = {"base": STABLE, "alt_est": STABLE, "alt_ctl": STABLE, "bad": UNSTABLE, "heavy": STABLE}
    base.update(by_conf)
    return base


# --------------------------------------------------------------------------- genericity
DIFFDRIVE = Path(__file__).resolve().parents[1] / "architectures" / "diffdrive.yaml"
# Robot names that are also generic words the runtime legitimately uses: `planner`
# (the robot's path planner; the runtime's Plan stage, planner.py), `nominal` (a
# scenario; the runtime's residual normalization mode), `actuator` (the last part of
# the type `model.actuator`; a generic kind of module).
GENERIC_WORDS = frozenset({"planner", "nominal", "actuator"})


def robot_names() -> set[str]:
    """Every name diffdrive.yaml declares, lower-case, minus :data:`GENERIC_WORDS`.

    Modules, configurations, scenarios, action ids, the file's ``name`` and the last
    part of each module type (``sensor.encoders`` -> ``encoders``); names ending in
    ``s`` also in the singular (``encoder``).
    """
    from archself.model.loader import load_architecture

    arch = load_architecture(DIFFDRIVE).arch
    names = set(arch.modules) | set(arch.configurations) | set(arch.scenarios)
    names |= {a.id for a in arch.actions}
    names |= {spec.type.rsplit(".", 1)[-1] for spec in arch.modules.values()}
    names.add(arch.name)
    names |= {n[:-1] for n in names if n.endswith("s") and len(n) > 3}
    return {n.lower() for n in names} - GENERIC_WORDS


def name_pattern(names: set[str]) -> re.Pattern[str]:
    """Whole words (``_`` counts as a letter), case-insensitive, plural ``s`` too."""
    words = "|".join(map(re.escape, sorted(names, key=lambda n: (-len(n), n))))
    return re.compile(rf"(?<![A-Za-z0-9_])({words})s?(?![A-Za-z0-9_])", re.IGNORECASE)


def name_hits(names: set[str], folder: Path | None = None) -> list[str]:
    """``file:line: 'name' in <line>`` for every robot name in ``archself/runtime/*.py``."""
    folder = folder or Path(runtime_pkg.__file__).parent
    pattern = name_pattern(names)
    hits = []
    for path in sorted(folder.glob("*.py")):
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            hits += [
                f"{path.name}:{n}: {m.group(1)!r} in {line.strip()}" for m in pattern.finditer(line)
            ]
    return hits


def test_robot_names_come_from_the_file():
    names = robot_names()
    # configurations, action ids and scenarios, not only modules (a4 was once missed)
    assert {"a1", "a4", "wheel_left", "compensate_left_wheel", "fallback_odometry_asym"} <= names
    assert {"imu_drift", "gps_dropout", "diffdrive", "wheel", "encoder", "spline"} <= names
    assert not names & GENERIC_WORDS
    pattern = name_pattern(names)
    found = [m.group(1).lower() for m in pattern.finditer("go to A4; wheels; use_ekf_gps_asym.")]
    assert found == ["a4", "wheel", "use_ekf_gps_asym"]
    assert not pattern.search("a41 xa4 wheel_leftover planner nominal my_gps")


def test_no_robot_names_in_runtime():
    files = sorted(Path(runtime_pkg.__file__).parent.glob("*.py"))
    assert len(files) >= 8
    hits = name_hits(robot_names())
    assert hits == [], "\n".join(hits)


# --------------------------------------------------------------------------- pure pieces
def test_filter_and_residual():
    assert filter_gain(1.0, 0.0) == 1.0
    assert module_residual(0.15, 2.0, 0.1) == pytest.approx(1.0)
    assert module_residual(0.05, 2.0, 0.1) == 0.0
    assert module_residual(-0.3, 1.0, 0.1, "none") == pytest.approx(0.3)
    assert module_residual(math.nan, 1.0, 0.1) == 0.0


def test_stability_tests():
    assert eigenvalue_margin(STABLE, 0.001).ok
    v = eigenvalue_margin(UNSTABLE, 0.001)
    assert not v.ok and v.value == pytest.approx(0.5)
    assert not eigenvalue_margin([[-1e-4]], 0.001).ok  # inside the margin
    assert not eigenvalue_margin([[math.nan]], 0.001).ok
    assert lyapunov_decrease([1.0, 0.5, 0.25], 0.01, 1e-6).ok
    assert not lyapunov_decrease([1.0, 2.0, 4.0], 0.01, 1e-6).ok
    assert not lyapunov_decrease([1.0, math.nan], 0.01, 1e-6).ok
    assert lyapunov_decrease([1e-3, 2e-3], 0.01, 0.25).method == "lyapunov-floor"


def test_budget_and_constraints():
    arch = make_arch()
    assert budget_violations(arch, arch.configurations["base"].modules) == []
    assert budget_violations(arch, arch.configurations["heavy"].modules) == ["power_w 54 > 20"]
    assert constraint_violations(arch, ["src"]) == []


def test_monitor_nan_and_unavailable_never_crash():
    arch = make_arch()

    def sig(t, c):
        return {"est_a": {"innov": math.nan}, "ctl_a": {"track": "garbage"}, "act": {}}

    system = FakeSystem(arch, sig, unavailable={"src"})
    k = Knowledge(arch)
    mon = Monitor(arch, k.names)
    obs = mon.observe(system, k.active)
    assert np.all(obs.r == 0.0)
    assert obs.kappa["est_a"].residual_ok is False
    assert obs.kappa["ctl_a"].residual_ok is False
    assert obs.kappa["src"].available is False
    assert obs.r_global == pytest.approx(0.5 - 1.0)


def test_monitor_survives_failing_system():
    class Broken(FakeSystem):
        def local_signals(self):
            raise RuntimeError("boom")

        def objective_error(self):
            raise RuntimeError("boom")

    arch = make_arch()
    loop = MapeK(arch)
    assert loop(Broken(arch)) == []
    rec = loop.decisions[-1].to_dict()
    assert rec["j_obs"] is None
    json.dumps(rec, allow_nan=False)


# --------------------------------------------------------------------------- the loop
def test_multi_hop_attribution_in_loop():
    """A residual at the source shows up downstream, attenuated along the path."""
    arch = make_arch()
    loop = MapeK(arch)
    system = FakeSystem(arch, high("src", "err", 0.2), linearizations=lin())
    system.step()
    loop(system)
    z = loop.decisions[-1].z
    r = loop.decisions[-1].r
    assert r["src"] == pytest.approx(1.0)
    # src -> est_a (0.5) -> ctl_a (0.5) -> act (0.4) -> src (0.3): a loop
    loop_gain = 0.5 * 0.5 * 0.4 * 0.3
    assert z["src"] == pytest.approx(1.0 / (1.0 - loop_gain))
    assert z["est_a"] == pytest.approx(0.5 * z["src"])
    assert z["ctl_a"] == pytest.approx(0.25 * z["src"])
    assert z["act"] == pytest.approx(0.1 * z["src"])


def test_switches_on_estimator_fault_and_logs():
    arch = make_arch()
    loop = MapeK(arch)
    system = FakeSystem(arch, high("est_a", "innov"), linearizations=lin())
    switches = run_loop(loop, system, 3.0)
    assert [s["to"] for s in switches] == ["alt_est"]
    assert switches[0]["action"] == "swap_est" and switches[0]["from"] == "base"
    assert system.configuration == "alt_est"
    assert loop.knowledge.configuration == "alt_est"
    g = loop.knowledge.graph
    assert g.nodes["est_b"]["active"] and not g.nodes["est_a"]["active"]
    assert g.edges["est_b", "ctl_a"]["active"] and not g.edges["est_a", "ctl_a"]["active"]
    assert loop.knowledge.t_last == pytest.approx(1.0)
    log = loop.log()
    text = json.dumps(log, allow_nan=False)
    assert "swap_est" in text
    first = log[0]
    assert first["chosen"]["action"] == "swap_est"
    reasons = {e["action"]: e["rejected"] for e in first["evaluations"]}
    assert reasons["unsafe"] == "unstable"
    assert reasons["heavy_est"] == "budget"
    story = explain(loop.decisions)
    assert "switched base → alt_est by swap_est" in story
    assert "UNSTABLE" in story
    assert explain(log) == story  # works on the saved JSON too


def test_planted_destabilizing_alternative_is_never_executed():
    """``unsafe`` scores best (cost 0, Δθ = −1) but its closed loop has Re λ = +0.5."""
    arch = make_arch(dwell_s=0.0)
    loop = MapeK(arch)
    # only the unsafe action and the stable one are possible: disable the budget option
    system = FakeSystem(arch, high("est_a", "innov"), linearizations=lin(alt_est=UNSTABLE))
    switches = run_loop(loop, system, 20.0)
    assert switches == []  # both alternatives unstable: nothing is executed
    assert all(name != "bad" for _, name in system.applied)
    evs = [e for d in loop.decisions for e in d.evaluations if e.action == "unsafe"]
    assert evs and all(e.rejected == "unstable" for e in evs)
    assert all(e.score is not None and e.score > 0 for e in evs)  # it would have won
    # with a stable alternative, the stable one is chosen, never the unsafe one
    loop2 = MapeK(arch)
    system2 = FakeSystem(arch, high("est_a", "innov"), linearizations=lin())
    switches2 = run_loop(loop2, system2, 20.0)
    assert [s["to"] for s in switches2][:1] == ["alt_est"]
    assert "bad" not in [s["to"] for s in switches2]


def test_lyapunov_path_without_a_model():
    """No linearization: the Lyapunov rollout on a snapshot rejects a diverging target."""
    arch = make_arch()
    grow = [[0.8, 0.0], [0.0, 0.8]]
    decay = [[-2.0, 0.0], [0.0, -2.0]]
    loop = MapeK(arch)
    system = FakeSystem(
        arch,
        high("est_a", "innov"),
        linearizations={},
        dynamics={"base": decay, "alt_est": decay, "bad": grow, "heavy": decay},
        x0=(3.0, 1.0),
    )
    system.step()
    loop(system)
    rec = loop.decisions[-1]
    by = {e.action: e for e in rec.evaluations}
    assert by["unsafe"].rejected == "unstable"
    assert by["unsafe"].stability["method"] == "lyapunov"
    assert by["swap_est"].stability["ok"] and rec.chosen["action"] == "swap_est"
    assert system.configuration == "alt_est"
    assert system.t == pytest.approx(0.1)  # the rollouts ran on snapshots only


def test_lyapunov_near_reference_uses_floor():
    arch = make_arch()
    loop = MapeK(arch)
    system = FakeSystem(
        arch,
        high("est_a", "innov"),
        linearizations={},
        x0=(1e-3, 0.0),
        dynamics={"alt_est": [[0.01, 0.0], [0.0, 0.01]], "bad": [[5.0, 0], [0, 5.0]]},
    )
    system.step()
    loop(system)
    by = {e.action: e for e in loop.decisions[-1].evaluations}
    assert by["swap_est"].stability["method"] == "lyapunov-floor"
    assert by["swap_est"].stability["ok"]


def test_stability_check_fails_closed():
    arch = make_arch()

    def boom(_):
        raise RuntimeError("no model")

    loop = MapeK(arch)
    system = FakeSystem(arch, high("est_a", "innov"), linearizations=lin(alt_est=boom))
    system.step()
    loop(system)
    by = {e.action: e for e in loop.decisions[-1].evaluations}
    assert by["swap_est"].rejected == "unstable"
    assert "linearization failed" in by["swap_est"].detail
    assert system.configuration == "base"


def test_dwell_time_under_flickering_fault():
    """A fault toggling every 3 s would make the loop chatter; T_min = 10 s prevents it."""
    arch = make_arch(dwell_s=10.0)

    def flicker(t, conf):
        on = int(t // 3.0) % 2 == 0
        est = "est_a" if conf == "base" else "est_b"
        return {est: {"innov": 1.0 if on else 0.0}}

    loop = MapeK(arch)
    system = FakeSystem(arch, flicker, linearizations=lin())
    switches = run_loop(loop, system, 60.0)
    times = [s["t_s"] for s in switches]
    assert len(times) >= 2  # it does adapt, back and forth
    assert all(b - a >= 10.0 - 1e-9 for a, b in zip(times, times[1:], strict=False))
    dwell = [e for d in loop.decisions for e in d.evaluations if e.rejected == "dwell"]
    assert dwell  # the dwell rule was what held it back
    # without dwell it would chatter every few seconds
    loop0 = MapeK(make_arch(dwell_s=0.0))
    sys0 = FakeSystem(loop0.arch, flicker, linearizations=lin())
    times0 = [s["t_s"] for s in run_loop(loop0, sys0, 60.0)]
    assert min(b - a for a, b in zip(times0, times0[1:], strict=False)) < 10.0


def test_hysteresis_keeps_candidate_between_thresholds():
    arch = make_arch(hysteresis={"on": 0.8, "off": 0.3}, dwell_s=0.0)
    current = {"v": 0.0}

    def sig(t, conf):
        return {"act": {"cmd_err": current["v"]}}

    loop = MapeK(arch)
    system = FakeSystem(arch, sig, linearizations=lin(alt_ctl=UNSTABLE))  # never switches
    member = []
    for v in [0.15, 0.2, 0.15, 0.13, 0.135, 0.12]:
        current["v"] = v
        system.step()
        loop(system)
        member.append("act" in loop.decisions[-1].candidates)
    # z_act ≈ r_act·(1 + loop gain): 0.5, 1.0, 0.5, 0.3, 0.35, 0.2 — on at 0.8, off below 0.3
    assert member == [False, True, True, True, True, False]


def test_budget_excludes_over_budget_configuration():
    arch = make_arch()
    loop = MapeK(arch)
    # only the table-driven 'heavy' action would have a huge score; it breaks the power budget
    system = FakeSystem(arch, high("est_a", "innov"), linearizations=lin(alt_est=UNSTABLE))
    run_loop(loop, system, 5.0)
    assert all(name != "heavy" for _, name in system.applied)
    evs = [e for d in loop.decisions for e in d.evaluations if e.action == "heavy_est"]
    assert evs and all(e.rejected == "budget" for e in evs)
    assert "power_w" in evs[0].detail


def test_unavailable_module_makes_action_inadmissible():
    arch = make_arch()
    loop = MapeK(arch)
    system = FakeSystem(arch, high("est_a", "innov"), linearizations=lin(), unavailable={"est_b"})
    # est_b is inactive in base; the system reports it unavailable only if asked: make it so
    system.available = lambda: {n: n != "est_b" for n in set(arch.modules)}
    run_loop(loop, system, 3.0)
    assert system.applied == []
    ev = [e for d in loop.decisions for e in d.evaluations if e.action == "swap_est"]
    assert ev and all(e.rejected == "unavailable" for e in ev)
    assert "est_b" in ev[0].detail


def test_warmup_suppresses_adaptation():
    arch = make_arch(warmup_steps=5)
    loop = MapeK(arch)
    system = FakeSystem(arch, high("est_a", "innov"), linearizations=lin())
    switches = run_loop(loop, system, 10.0)
    assert len(loop.decisions) == 10
    assert [d.phase for d in loop.decisions[:5]] == ["warmup"] * 5
    assert all(
        d.candidates == ["est_a", "ctl_a"] or "est_a" in d.candidates for d in loop.decisions[:5]
    )
    assert all(not d.evaluations and d.chosen is None for d in loop.decisions[:5])
    assert [s["t_s"] for s in switches] == [pytest.approx(6.0)]
    assert "warm-up" in explain(loop.decisions)


def test_parameter_update_is_executed_once():
    arch = make_arch()
    loop = MapeK(arch)
    system = FakeSystem(arch, high("ctl_a", "track", 0.3), linearizations=lin())
    switches = run_loop(loop, system, 5.0)
    assert switches == []
    assert system.param_log == [(pytest.approx(1.0), "ctl_a", {"gain": 2.0})]
    assert loop.updates[0]["set"] == {"gain": 2.0}
    assert loop.knowledge.params["ctl_a"]["gain"] == 2.0
    assert loop.knowledge.graph.nodes["ctl_a"]["params"]["gain"] == 2.0
    later = [e for d in loop.decisions[1:] for e in d.evaluations if e.action == "tune"]
    assert later and all(e.rejected == "no change" for e in later)
    assert "updated ctl_a" in explain(loop.decisions)


def test_rollout_and_table_estimates():
    arch = make_arch()
    data = arch.model_dump(by_alias=True)
    for a in data["actions"]:
        if a["id"] == "swap_est":
            a["improvement"] = {"method": "rollout", "horizon_s": 1.0}
    arch2 = type(arch).model_validate(data)
    loop = MapeK(arch2)
    system = FakeSystem(
        arch2,
        high("est_a", "innov"),
        linearizations=lin(),
        dynamics={"alt_est": [[-5.0, 0.0], [0.0, -5.0]]},
        x0=(2.0, 0.0),
    )
    system.step()
    loop(system)
    by = {e.action: e for e in loop.decisions[-1].evaluations}
    assert by["swap_est"].delta > 0  # faster decay under alt_est: J(no action) > J(action)
    assert system.t == pytest.approx(0.1)
    heavy = next(a for a in arch2.actions if a.id == "heavy_est")
    assert estimate_improvement(heavy, "est_a", 0.0) == 100.0  # table value for est_a
    assert estimate_improvement(heavy, "src", 0.0) == 0.0  # default


def test_top_k_selector_in_loop():
    arch = make_arch(top_k=1)
    loop = MapeK(arch)
    system = FakeSystem(arch, high("act", "cmd_err", 0.5), linearizations=lin())
    system.step()
    loop(system)
    assert loop.decisions[-1].candidates == ["act"]
    assert system.configuration == "alt_ctl"


def test_nominal_signals_never_switch():
    arch = make_arch()
    rng = np.random.default_rng(0)

    def noise(t, conf):  # inside the nominal band of every channel
        return {
            m: {s: float(rng.uniform(-0.1, 0.1))}
            for m, s in [("src", "err"), ("est_a", "innov"), ("ctl_a", "track"), ("act", "cmd_err")]
        }

    loop = MapeK(arch)
    system = FakeSystem(arch, noise, linearizations=lin())
    assert run_loop(loop, system, 50.0) == []
    assert all(not d.candidates for d in loop.decisions)
    assert "no candidate" in explain(loop.decisions)


def test_weights_normalized_when_spectral_radius_too_large():
    arch = make_arch()
    data = arch.model_dump(by_alias=True)
    for e in data["edges"]:
        e["weight"] = 0.99
    data["edges"].append({"from": "est_a", "to": "src", "weight": 0.99, "carries": "back"})
    big = type(arch).model_validate(data)
    k = Knowledge(big)
    assert k.rho_full >= big.runtime.max_spectral_radius
    assert k.w_scale < 1.0
    z = k.influence(np.ones(len(k.names)))
    assert np.all(np.isfinite(z))


def test_factorization_reused_across_cycles():
    arch = make_arch()
    loop = MapeK(arch)
    # a residual just over its band every cycle (r > 0, z below τ): z is solved each cycle
    system = FakeSystem(arch, high("src", "err", 0.11), linearizations=lin())
    assert run_loop(loop, system, 10.0) == []
    assert isinstance(loop.knowledge.solver, InfluenceSolver)
    assert loop.knowledge.solver.factorizations == 1
    assert all(d.z["src"] > 0 for d in loop.decisions[-5:])


def test_quiet_cycles_need_no_solve():
    """r = 0 (every residual inside its band): z = ê = 0 without a factorization."""
    arch = make_arch()
    loop = MapeK(arch)
    run_loop(loop, FakeSystem(arch, lambda t, c: {}, linearizations=lin()), 10.0)
    assert loop.knowledge.solver.factorizations == 0
    last = loop.decisions[-1]
    assert dict(last.z) == dict(last.source) == dict(last.r) == dict.fromkeys(last.r, 0.0)


def test_failed_execution_is_logged_not_raised():
    arch = make_arch()

    class Refuses(FakeSystem):
        def apply_configuration(self, name):
            raise RuntimeError("cannot build")

    loop = MapeK(arch)
    system = Refuses(arch, high("est_a", "innov"), linearizations=lin())
    system.step()
    assert loop(system) == []
    assert "execution of swap_est failed" in loop.decisions[-1].note
    assert loop.knowledge.t_last == -math.inf


_maybe_num = st.one_of(st.none(), st.floats(allow_nan=False, allow_infinity=False), st.integers())
_name = st.sampled_from(["m1", "m2", "m3"])
_eval = st.fixed_dictionaries(
    {"action": _name, "module": _name, "kind": st.sampled_from(["substitute", "parameter_update"])},
    optional={
        "to": st.one_of(st.none(), _name),
        "delta": _maybe_num,
        "score": _maybe_num,
        "stability": st.one_of(
            st.none(),
            st.fixed_dictionaries({}, optional={"ok": st.booleans(), "reason": st.text()}),
        ),
        "rejected": st.one_of(st.none(), st.text()),
        "detail": st.text(),
    },
)
_record = st.fixed_dictionaries(
    {},
    optional={
        "t": _maybe_num,
        "configuration": st.one_of(st.none(), _name),
        "phase": st.sampled_from(["warmup", "adapt"]),
        "j_obs": _maybe_num,
        "r": st.dictionaries(_name, _maybe_num),
        "z": st.dictionaries(_name, _maybe_num),
        "candidates": st.lists(_name, max_size=3),
        "evaluations": st.lists(_eval, max_size=3),
        "chosen": st.one_of(
            st.none(),
            st.fixed_dictionaries(
                {"action": _name},
                optional={"kind": st.sampled_from(["substitute", "parameter_update"])},
            ),
        ),
        "note": st.text(max_size=5),
    },
)


@settings(max_examples=100, deadline=None)
@given(st.lists(_record, max_size=6))
def test_explain_never_crashes_on_partial_records(records):
    assert isinstance(explain(records), str)


def test_explain_import_is_light():
    import subprocess
    import sys

    code = (
        "import sys; from archself.runtime import explain; "
        "heavy = [m for m in ('scipy', 'networkx', 'numpy') if m in sys.modules]; "
        "assert not heavy, heavy"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
