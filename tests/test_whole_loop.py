"""Stability over the whole loop (issue 33): the state contract, the numerical A, the verdicts."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from numpy.testing import assert_allclose
from typer.testing import CliRunner

from archself.check import check
from archself.check.stability import loop_table
from archself.cli import app
from archself.model.loader import load_architecture, load_text
from archself.modules.base import RuntimeModule
from archself.runtime import MapeK
from archself.sim.run import simulate
from archself.system.live import compile_system

from conftest import FIXTURES, ROOT

RELAY = FIXTURES / "valid" / "relay_side_loop.yaml"
SWAP = FIXTURES / "valid" / "actuator_swap.yaml"
ARCHS = ROOT / "architectures"


def _with(text: str, extra: str) -> str:
    old = "horizon_steps: 20}"
    assert text.count(old) == 1
    return text.replace(old, f"horizon_steps: 20, {extra}}}")


# ------------------------------------------------------------------ the state contract
def test_automatic_state_leaves_out_what_configure_sets() -> None:
    class Lag(RuntimeModule):
        def __init__(self, name, params, rng):
            super().__init__(name, params, rng)
            self.y = 0.5
            self.hist = np.array([1.0, 2.0])
            self.count = 3  # an int: a counter, not a state

        def configure(self):
            self.tau = float(self.params.get("tau", 2.0))

    lag = Lag("lag", {}, np.random.default_rng(0))
    assert lag.state_names() == ("y", "hist")
    assert_allclose(lag.state(), [0.5, 1.0, 2.0])
    lag.set_state([4.0, 5.0, 6.0])
    assert lag.y == 4.0 and lag.hist.tolist() == [5.0, 6.0] and lag.tau == 2.0


@pytest.mark.parametrize("fname", ["diffdrive.yaml", "process_plant.yaml", "motor_drive.yaml"])
def test_every_shipped_module_round_trips_its_state(fname: str) -> None:
    arch = load_architecture(ARCHS / fname).arch
    for conf in arch.configurations:
        system = compile_system(arch, conf, seed=0)
        system.run(0.5)
        for name, mod in system.modules.items():
            x = type(mod).state(mod)
            assert x.ndim == 1 and np.all(np.isfinite(x)), name
            type(mod).set_state(mod, x + 0.25)
            assert_allclose(type(mod).state(mod), x + 0.25, err_msg=name)


@pytest.mark.parametrize("fname", ["diffdrive.yaml", "process_plant.yaml", "motor_drive.yaml"])
def test_lane_classes_state_is_the_per_run_state_and_round_trips(fname: str) -> None:
    """check_pack compares each lanes class's per-lane state with its per-run twin's
    state() after 20 steps; set_state writes a lane's row back (the other lane kept)."""
    from archself.lanes.system import LaneSystem
    from archself.testing import check_pack

    arch = load_architecture(ARCHS / fname).arch
    report = check_pack(arch, scenarios=[], seeds=(0, 1), raise_on_error=False)
    assert report.problems == ["no run compared: no scenario, no seed, or neither fixed nor "
                               "adaptive; lanes and per-run runs were not checked"]
    lanes = LaneSystem([compile_system(arch, seed=s) for s in (0, 1)])
    for _ in range(5):
        lanes.step()
    stateful = 0
    for name, mod in lanes.modules.items():
        x = mod.state()
        assert x.shape[0] == 2 and np.all(np.isfinite(x)), name
        stateful += x.shape[1] > 0
        mod.set_state(x[1:] + 0.25, np.array([1]))
        assert_allclose(mod.state(), np.vstack([x[0], x[1] + 0.25]), err_msg=name)
    assert stateful >= 4


def test_check_pack_finds_a_lanes_class_whose_state_is_not_stored(monkeypatch) -> None:
    from archself.testing import check_pack
    from archself_process.lanes_tank import TankPlantLanes

    monkeypatch.setattr(TankPlantLanes, "store", lambda self, lanes: None)
    report = check_pack(ARCHS / "process_plant.yaml", scenarios=[], seeds=(3,),
                        raise_on_error=False)
    bad = [p for p in report.problems if p.startswith("tank (TankPlantLanes), seed 3: lane state")]
    assert len(bad) == 1 and "after 20 steps, per run" in bad[0]


# ------------------------------------------------------------------ the numerical A
BLOCKS = FIXTURES / "valid" / "blocks_loop.yaml"


@pytest.mark.parametrize(("path", "conf"), [
    (ARCHS / "motor_drive.yaml", "m1"), (ARCHS / "motor_drive.yaml", "m2"),
    (ARCHS / "motor_drive.yaml", "m3"), (BLOCKS, "observer"),
])
def test_numerical_a_has_the_declared_models_eigenvalues(path, conf: str) -> None:
    """Every shipped type with a linear model: generic.state_space, generic.actuator,
    generic.sensor, generic.gain, generic.kalman, generic.pid (motor_drive) and
    generic.transfer_function, generic.sum, generic.select, generic.luenberger (blocks_loop):
    both ways agree (the check found two states the packs had left out: the plant's held
    input and the observer's last measurement)."""
    arch = load_architecture(path).arch
    system = compile_system(arch, conf, seed=0)
    system.run(2.0)
    declared = np.linalg.eigvals(system.closed_loop().loop.A)
    numerical = np.linalg.eigvals(np.asarray(system.whole_loop().A))
    # the numerical A has the modules' extra states (the PID's derivative filter, the
    # actuator's rate limiter): their eigenvalues are e^{-N dt} and 0, the rest are equal
    top = np.sort(np.abs(declared))[::-1][:5]
    assert_allclose(np.sort(np.abs(numerical))[::-1][:5], top, rtol=1e-6, atol=1e-8)


def test_ekf_without_a_linear_model_enters_the_whole_loop() -> None:
    """generic.ekf gives no linear model (η multiplies u): the declared loop leaves it out
    and the PI's integrator open (|λ| = 1); the whole loop has its states and is stable."""
    arch = load_architecture(BLOCKS).arch
    system = compile_system(arch, "ekf", seed=0)
    system.run(2.0)
    declared = np.abs(np.linalg.eigvals(system.closed_loop().loop.A))
    assert_allclose(declared.max(), 1.0, atol=1e-9)
    whole = system.whole_loop()
    assert {"ekf.x[0]", "ekf.x[1]"} <= set(whole.labels)
    worst, marginal, unstable = whole.modes()
    assert marginal == [] and unstable == []
    assert_allclose(worst, 0.99594, atol=1e-5)


def test_numerical_a_sees_the_unstable_backup_as_the_declared_models_do() -> None:
    arch = load_architecture(SWAP).arch
    system = compile_system(arch, "hot", seed=0)
    system.run(2.0)
    worst, marginal, unstable = system.whole_loop().modes()
    assert_allclose(worst, 4.394757, rtol=1e-6)
    assert marginal == [] and unstable[0].shares[0][0] == "backup_hot"


def test_columns_grouped_by_reach_give_the_same_a_as_one_by_one(monkeypatch) -> None:
    import archself.system.linearizing as sl

    arch = load_architecture(RELAY).arch
    system = compile_system(arch, "hot", seed=0)
    system.run(1.0)
    grouped = np.asarray(system.whole_loop().A)
    monkeypatch.setattr(sl, "_groups", lambda cols, reach: [[c] for c in cols])
    alone = np.asarray(system.whole_loop().A)
    assert_allclose(grouped, alone, rtol=1e-9, atol=1e-12)
    assert np.count_nonzero(grouped) >= 4


def test_probe_copies_from_one_pickle_give_the_deep_copies_a(monkeypatch) -> None:
    """The check's copies loaded from one pickle (``Clones``) give A bit for bit as deep
    copies of the snapshot do (the fallback when pickle cannot take a value): the
    diff-drive's a1 → a2 over its 24-step map, mid-run with the imu drift on."""
    import archself.system.linearizing as sl

    arch = load_architecture(ARCHS / "diffdrive.yaml").arch
    system = compile_system(arch, "a1", seed=2, scenario=arch.scenarios["imu_drift"])
    system.run(65.0)
    loaded = system.whole_loop("a2", 24)
    made: list[int] = []

    class Unpicklable:
        def __init__(self, snap) -> None:
            made.append(1)
            raise pickle.PicklingError("a value pickle cannot take")

    monkeypatch.setattr(sl, "Clones", Unpicklable)
    deep = system.whole_loop("a2", 24)
    assert made == [1]  # tried once a check, then deep copies
    assert loaded.A.shape == (14, 14) and np.count_nonzero(loaded.A) > 50
    assert_allclose(loaded.A, deep.A, rtol=0, atol=0)
    assert loaded.problems == deep.problems == []
    assert_allclose(loaded.modes()[0], deep.modes()[0], rtol=0, atol=0)


def test_a_discontinuity_leaves_the_configuration_unverified() -> None:
    class Sign(RuntimeModule):
        direct_feedthrough = False
        outputs = ("signal",)

        def __init__(self, name, params, rng):
            super().__init__(name, params, rng)
            self.s = 0.0

        def output(self, t):
            return {"signal": self.s}

        def step(self, t, dt, inputs):
            self.s = 0.5 if self.s >= 0 else 0.0  # a jump at 0
            return {"signal": self.s}

    from archself.system.linearizing import numerical_loop

    arch = load_architecture(RELAY).arch
    system = compile_system(arch, "normal", seed=0)
    system.run(0.5)
    system._pool["pi"] = Sign("pi", {}, np.random.default_rng(0))
    loop = numerical_loop(system)
    assert any("discontinuity" in p and "pi.s" in p for p in loop.problems), loop.problems


# ------------------------------------------------------------------ verdicts at validate
def test_shipped_configurations_are_all_verified_or_marginal() -> None:
    table = {}
    for fname in ("diffdrive.yaml", "process_plant.yaml", "motor_drive.yaml"):
        for v in loop_table(load_architecture(ARCHS / fname).arch):
            table[v.configuration] = v
    assert all(v.verdict in ("verified", "marginal") for v in table.values()), table
    assert all(v.covered == v.stateful > 0 for v in table.values())
    # dead reckoning: the robot's position is integrated and never measured in a1/a4
    for conf in ("a1", "a4"):
        assert table[conf].verdict == "marginal"
        assert all("chassis" in m and "chassis.pose" in m for m in table[conf].marginal)
    # the GPS closes it over its period in a2/a3
    for conf in ("a2", "a3", "p1", "p2", "p3", "p4", "m1", "m2", "m3", "m4"):
        assert table[conf].verdict == "verified", table[conf]
        assert 0.9 < table[conf].max_lambda < 1.0 - 1e-4


def test_a1_is_marginal_in_the_true_position_not_in_the_heading_estimate() -> None:
    """The robot's a1 drifts through its heading, but the heading is not a mode: odometry
    takes each step's heading from the IMU (its error is the IMU's bias, an input of the
    loop), so the marginal modes are the true position's two integrators, which turn a
    heading bias into a growing position error (docs/stability.md)."""
    arch = load_architecture(ARCHS / "diffdrive.yaml").arch
    system = compile_system(arch, "a1", seed=0)
    system.step()
    system.run(float(arch.runtime.stability.settle_s))
    whole = system.whole_loop("a1", 1)
    A, lab = np.asarray(whole.A), whole.labels
    th, yaw = lab.index("odometry.th"), lab.index("chassis.pose[2]")
    assert_allclose(A[th, th], 0.0, atol=1e-6)  # an estimate offset is gone next step
    assert_allclose(A[th, yaw], 1.0, atol=1e-6)  # the true heading, through the IMU
    _, marginal, unstable = whole.modes()
    assert unstable == []
    assert sorted(s for m in marginal for s in m.states) == ["chassis.pose[0]",
                                                             "chassis.pose[1]"]
    assert_allclose([m.magnitude for m in marginal], [1.0, 1.0], atol=1e-9)


def test_relay_side_loop_fails_validate_with_verify_error(tmp_path) -> None:
    runner = CliRunner()
    path = tmp_path / "relay.yaml"
    path.write_text(_with(RELAY.read_text(encoding="utf-8"), "verify: error"), encoding="utf-8")
    result = runner.invoke(app, ["validate", str(path)])
    assert result.exit_code == 1
    assert ": error: configurations.hot: configuration 'hot' is unstable over the whole loop: " \
           "max |λ| = 1.05 per step" in result.stderr
    assert "λ = +1.05 (echo_a 50 %, echo_b 50 %" in result.stderr
    assert ": error: actions[0].to: action 'use_hot' leads to configuration 'hot'" in result.stderr
    assert result.stdout == ""  # a failing file prints nothing on stdout; --json has the table


def test_relay_side_loop_warns_without_error_and_json_carries_the_table(tmp_path) -> None:
    import json

    runner = CliRunner()
    path = tmp_path / "relay.yaml"
    path.write_text(_with(RELAY.read_text(encoding="utf-8"), "verify: warning"), encoding="utf-8")
    result = runner.invoke(app, ["validate", str(path)])
    assert result.exit_code == 0
    assert ": warning: configurations.hot: configuration 'hot' is unstable" in result.stderr
    assert "  hot: unstable, 5/5 stateful modules" in result.stdout
    assert "  normal: verified, 3/3 stateful modules (6 states), max |λ| = 0.949835" in \
        result.stdout
    data = json.loads(runner.invoke(app, ["validate", "--json", str(path)]).stdout)[0]
    rows = {r["configuration"]: r for r in data["stability"]}
    assert rows["hot"]["verdict"] == "unstable"
    assert_allclose(rows["hot"]["max_lambda"], 1.05, rtol=1e-9)
    assert_allclose(rows["normal"]["margin"], 1 - 0.949835, atol=1e-6)
    # off (the default): no table, and one finding that says so (never a silent "ok")
    off = json.loads(runner.invoke(app, ["validate", "--json", str(RELAY)]).stdout)[0]
    assert off["stability"] == [] and off["ok"] is True
    assert [(f["severity"], f["code"], f["path"]) for f in off["findings"]] == [
        ("info", "stability", "runtime.stability.verify")]
    assert "archself validate --stability" in off["findings"][0]["message"]


def test_plain_validate_says_the_whole_loop_was_not_checked() -> None:
    result = CliRunner().invoke(app, ["validate", str(RELAY), str(ARCHS / "motor_drive.yaml")])
    assert result.exit_code == 0
    assert result.stdout.splitlines() == [f"{RELAY}: ok", f"{ARCHS / 'motor_drive.yaml'}: ok"]
    lines = result.stderr.splitlines()
    assert len(lines) == 2  # one line per file, not one per configuration
    assert all(": info: runtime.stability.verify: whole-loop stability not checked" in line
               for line in lines)


def test_validate_stability_runs_the_check_where_the_file_leaves_it_off() -> None:
    import json

    runner = CliRunner()
    result = runner.invoke(app, ["validate", "--stability", str(RELAY)])
    assert result.exit_code == 0
    assert result.stdout.splitlines()[0] == f"{RELAY}: ok (2 warnings)"
    assert "  hot: unstable, 5/5 stateful modules (8 states), max |λ| = 1.050000" in result.stdout
    assert ": warning: configurations.hot: configuration 'hot' is unstable" in result.stderr
    assert ": warning: actions[0].to: action 'use_hot' leads to configuration 'hot'" in \
        result.stderr
    assert "not checked" not in result.stderr
    strict = runner.invoke(app, ["validate", "--stability", "--strict", str(RELAY)])
    assert strict.exit_code == 1 and strict.stdout == ""
    data = json.loads(runner.invoke(app, ["validate", "--stability", "--json",
                                          str(RELAY)]).stdout)[0]
    assert {r["configuration"]: r["verdict"] for r in data["stability"]} == {
        "normal": "verified", "hot": "unstable", "slow": "verified"}
    hot = next(r for r in data["stability"] if r["configuration"] == "hot")
    assert sorted(m.split(" (")[0] for m in hot["unstable"]) == ["λ = +1.05", "λ = -1.05"]
    assert sorted(f["severity"] for f in data["findings"]) == ["warning", "warning"]


def test_marginal_setting_decides_whether_marginal_passes() -> None:
    text = (ARCHS / "diffdrive.yaml").read_text(encoding="utf-8")
    old = "linearize_s: 1.2}"
    assert text.count(old) == 1

    def found(marginal: str):
        t = text.replace(old, f"linearize_s: 1.2, verify: error, marginal: {marginal}}}")
        return [(f.severity, f.path) for f in check(load_text(t, "d.yaml"))
                if f.code == "stability"]

    assert found("pass") == []
    assert found("warning") == [("warning", "configurations.a1"),
                                ("warning", "configurations.a4")]
    assert found("error") == [("error", "configurations.a1"), ("error", "configurations.a4")]


def test_info_stability_prints_the_table() -> None:
    result = CliRunner().invoke(app, ["info", "--stability", str(RELAY)])
    assert result.exit_code == 0
    assert "  hot: unstable" in result.stdout and "  slow: verified" in result.stdout


# ------------------------------------------------------------------ at run time
def _decisions(arch):
    res = simulate(arch, "main_loss", seed=1, adapt=MapeK(arch))
    evals = [ev for d in res.decisions for ev in d.to_dict()["evaluations"]
             if ev.get("stability")]
    return res, evals


def test_relay_side_loop_is_never_chosen_at_run_time() -> None:
    arch = load_architecture(RELAY).arch
    res, evals = _decisions(arch)
    assert [s["to"] for s in res.switches] == ["slow"]
    hot = [ev["stability"] for ev in evals if ev["action"] == "use_hot"]
    assert hot and all(not s["ok"] and s["method"] == "whole-loop" for s in hot)
    assert_allclose(hot[0]["value"], 1.05, rtol=1e-6)
    assert "echo_a 50 %, echo_b 50 %" in hot[0]["reason"]


def test_without_the_whole_loop_check_the_side_loop_is_chosen(monkeypatch) -> None:
    """The control: the declared models alone call 'hot' stable (the bug of issue 33)."""
    import archself.runtime.stability as st

    monkeypatch.setattr(st, "whole_loop_check", lambda system, action, passed, *a: passed)
    res, _ = _decisions(load_architecture(RELAY).arch)
    assert [s["to"] for s in res.switches][:1] == ["hot"]


# ------------------------------------------------------------------ python-control
def test_numerical_a_equals_python_control_interconnect_and_c2d() -> None:
    """Mass-spring under PI: ct.c2d (zoh) of the plant, the PI as generic.pid runs it
    (I⁺ = I + ki·dt·e, u = kp·e + I), ct.interconnect: A agrees within 1e-9 (central
    differences on a linear map are exact but for rounding, ~eps·|x|/h ≈ 1e-10), and the
    closed loop's step response agrees with the run's step by step."""
    ct = pytest.importorskip("control")
    arch = load_architecture(FIXTURES / "valid" / "mass_spring.yaml").arch
    dt, kp, ki = 0.01, 3.0, 1.0
    plant = ct.c2d(ct.ss([[0, 1], [-2, -0.5]], [[0], [1]], [[1, 0]], [[0]],
                         inputs="u", outputs="y", name="mass"), dt, "zoh")
    pi = ct.ss([[1.0]], [[ki * dt, -ki * dt]], [[1.0]], [[kp, -kp]], dt,
               inputs=["r", "y"], outputs="u", name="pi")
    loop = ct.interconnect([plant, pi], inputs="r", outputs="y")

    system = compile_system(arch, "only", seed=0)
    system.run(1.0)
    whole = system.whole_loop()
    assert whole.labels == ["mass.x[0]", "mass.x[1]", "mass.u[0]", "pi.integral", "pi.y_f"]
    A = np.asarray(whole.A)
    idx = [0, 1, 3]  # the held input and the derivative filter are read by nobody (kd = 0)
    assert_allclose(A[np.ix_(idx, idx)], loop.A, rtol=0, atol=1e-9)
    assert_allclose(A[np.ix_(idx, [2, 4])], 0.0, atol=1e-9)

    fresh = compile_system(arch, "only", seed=0)
    ys = []
    for _ in range(300):
        fresh.step()
        ys.append(float(np.asarray(fresh.signal("mass.y"))[0]))
    t = np.arange(301) * dt
    resp = ct.forced_response(loop, t, np.ones_like(t), X0=[0.2, 0.0, 0.0])
    assert_allclose(ys, np.asarray(resp.outputs)[:300], rtol=0, atol=1e-9)


def test_loop_divergence_watches_the_whole_state_not_the_objective() -> None:
    """The fallback where the loop cannot be linearized: two rollouts, ‖x' − x‖² of every
    module's state; the side loop grows 1.05² per step, the spare's loop shrinks."""
    from archself.runtime.stability import StabilityVerdict, loop_divergence

    arch = load_architecture(RELAY).arch
    system = compile_system(arch, "normal", seed=0)
    system.run(2.0)
    ok = StabilityVerdict(True, "lyapunov", -1.0, -0.5, "passed")
    actions = {a.id: a for a in arch.actions}
    hot = loop_divergence(system, actions["use_hot"], 40, ok, "a test")
    assert not hot.ok and hot.method == "whole-loop"
    assert hot.value > 1.05 ** 40  # ‖Δx‖² grows at least as the side loop's mode, 1.05²/step
    assert "diverges from its neighbour" in hot.reason
    assert loop_divergence(system, actions["use_spare"], 40, ok, "a test") is ok


def test_lanes_reject_the_side_loop_as_the_per_run_loop_does() -> None:
    """The lane view hands the Plan its per-run system: the same whole-loop check."""
    from archself.lanes.run import simulate_lanes

    arch = load_architecture(RELAY).arch
    lanes = simulate_lanes(arch, "main_loss", [1, 2], adapt=True)
    for seed, run in zip((1, 2), lanes, strict=True):
        alone = simulate(arch, "main_loss", seed=seed, adapt=MapeK(arch))
        assert [s["to"] for s in run.switches] == [s["to"] for s in alone.switches] == ["slow"]
        assert_allclose(run.series["J"], alone.series["J"], rtol=0, atol=0)
