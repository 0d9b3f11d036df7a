"""The lane classes' array state API equals the per-run bridge (issue 38).

A lane class that declares its state layout (``LaneModule.state_rows`` /
``set_state_rows``) must give, on random lanes of running lane systems, exactly the
state the per-run bridge gives (``bridged_state``: store the lane, the per-run
instance's ``state()``), and a state set through it must read back, through both
paths, as written (bit for bit: the whole-loop check's A depends on it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import archself
from archself.lanes.module import LaneModule
from archself.lanes.system import LaneSystem
from archself.system.live import compile_system

ROOT = Path(__file__).resolve().parents[1]

#: (file, configuration, scenario, steps run per-run, the classes that must declare it)
CASES = [
    ("architectures/diffdrive.yaml", "a2", "imu_drift", 130,
     {"DiffDrivePlantLanes", "WheelActuatorLanes", "EkfLanes"}),
    ("architectures/diffdrive.yaml", "a1", "imu_drift", 130, {"OdometryLanes"}),
    ("architectures/process_plant.yaml", "p1", "level_drift", 40,
     {"TankPlantLanes", "ControlValveLanes", "LevelObserverLanes", "PiControllerLanes"}),
    ("architectures/thermal_zone.yaml", "z1", "sensor_dropout", 40,
     {"StateSpacePlantLanes", "ActuatorLanes", "PidLanes"}),
]


def _lanes(file: str, configuration: str, scenario: str, steps: int) -> LaneSystem:
    """Five lanes (seeds 1-5) resumed from running per-run systems, stepped a little more."""
    arch = archself.load(ROOT / file)
    systems = [compile_system(arch, configuration, seed=s, scenario=arch.scenarios[scenario])
               for s in range(1, 6)]
    for s in systems:
        for _ in range(steps):
            s.step()
    lanes = LaneSystem.resume(systems)
    for _ in range(7):
        lanes.step()
    return lanes


def _declared(mod: LaneModule, lanes: np.ndarray) -> bool:
    return type(mod).state_rows is not LaneModule.state_rows and mod.state_rows(lanes) is not None


@pytest.mark.parametrize(("file", "configuration", "scenario", "steps", "classes"), CASES)
def test_array_state_is_the_bridge_state(file, configuration, scenario, steps, classes) -> None:
    lanes = _lanes(file, configuration, scenario, steps)
    rng = np.random.default_rng(4)
    seen = set()
    for name in sorted(lanes.plan(lanes.configuration[0]).active):
        mod = lanes.module(name)
        pick = np.sort(rng.choice(mod.n, 3, replace=False))
        if not _declared(mod, pick):
            continue
        seen.add(type(mod).__name__)
        want = mod.bridged_state(pick)
        got = mod.state_rows(pick)
        assert want.size > 0 and got.shape == want.shape, name
        assert np.array_equal(got, want), name
        assert np.array_equal(mod.state_rows(slice(None))[pick], want), name
        # set through the arrays, then read back through both paths
        x = want + rng.normal(scale=0.1, size=want.shape)
        assert mod.set_state_rows(x, pick), name
        assert np.array_equal(mod.state_rows(pick), x), name
        assert np.array_equal(mod.bridged_state(pick), x), name
        # set through the bridge, read through the arrays
        y = want - rng.normal(scale=0.1, size=want.shape)
        mod.bridged_set_state(y, pick)
        assert np.array_equal(mod.state_rows(pick), y), name
        # the public door takes the array path and leaves the other lanes alone
        rest = np.setdiff1d(np.arange(mod.n), pick)
        before = mod.state_rows(rest)
        mod.set_state(want, pick)
        assert np.array_equal(mod.state(pick), want), name
        assert np.array_equal(mod.state(rest), before), name
    assert classes <= seen, f"not declared: {sorted(classes - seen)}"


def test_wheel_without_a_previous_command_has_expected_alone() -> None:
    """A wheel lane without a previous command has ``expected`` alone as its state, as the
    per-run wheel; lanes that differ in size go through the bridge, which says so."""
    lanes = _lanes("architectures/diffdrive.yaml", "a2", "imu_drift", 130)
    mod = lanes.module("wheel_left")
    assert mod.state_rows(slice(None)).shape == (5, 2)
    mod.has_prev[[1, 3]] = False
    none = np.array([1, 3])
    assert np.array_equal(mod.state_rows(none), mod.bridged_state(none))
    assert mod.state_rows(none).shape == (2, 1)
    assert mod.state_rows(slice(None)) is None  # sizes 1 and 2: no array
    assert not mod.set_state_rows(np.zeros((2, 2)), none)  # a 2-value state for 1 value
    with pytest.raises(archself.errors.SimulationError, match="differ in size"):
        mod.state(slice(None))
