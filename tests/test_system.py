"""The live-system executor, the compiler and the simulation driver."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from archself.errors import CompileError, SimulationError
from archself.model.architecture import Architecture, Scenario
from archself.model.loader import load_architecture
from archself.modules.base import RuntimeModule
from archself.registry import register, unregister
from archself.sim.run import simulate
from archself.system.live import compile_system, stable_hash

DIFFDRIVE = Path(__file__).resolve().parents[1] / "architectures" / "diffdrive.yaml"


@pytest.fixture(scope="module")
def arch() -> Architecture:
    return load_architecture(DIFFDRIVE).arch


# ---------------------------------------------------------------- toy modules
class _Clock(RuntimeModule):
    role = "source"
    outputs = ("value",)

    def step(self, t, dt, inputs):
        return {"value": float(t)}


class _Pass(RuntimeModule):
    role = "relay"
    inputs = ("value",)
    outputs = ("value",)

    def step(self, t, dt, inputs):
        self.seen = inputs.get("value")
        return {"value": self.seen}


class _Flaky(RuntimeModule):
    role = "relay"
    inputs = ("value",)
    outputs = ("value",)

    def step(self, t, dt, inputs):
        if 0.5 <= t < 1.0:
            raise RuntimeError("boom")
        if 1.0 <= t < 1.5:
            return {"value": math.nan}
        return {"value": inputs.get("value")}


class _Gappy(RuntimeModule):
    role = "source"
    outputs = ("value",)

    def step(self, t, dt, inputs):
        return {"value": None if round(t / dt) % 2 else -float(t)}


TOYS = {"toy.clock": _Clock, "toy.pass": _Pass, "toy.flaky": _Flaky, "toy.gappy": _Gappy}


@pytest.fixture
def toys():
    for k, c in TOYS.items():
        register(k)(c)
    yield
    for k in TOYS:
        unregister(k)


def toy_arch(modules: dict[str, str], edges: list[dict], confs=None) -> Architecture:
    return Architecture.model_validate(
        {
            "archself": 1,
            "name": "toy",
            "modules": {n: {"kind": "functional", "type": t} for n, t in modules.items()},
            "edges": [{"weight": 0.1, "carries": "value", **e} for e in edges],
            "configurations": confs or {"c": {"modules": list(modules)}},
            "runtime": {
                "step_s": 0.05,
                "period_s": 1.0,
                "cost_weight": 0.5,
                "threshold": 0.5,
                "objective": {"actual": "src.value", "reference": "src.value"},
                "stability": {"margin": 0.001, "lyapunov_alpha": 0.01, "horizon_steps": 5},
            },
        }
    )


# ---------------------------------------------------------------- executor
def test_order_respects_active_edges(arch):
    s = compile_system(arch, "a1", seed=1)
    order = s.execution_order
    assert order[0] == "chassis"  # non-feedthrough modules publish first
    pos = {n: i for i, n in enumerate(order)}
    for i in s.active_edges:
        e = arch.edges[i]
        if type(s.modules[e.target]).direct_feedthrough:
            assert pos[e.source] < pos[e.target], (e.source, e.target)
    assert s.active == set(arch.configurations["a1"].modules)


def test_output_types_are_learnt_per_system(arch, monkeypatch):
    """The non-numeric output types a system finds (model objects) stay in that system."""
    from archself.system.live import NOT_NUMERIC

    a = compile_system(arch, "a1", seed=1)
    # the model nodes declare finite outputs (not checked): have one checked here
    monkeypatch.setattr(type(a.modules["kinematic_model"]), "finite_outputs", False)
    b = compile_system(arch, "a1", seed=1)
    for _ in range(3):
        a.step()
    assert len(a._not_numeric) > len(NOT_NUMERIC)  # it found model objects
    assert b._not_numeric == set(NOT_NUMERIC) == {str, bool, type(None)}


def test_algebraic_loop_is_a_compile_error(toys):
    a = toy_arch(
        {"src": "toy.clock", "p": "toy.pass", "q": "toy.pass"},
        [{"from": "src", "to": "p"}, {"from": "p", "to": "q"}, {"from": "q", "to": "p"}],
    )
    with pytest.raises(CompileError, match="algebraic loop"):
        compile_system(a, "c", seed=0)


def test_latency_and_uncertainty(toys):
    a = toy_arch(
        {"src": "toy.clock", "late": "toy.pass", "noisy": "toy.pass"},
        [
            {"from": "src", "to": "late", "latency_s": 0.1},
            {"from": "src", "to": "noisy", "uncertainty": 0.5},
        ],
    )
    s = compile_system(a, "c", seed=0)
    got = []
    for _ in range(4000):
        s.step()
        got.append(s.outputs["noisy"]["value"] - s.outputs["src"]["value"])
    assert s.outputs["late"]["value"] == pytest.approx(s.outputs["src"]["value"] - 0.1)
    assert np.std(got) == pytest.approx(0.5, rel=0.05)


def test_failing_module_is_held_and_flagged(toys):
    a = toy_arch(
        {"src": "toy.clock", "f": "toy.flaky", "sink": "toy.pass"},
        [{"from": "src", "to": "f"}, {"from": "f", "to": "sink"}],
    )
    s = compile_system(a, "c", seed=0)
    flags = {}
    for _ in range(40):
        s.step()
        flags[round(s.t - s.dt, 2)] = (s.available()["f"], s.outputs["f"]["value"])
    assert flags[0.45] == (True, pytest.approx(0.45))
    assert flags[0.7] == (False, pytest.approx(0.45))  # raised: last good output held
    assert flags[1.2] == (False, pytest.approx(0.45))  # NaN: not published
    assert flags[1.6] == (True, pytest.approx(1.6))  # recovered


def test_step_function_merges_sources_and_flags_unrouted_inputs(toys):
    """The generated step reads a signal two edges bring as the general path does (the
    later source's value where it is not None), and a required input no edge brings is
    lost every step."""
    a = toy_arch(
        {"src": "toy.clock", "gap": "toy.gappy", "sink": "toy.pass", "alone": "toy.pass"},
        [{"from": "src", "to": "sink"}, {"from": "gap", "to": "sink"}],
    )
    s = compile_system(a, "c", seed=0)
    seen = []
    for _ in range(6):
        s.step()
        seen.append(s.pool()["sink"].seen)
    np.testing.assert_allclose(seen, [-0.0, 0.05, -0.1, 0.15, -0.2, 0.25], atol=1e-12)
    assert s.health() == {"src": None, "gap": None, "sink": None,
                          "alone": "lost input value"}


class _FlakyFinite(_Flaky):
    finite_outputs = True  # a false declaration: its NaN goes unchecked


def test_declared_finite_outputs_skip_the_scan_and_a_fault_restores_it(toys):
    """A type declaring ``finite_outputs`` is not scanned for NaN (its declaration is
    trusted); the same type with a fault on its outputs, or a type declaring nothing,
    is (health.needs_checks)."""
    from archself.system.live import needs_checks, publish_checks

    register("toy.flaky_finite")(_FlakyFinite)
    try:
        a = toy_arch(
            {"src": "toy.clock", "f": "toy.flaky_finite", "sink": "toy.pass"},
            [{"from": "src", "to": "f"}, {"from": "f", "to": "sink"}],
        )
        s = compile_system(a, "c", seed=0)
        for _ in range(25):  # to t = 1.2: it publishes NaN from t = 1.0
            s.step()
        assert s.available()["f"] is True
        assert math.isnan(s.outputs["f"]["value"])  # published unchecked
        mod = s.modules["f"]
        assert not needs_checks(mod)
        assert needs_checks(mod, [("value", object())])  # a fault on its outputs
        assert needs_checks(s.modules["sink"])  # declares nothing: checked
        mod.noise_levels = {"value": 0.1}
        assert needs_checks(mod)  # a stale test to run
        # ... and only that: no NaN scan unless a fault acts on its outputs
        assert publish_checks(mod, "f") == (False, None, (("value", ("f", "value"), 0.1),))
        assert publish_checks(mod, "f", [("value", object())])[0] is True
        assert publish_checks(s.modules["sink"], "sink") == (True, None, ())
    finally:
        unregister("toy.flaky_finite")


class _Sensor(RuntimeModule):
    """Noisy, then silent (0.5–1 s), then frozen (1–1.5 s), then noisy: a type declaring
    finite outputs, a silence limit and a noise level (its checks inlined in the step)."""

    role = "source"
    outputs = ("value", "level", "spread")
    fault_kinds = frozenset({"bias"})
    finite_outputs = True
    max_silence_s = 0.2
    noise_levels = {"value": 0.1, "level": 0.0, "spread": 0.2}

    def step(self, t, dt, inputs):
        if 0.5 <= t < 1.0:
            return {"value": None, "level": None, "spread": None}
        if 1.0 <= t < 1.5:
            return {"value": np.array([3.0, 1.0]), "level": 1.0, "spread": 2.0}
        return {"value": self.rng.standard_normal(2), "level": 1.0,
                "spread": float(self.rng.standard_normal())}


def test_health_checks_with_and_without_fault_and_scan_agree(toys):
    """The step plan's checks of a declared finite-output type (silence and repeats only)
    give, step by step, the reasons and health state of the same type with a fault that
    never acts (the fault path and the NaN scan too); and they do fire."""
    register("toy.sensor")(_Sensor)
    try:
        a = toy_arch({"src": "toy.clock", "sen": "toy.sensor"}, [])
        never = Scenario.model_validate({"duration_s": 2.0, "faults": [
            {"module": "sen", "kind": "bias", "onset_s": 1e6, "magnitude": 1.0}]})
        inline, general = compile_system(a, "c", seed=4), compile_system(a, "c", seed=4,
                                                                          scenario=never)
        seen = []
        for _ in range(40):
            inline.step()
            general.step()
            assert inline.health() == general.health()
            for attr in ("_heard", "_last", "_repeats", "_broken"):
                assert getattr(inline, attr) == getattr(general, attr), attr
            seen.append(inline.health()["sen"])
        assert inline._repeats[("sen", "spread")] == 0  # noisy again
        stale = tuple((s, ("sen", s), v) for s, v in _Sensor.noise_levels.items())
        clock = (True, False, None, ())  # declares nothing: the scan
        assert list(inline._plan.step_functions) == [(clock, (False, False, 0.2, stale))]
        assert list(general._plan.step_functions) == [(clock, (True, True, 0.2, stale))]
        assert "silent for 0.25 s" in seen and "stale value (4 identical values)" in seen
        assert seen[-1] is None and seen.count(None) == 10 + 4 + 3 + 10
    finally:
        unregister("toy.sensor")


def test_keep_records_only_the_series_asked_for(arch):
    """``simulate(keep=())`` records J alone, with the same J and metrics as a full
    recording; an unknown series is a located error with the known names."""
    full = simulate(arch, "nominal", configuration="a1", seed=3)
    lean = simulate(arch, "nominal", configuration="a1", seed=3, keep=())
    some = simulate(arch, "nominal", configuration="a1", seed=3, keep=["actual"])
    assert sorted(lean.series) == ["J", "configuration", "t"]
    assert sorted(some.series) == ["J", "actual", "configuration", "t"]
    assert_array_equal(lean.series["J"], full.series["J"])
    assert_array_equal(some.series["actual"], full.series["actual"])
    assert lean.metrics == full.metrics
    with pytest.raises(SimulationError, match="unknown series 'refrence'; did you mean"):
        simulate(arch, "nominal", configuration="a1", seed=3, keep=["refrence"])


def test_lost_input_marks_unavailable(arch):
    from archself.model.architecture import Fault, Scenario

    sc = Scenario(duration_s=10, faults=[Fault(module="imu", kind="dropout", onset_s=1.0)])
    s = compile_system(arch, "a1", seed=1, scenario=sc)
    for _ in range(40):
        s.step()
    av = s.available()
    assert av["imu"] and not av["odometry"] and av["lqr"]


def test_stable_hash_across_processes():
    code = "from archself.system.live import stable_hash; print(stable_hash('wheel_left'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert int(out.stdout) == stable_hash("wheel_left")


def test_snapshot_is_independent_and_deterministic(arch):
    s = compile_system(arch, "a2", seed=3, scenario="imu_drift")
    for _ in range(100):
        s.step()
    snap = s.snapshot()
    for _ in range(50):
        snap.step()
    assert s.t == pytest.approx(5.0)
    snap2 = s.snapshot()
    for _ in range(50):
        snap2.step()
    assert_array_equal(snap.outputs["ekf"]["pose_estimate"], snap2.outputs["ekf"]["pose_estimate"])
    for _ in range(50):
        s.step()
    assert_array_equal(s.outputs["chassis"]["pose"], snap.outputs["chassis"]["pose"])


def _errors(system, configuration, steps, *, only=None):
    snap = system.snapshot(only=only)
    snap.apply_configuration(configuration)
    out = [snap.objective_error()]
    for _ in range(steps):
        snap.step()
        out.append(snap.objective_error())
    return out


@pytest.mark.parametrize(
    ("fname", "start", "scenario"),
    [
        ("diffdrive.yaml", "a1", "imu_drift"),
        ("process_plant.yaml", "p1", "level_drift"),
        ("motor_drive.yaml", None, None),
        ("generated", None, None),
    ],
)
def test_partial_snapshot_rolls_the_objective_out_as_the_whole(fname, start, scenario):
    """snapshot(only=rollout_scope(c, H)): the objective error of a whole copy, step by step."""
    if fname == "generated":
        from archself.model.generate import generate_architecture
        from archself.model.loader import load_text

        arch = load_text(generate_architecture(400, seed=2, feedback=20)).arch
    else:
        arch = load_architecture(DIFFDRIVE.parent / fname).arch
    start = start or arch.initial_configuration()
    s = compile_system(arch, start, seed=4, scenario=scenario)
    for _ in range(300):
        s.step()
    targets = [start, *sorted({a.to for a in arch.actions if a.to and a.to != start})]
    for conf in targets:
        for steps in (1, 10, 40):
            scope = s.rollout_scope(conf, steps)
            assert_array_equal(
                _errors(s, conf, steps, only=scope), _errors(s, conf, steps), err_msg=conf
            )
    assert len(s.rollout_scope(start, 0)) < len(s.active) or fname != "generated"
    assert s.t == pytest.approx(300 * s.dt)  # the live system did not move


def test_hot_swap_hands_over_state(arch):
    s = compile_system(arch, "a1", seed=1, scenario="imu_drift")
    for _ in range(600):
        s.step()
    odo_pose = s.outputs["odometry"]["pose_estimate"].copy()
    A2 = s.linearization("a2")
    assert s.configuration == "a1" and "ekf" not in s.active  # the query changed nothing
    assert A2 is not None and np.linalg.eigvals(A2).real.max() < 0
    s.apply_configuration("a2")
    assert s.configuration == "a2" and "ekf" in s.active and "odometry" not in s.active
    assert_allclose(s.modules["ekf"].x[:3], odo_pose)
    assert s.history[-1]["from"] == "a1"
    for _ in range(200):
        s.step()
    assert "odometry" not in s.outputs
    assert all(s.available().values())
    assert s.objective_error() < 2.0


def test_set_params_and_state_error(arch):
    s = compile_system(arch, "a1", seed=1)
    s.step()
    k = s.modules["lqr"].K[1, 1]
    s.set_params("lqr", {"q_lateral": 0.01})
    assert s.modules["lqr"].K[1, 1] > k
    err = s.state_error()
    assert err.shape == (2,) and s.objective_error() == pytest.approx(np.linalg.norm(err))
    sig = s.local_signals()
    assert set(sig) == s.active and "command_error" in sig["wheel_left"]


def test_compile_errors(arch):
    with pytest.raises(CompileError, match="unknown configuration"):
        compile_system(arch, "a9", seed=0)
    with pytest.raises(SimulationError, match="unknown scenario"):
        compile_system(arch, "a1", seed=0, scenario="earthquake")
    from archself.model.architecture import Fault, Scenario

    bad = Scenario(duration_s=1, faults=[Fault(module="planner", kind="bias", onset_s=0)])
    with pytest.raises(CompileError, match="does not take"):
        compile_system(arch, "a1", seed=0, scenario=bad)


# ---------------------------------------------------------------- simulation
def test_simulate_is_deterministic(arch, tmp_path):
    # speed is measured by bench/test_bench_sim.py, not asserted here
    a = simulate(arch, "actuator_fault", configuration="a1", seed=5)
    b = simulate(arch, "actuator_fault", configuration="a1", seed=5)
    c = simulate(arch, "actuator_fault", configuration="a1", seed=6)
    assert_array_equal(a.series["J"], b.series["J"])
    assert not np.array_equal(a.series["J"], c.series["J"])
    p1, p2 = tmp_path / "a.json", tmp_path / "b.json"
    a.write_trace(p1)
    b.write_trace(p2)
    assert p1.read_bytes() == p2.read_bytes()
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.json", "b.json"]  # no temp files
    doc = json.loads(p1.read_text())
    assert set(doc) == {"meta", "series", "decisions"}
    assert len(doc["series"]["t"]) == 8000
    assert {
        "reference",
        "actual",
        "estimate",
        "command",
        "J",
        "residual.wheel_left",
        "residual.odometry",
    } <= set(doc["series"])
    d = a.to_dict()
    assert d["mode"] == "fixed" and d["switches"] == [] and d["seed"] == 5
    assert d["configuration"] == d["final_configuration"] == "a1"
    assert set(d["metrics"]) == {"max_error", "final_error", "rms_error", "peak_time_s",
                                 "max_error_m", "final_error_m", "rms_error_m"}  # unit m


def test_simulate_seed_defaults_to_scenario(arch):
    r = simulate(arch, "nominal", configuration="a1")
    assert r.seed == arch.scenarios["nominal"].seed


def test_simulate_calls_adapt_every_period(arch):
    calls = []

    def adapt(system):
        calls.append(system.t)
        if len(calls) == 30:
            system.apply_configuration("a2")
            return [{"t_s": system.t, "from": "a1", "to": "a2", "action": "use_ekf_gps"}]
        return []

    r = simulate(arch, "imu_drift", configuration="a1", adapt=adapt)
    period = arch.runtime.period_s
    assert len(calls) == round(400 / period) and calls[0] == pytest.approx(period)
    assert r.mode == "adaptive" and r.final_configuration == "a2"
    assert r.switches == [
        {"t_s": pytest.approx(30 * period), "from": "a1", "to": "a2", "action": "use_ekf_gps"}
    ]
    assert r.metrics["max_error_m"] < 1.5  # switched early: the EKF keeps the robot on track
    assert np.isnan(r.series["residual.odometry"][-1])  # inactive after the switch


@pytest.mark.skipif(
    not any(ep.name == "example.magnetometer" for ep in entry_points(group="archself.modules")),
    reason="example plugin not installed",
)
def test_plugin_module_runs_in_a_simulation(arch):
    raw = arch.model_dump(by_alias=True, exclude_none=True)
    raw["modules"]["imu"]["type"] = "example.magnetometer"
    raw["modules"]["imu"]["params"] = {"noise_rad": {"value": 0.005}}
    plug = Architecture.model_validate(raw)
    r = simulate(plug, "nominal", configuration="a1")
    assert r.metrics["max_error_m"] < 0.5
