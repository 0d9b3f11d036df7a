"""Configurations composed from subsystem modes (issue 35, point 4): the loader expands
them into the flat configurations the runtime uses; bad names are located errors."""

from __future__ import annotations

import subprocess
import sys

import pytest

from archself.check import check
from archself.model.loader import SchemaError, load_architecture, load_text
from archself.resources import data_dir

ROBOT = data_dir("architectures") / "diffdrive.yaml"

#: The robot's configurations as they were written flat (before the subsystems).
FLAT = {
    "a1": ["chassis", "wheel_left", "wheel_right", "encoders", "imu", "gps", "planner",
           "odometry", "lqr", "kinematic_model", "dynamic_model", "actuator_model"],
    "a2": ["chassis", "wheel_left", "wheel_right", "encoders", "imu", "gps", "planner", "ekf",
           "lqr_fused", "kinematic_model", "dynamic_model", "actuator_model"],
    "a3": ["chassis", "wheel_left", "wheel_right", "encoders", "imu", "gps", "planner", "ekf",
           "asym_lqr", "kinematic_model", "dynamic_model", "actuator_model"],
    "a4": ["chassis", "wheel_left", "wheel_right", "encoders", "imu", "gps", "planner",
           "odometry", "asym_lqr", "kinematic_model", "dynamic_model", "actuator_model"],
}


def test_the_robot_by_subsystem_expands_to_its_flat_configurations():
    arch = load_architecture(ROBOT).arch
    assert {c: conf.modules for c, conf in arch.configurations.items()} == FLAT
    assert arch.configurations["a4"].modes == {"localization": "dead_reckoning",
                                               "control": "asymmetric"}
    assert arch.initial_configuration() == "a1"
    # the model dumped and read again stays the same (the expansion is idempotent)
    again = type(arch).model_validate(arch.model_dump(by_alias=True))
    assert {c: conf.modules for c, conf in again.configurations.items()} == FLAT
    assert not [f for f in check(load_architecture(ROBOT)) if f.severity == "error"]


def test_flat_and_composed_configurations_mix():
    text = ROBOT.read_text().replace(
        "configurations:\n",
        "configurations:\n  flat_a1:\n    modules: [" + ", ".join(FLAT["a1"]) + "]\n", 1)
    arch = load_text(text, "mixed.yaml").arch
    assert arch.configurations["flat_a1"].modules == arch.configurations["a1"].modules
    assert arch.configurations["flat_a1"].modes is None


BAD = [
    ("{localization: fused, control: asymmetric}", "{localization: fusd, control: asymmetric}",
     "configurations.a3.modes.localization",
     "subsystem 'localization' has no mode 'fusd' (modes: dead_reckoning, fused); "
     "did you mean 'fused'?"),
    ("{localization: dead_reckoning, control: symmetric}",
     "{localization: dead_reckoning, contrl: symmetric}",
     "configurations.a1.modes.contrl", "unknown subsystem 'contrl'; did you mean 'control'?"),
    ("asymmetric: [asym_lqr]", "asymmetric: [asym_lqrr]",
     "subsystems.control.modes.asymmetric[0]",
     "unknown module 'asym_lqrr'; did you mean 'asym_lqr'?"),
    ("fused: [ekf]", "fused: [ekf, odometry]", "subsystems.localization.modes.fused[1]",
     "'odometry' is already in mode 'dead_reckoning': a module belongs to one mode of one "
     "subsystem"),
    ("symmetric: [lqr]", "symmetric: [lqr, ekf]", "subsystems.control.modes.symmetric[1]",
     "'ekf' is already in subsystem 'localization': a module belongs to one mode of one "
     "subsystem"),
    ("    modes: {localization: fused, control: symmetric_fused}\n    modules: *platform",
     "    modes: {localization: fused, control: symmetric_fused}\n    modules: [lqr]",
     "configurations.a2.modules[0]",
     "'lqr' is in subsystem 'control': a composed configuration picks it by its mode"),
    ("  localization:\n    description", "  planner:\n    description", "subsystems.planner",
     "subsystem 'planner' has the name of a module (one ROS 2 part each)"),
]


@pytest.mark.parametrize(("old", "new", "path", "message"), BAD)
def test_bad_modes_are_located_errors(old, new, path, message):
    text = ROBOT.read_text()
    assert text.count(old) == 1
    bad = text.replace(old, new)
    errors = [f for f in check(load_text(bad, "robot.yaml")) if f.severity == "error"]
    hit = [f for f in errors if (f.path, f.message) == (path, message)]
    assert hit, [str(f) for f in errors]
    line = bad.splitlines()[hit[0].line - 1]
    assert path.split(".")[-1].split("[")[0] in line or path.endswith("]")


def test_a_configuration_needs_modules_or_modes():
    text = ROBOT.read_text().replace(
        "configurations:\n", "configurations:\n  empty: {description: nothing}\n", 1)
    with pytest.raises(SchemaError) as err:
        load_text(text, "robot.yaml")
    f = err.value.findings[0]
    assert f.path == "configurations.empty" and f.line is not None
    assert "needs 'modules' (flat) or 'modes'" in f.message


def test_validate_prints_one_located_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(ROBOT.read_text().replace("control: asymmetric}", "control: asym}", 1))
    proc = subprocess.run([sys.executable, "-m", "archself", "validate", str(bad)],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 1
    assert f"{bad}:" in proc.stdout + proc.stderr
    assert "subsystem 'control' has no mode 'asym'" in proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
