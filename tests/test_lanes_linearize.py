"""A lane's whole-loop linearization, its perturbed copies stepped as lanes, is the per-run one.

:func:`archself.lanes.view.lane_loop` (what a lane's stability check uses) against
:func:`archself.system.linearizing.numerical_loop` on the same running system: the same
A entry by entry (bit for bit here; 1e-9 asserted), the same problems.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

import archself
from archself.lanes.system import LaneSystem
from archself.lanes.view import lane_loop, lane_loops
from archself.system.linearizing import numerical_loop
from archself.system.live import compile_system

ROOT = Path(__file__).resolve().parents[1]


def _dense(A):
    return A.toarray() if hasattr(A, "toarray") else np.asarray(A)


@pytest.mark.parametrize(
    ("file", "start", "target", "scenario", "t_s", "steps"),
    [
        ("architectures/diffdrive.yaml", "a1", "a2", "imu_drift", 47.3, 24),  # EKF, GPS latency
        ("architectures/diffdrive.yaml", "a2", None, "nominal", 12.0, 24),
        ("architectures/motor_drive.yaml", "m1", "m2", "nominal", 3.0, 2),  # quantizing sensor
        # relays, whose lane class keeps a ``state`` array (the state API on the class)
        ("tests/fixtures/valid/relay_side_loop.yaml", "normal", "hot", "main_loss", 3.0, 5),
    ],
)
def test_lane_loop_is_the_per_run_loop(file, start, target, scenario, t_s, steps) -> None:
    arch = archself.load(ROOT / file)
    system = compile_system(arch, start, seed=3, scenario=arch.scenarios[scenario])
    for _ in range(int(round(t_s / system.dt))):
        system.step()
    before = system.snapshot()
    one = numerical_loop(system, target, steps)
    lanes = lane_loop(system, target, steps)
    assert_allclose(_dense(lanes.A), _dense(one.A), rtol=0, atol=1e-9)
    assert lanes.labels == one.labels and lanes.problems == one.problems
    assert np.abs(_dense(one.A)).max() > 0.1  # a loop with dynamics, not an empty matrix
    for name in system._plan.active:  # the running system is not changed
        assert_allclose(system.modules[name].state(), before.modules[name].state(), rtol=0,
                        atol=0, err_msg=name)


def test_checks_of_one_cycle_made_together_are_each_lanes_own(monkeypatch) -> None:
    """lane_loops: two lanes' checks stepped as one lane system give each lane's per-run A
    (each check's probes are lanes of its one base: no copy is made)."""
    from archself.system import linearizing

    arch = archself.load(ROOT / "architectures" / "diffdrive.yaml")
    systems = [compile_system(arch, "a1", seed=s, scenario=arch.scenarios["imu_drift"])
               for s in (3, 4)]
    for s in systems:
        for _ in range(int(round(47.3 / s.dt))):
            s.step()
    with monkeypatch.context() as m:
        m.setattr(linearizing._Probe, "copy", lambda *a: pytest.fail("a probe was copied"))
        both = lane_loops([(s, "a2", 24) for s in systems])
    for got, s in zip(both, systems, strict=True):
        want = numerical_loop(s, "a2", 24)
        assert_allclose(_dense(got.A), _dense(want.A), rtol=0, atol=1e-9)
        assert got.labels == want.labels and got.problems == want.problems
    assert np.abs(_dense(both[0].A) - _dense(both[1].A)).max() > 0  # two lanes, two loops


def test_resume_takes_over_the_outputs_and_latency_lines() -> None:
    """Lanes resumed from running systems step as those systems do (the EKF's delayed fixes)."""
    arch = archself.load(ROOT / "architectures" / "diffdrive.yaml")
    systems = [compile_system(arch, "a2", seed=s, scenario=arch.scenarios["nominal"])
               for s in (1, 2)]
    for s in systems:
        for _ in range(41):  # a fix at 2.0 s still in the GPS -> EKF latency line
            s.step()
    lanes = LaneSystem.resume([s.snapshot() for s in systems])
    for _ in range(3):
        lanes.step()
        for s in systems:
            s.step()
    for i, s in enumerate(systems):
        assert_allclose(lanes.signal("ekf", "pose_estimate")[i], s.outputs["ekf"]["pose_estimate"],
                        rtol=0, atol=1e-12)
        assert_allclose(lanes.module("ekf").state()[i], s.modules["ekf"].state(), rtol=0,
                        atol=1e-12)


def test_a_clone_is_the_deep_copy_of_a_snapshot() -> None:
    """system.linearizing.Clones: the same states and random streams as the snapshot's deep copy,
    its own modules and streams, the architecture and step plans shared."""
    from archself.system.linearizing import Clones as _Clones

    arch = archself.load(ROOT / "architectures" / "diffdrive.yaml")
    system = compile_system(arch, "a2", seed=5, scenario=arch.scenarios["imu_drift"])
    for _ in range(120):
        system.step()
    snap = system.snapshot(system._plan.active)
    clones = _Clones(snap)
    a, b = clones(), snap.snapshot(system._plan.active)
    assert a.arch is snap.arch and a._plan is snap._plan
    for name in system._plan.active:
        assert a._pool[name] is not snap._pool[name]
        assert_allclose(a._pool[name].state(), b._pool[name].state(), rtol=0, atol=0)
    for _ in range(30):  # stepped, the clone and the deep copy stay equal; the snapshot stays
        a.step()
        b.step()
    assert_allclose(a.objective_error(), b.objective_error(), rtol=0, atol=0)
    assert_allclose(snap._pool["chassis"].state(), clones()._pool["chassis"].state(), rtol=0,
                    atol=0)
    assert not np.array_equal(a._pool["chassis"].state(), snap._pool["chassis"].state())


def test_lanes_resumed_from_one_system_are_each_its_own_copy() -> None:
    """LaneSystem.resume of one system for several lanes (the check's probes): each lane
    steps as a deep copy of it, its state moved through LaneModule.set_state as the copy's
    set_state moves it; random streams and a noise fault's injector drawn per lane."""
    from archself.system.live import FaultInjector

    arch = archself.load(ROOT / "architectures" / "diffdrive.yaml")
    system = compile_system(arch, "a2", seed=5, scenario=arch.scenarios["imu_drift"])
    for _ in range(60):
        system.step()
    system._faults.setdefault("imu", []).append(
        ("heading", FaultInjector("noise_increase", 0.0, 0.05, rng=np.random.default_rng(7))))
    twins = [system.snapshot() for _ in range(3)]
    lanes = LaneSystem.resume([system] * 3)
    x = twins[0].modules["chassis"].state().copy()
    x[0] += 1e-3
    type(twins[2]._pool["chassis"]).set_state(twins[2]._pool["chassis"], x)
    for name in system._plan.active:
        lanes.module(name)
    lanes.module("chassis").set_state(x[None], np.array([2]))
    for _ in range(30):
        lanes.step()
        for s in twins:
            s.step()
    for i, s in enumerate(twins):
        for name in ("chassis", "ekf", "imu"):
            assert_allclose(lanes.module(name).state(np.array([i]))[0], s.modules[name].state(),
                            rtol=0, atol=1e-12, err_msg=f"{name} lane {i}")
        assert_allclose(lanes.signal("imu", "heading")[i], s.outputs["imu"]["heading"],
                        rtol=0, atol=1e-12)
    heading = lanes.signal("imu", "heading")
    assert heading[0] == heading[1] != heading[2]  # the moved lane went its own way
    normals = lanes.module("imu").normals  # one stream drawn once while the lanes share it
    for i, s in enumerate(twins):  # pinned, each lane's own generator at its twin's state
        normals.pin(i)
        assert normals.rngs[i].bit_generator.state == s._pool["imu"].rng.bit_generator.state
    assert normals.rngs[0] is not normals.rngs[1]
    normals.unpin()


def test_a_type_that_runs_lane_by_lane_gets_its_own_instance_per_probe(monkeypatch) -> None:
    """A type that runs lane by lane under smooth (the motor drive's quantizing sensor)
    cannot share its per-run instance between lanes: resume refuses; the check's probe lanes
    (lane_copies) share the base's other modules and own a copy of it; no probe is copied."""
    from archself.errors import SimulationError
    from archself.lanes.system import lane_copies
    from archself.system import linearizing

    arch = archself.load(ROOT / "architectures" / "motor_drive.yaml")
    system = compile_system(arch, "m1", seed=3, scenario=arch.scenarios["nominal"])
    for _ in range(10):
        system.step()
    with pytest.raises(SimulationError, match="share a system"):
        LaneSystem.resume([system, system], smooth=True)
    copies = lane_copies(system, 3, smooth=True)
    own = {n for n in system._plan.active if copies[1]._pool[n] is not system._pool[n]}
    assert own and all(type(system._pool[n]).__name__ == "Sensor" for n in own)
    assert copies[0] is system and copies[2]._pool[next(iter(own))] is not copies[1]._pool[
        next(iter(own))]
    want = numerical_loop(system, "m2", 2)
    monkeypatch.setattr(linearizing._Probe, "copy", lambda *a: pytest.fail("a probe was copied"))
    loop = lane_loop(system, "m2", 2)
    assert_allclose(_dense(loop.A), _dense(want.A), rtol=0, atol=1e-9)
    assert loop.labels == want.labels and loop.problems == want.problems
