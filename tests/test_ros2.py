"""``archself ros2``: the loop manages the robot as ROS 2 nodes (docs/ros2.md).

Every process that imports rclpy runs in a network namespace of its own with only
the loopback interface (``unshare -n``), bounded by a timeout: DDS discovery never
reaches the machine's network. The tests skip, with the reason, when the ROS 2
wheels (``pip install 'archself[ros2]'``) cannot be imported or no such namespace
can be made (not root, no ``unshare``/``ip``).
"""

from __future__ import annotations

import importlib.util
import json
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from archself.io.jsondata import Ros2Doc
from archself.resources import data_dir

HERE = Path(__file__).parent
DIFFDRIVE = data_dir("architectures") / "diffdrive.yaml"
PLANT = data_dir("architectures") / "process_plant.yaml"


def _why_not() -> str | None:
    if importlib.util.find_spec("rclpy") is None:
        return "rclpy not importable (pip install 'archself[ros2]')"
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return "no unshare/ip to make a loopback-only network namespace"
    if os.geteuid() != 0:
        return "a private network namespace (unshare -n) needs root here"
    probe = subprocess.run(["unshare", "-n", "sh", "-c", "ip link set lo up"],
                           capture_output=True, timeout=10)
    if probe.returncode != 0:
        return f"unshare -n failed: {probe.stderr.decode(errors='replace').strip()}"
    return None


WHY_NOT = _why_not()
needs_ros = pytest.mark.skipif(WHY_NOT is not None, reason=str(WHY_NOT))


def _netns(*args: str) -> list[str]:
    """``args`` run in a new network namespace with only loopback, up."""
    return ["unshare", "-n", "sh", "-c", 'ip link set lo up; exec "$@"', "sh", *args]


def _archself(*args: str) -> list[str]:
    return [sys.executable, "-m", "archself", *args]


def _simulated(arch_file: Path, scenario: str, seed: int, duration_s: float) -> list[tuple]:
    from archself import MapeK, load, simulate

    arch = load(arch_file)
    sc = arch.scenarios[scenario].model_copy(update={"duration_s": duration_s})
    arch = arch.model_copy(update={"scenarios": {**arch.scenarios, scenario: sc}})
    run = simulate(arch, scenario, seed=seed, adapt=MapeK(arch))
    return [(s["from"], s["to"], float(s["t_s"])) for s in run.switches]


RUNS = [(sc, seed, dur) for sc, dur in (("imu_drift", 80.0), ("actuator_fault", 30.0))
        for seed in (1, 2, 3)]


@needs_ros
@pytest.mark.slow
def test_ros2_demo_switches_as_simulate_on_three_seeds() -> None:
    """imu_drift and actuator_fault, seeds 1-3: the same configuration path as
    ``archself simulate``, every switch within 1 s of the simulated one. The six runs
    go in parallel, each in its own namespace (lock step: load changes no result)."""
    procs = {
        run: subprocess.Popen(
            _netns(*_archself("ros2", str(DIFFDRIVE), "--demo", "--scenario", run[0],
                              "--seed", str(run[1]), "--duration", str(run[2]), "--json",
                              "--timeout", "60")),
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for run in RUNS
    }
    outs = {}
    try:
        for run, p in procs.items():
            out, err = p.communicate(timeout=600)
            assert p.returncode == 0, (run, err[-2000:])
            outs[run] = json.loads(out)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    for (scenario, seed, duration), res in outs.items():
        Ros2Doc.model_validate(res, strict=True)  # the shape docs/json.md gives
        want = _simulated(DIFFDRIVE, scenario, seed, duration)
        got = [(s["from"], s["to"], float(s["t_s"])) for s in res["switches"]]
        assert want, (scenario, seed)
        assert [w[:2] for w in got] == [w[:2] for w in want], (scenario, seed, got, want)
        for g, w in zip(got, want, strict=True):
            assert abs(g[2] - w[2]) <= 1.0, (scenario, seed, got, want)
        ros = res["ros2"]
        assert ros["lifecycle_nodes"] == ["planner", "odometry", "ekf", "lqr", "lqr_fused",
                                          "asym_lqr"]
        assert ros["refused"] == []
        assert ros["plant"]["switches"] == [{"t_s": g[2], "from": g[0], "to": g[1]}
                                            for g in got]
        assert ros["cycles"] == round(duration / 0.5)


@needs_ros
@pytest.mark.slow
def test_lifecycle_and_parameters_seen_by_a_plain_rclpy_client(tmp_path: Path) -> None:
    """process_plant drift_then_valve (z localization): a plain rclpy client (no archself)
    sees, through ROS 2's own get_state and get_parameters, the nodes go p1 → p2 → p4 and
    the PI controller's gains raised by raise_pi_gain."""
    from archself import load
    from archself.reports.export import node_modules

    # The paper's z localization raises the PI gains while the valve's switch waits out
    # its dwell (the default source fit makes the same update: docs/localization.md); the
    # test pins the paper's mechanism.
    plant = tmp_path / "process_plant.yaml"
    text = PLANT.read_text(encoding="utf-8")
    assert text.count("\nruntime:\n") == 1
    plant.write_text(text.replace("\nruntime:\n", "\nruntime:\n  localization: influence\n"),
                     encoding="utf-8")
    arch = load(plant)
    assert arch.runtime.localization == "influence"
    nodes = node_modules(arch)
    pi = next(a for a in arch.actions if a.kind == "parameter_update")
    names = sorted(pi.set)
    client = shlex.join([sys.executable, str(HERE / "ros2_plain_client.py"), ",".join(nodes),
                         pi.module, ",".join(names), "400"])
    run = shlex.join(_archself("ros2", str(plant), "--demo", "--scenario", "drift_then_valve",
                               "--duration", "150", "--rate", "20", "--linger", "3",
                               "--json",
                               "--timeout", "60"))
    seen_file = tmp_path / "plain.json"
    with subprocess.Popen(
        ["unshare", "-n", "sh", "-c", f'ip link set lo up; {client} > "$1" & {run}; wait',
         "sh", str(seen_file)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    ) as p:
        try:
            out, err = p.communicate(timeout=600)
        except subprocess.TimeoutExpired:
            p.kill()
            raise
    assert p.returncode == 0, err[-2000:]
    res = json.loads(out)
    plain = json.loads(seen_file.read_text(encoding="utf-8"))
    assert [s["to"] for s in res["switches"]] == ["p2", "p4"]
    assert [u["module"] for u in res["updates"]] == [pi.module]

    def conf_of(states: dict) -> str | None:
        on = {n for n, s in states.items() if s == "active"}
        hits = [c for c, conf in arch.configurations.items() if set(conf.modules) & set(nodes)
                == on]
        return hits[0] if len(hits) == 1 else None

    seen = [conf_of(s) for s in plain["states"]]
    path = [c for i, c in enumerate(seen) if c is not None and (i == 0 or seen[i - 1] != c)]
    # p2 lasts 16 s of the run (0.8 s at --rate 20): the poll may miss it
    assert path in (["p1", "p2", "p4"], ["p1", "p4"]), plain["states"]
    nominal = {k: arch.modules[pi.module].params[k].value for k in names}
    assert plain["params"][0] == pytest.approx(nominal)
    assert plain["params"][-1] == pytest.approx(dict(pi.set))


def test_without_rclpy_one_line_names_the_extra() -> None:
    """No ROS 2 installed: one line naming ``archself[ros2]``, exit 1 (rclpy hidden)."""
    code = (
        "import sys\n"
        "sys.modules['rclpy'] = None  # as if not installed\n"
        "from archself.cli import main\n"
        f"sys.argv = ['archself', 'ros2', {str(DIFFDRIVE)!r}]\n"
        "main()\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        "rclpy is not installed; install the ROS 2 wheels: pip install 'archself[ros2]'"]


def test_cli_ros2_refuses_unknown_nodes_and_scenarios_before_ros_starts() -> None:
    from typer.testing import CliRunner

    from archself.cli import app

    res = CliRunner().invoke(app, ["ros2", str(DIFFDRIVE), "--nodes", "ekf,nope"])
    assert res.exit_code == 1 and "'nope' is not a module" in res.output
    res = CliRunner().invoke(app, ["ros2", str(DIFFDRIVE), "--demo", "--scenario", "nope"])
    assert res.exit_code == 1 and "no scenario 'nope'" in res.output
    res = CliRunner().invoke(app, ["ros2", str(DIFFDRIVE), "--demo"])
    assert res.exit_code == 2 and "--demo needs --scenario" in res.output


def test_lifecycle_view_of_configurations() -> None:
    """Which transitions reach a configuration, and which configuration states show."""
    from archself import load
    from archself.reports.export import node_modules
    from archself.ros2.topics import configuration_of, transitions

    arch = load(DIFFDRIVE)
    nodes = node_modules(arch)
    fresh = dict.fromkeys(nodes, "unconfigured")
    steps = transitions(arch, nodes, fresh, "a1")
    assert [s for s in steps if s[1] == "activate"] == [
        ("planner", "activate"), ("odometry", "activate"), ("lqr", "activate")]
    assert {n for n, what in steps if what == "configure"} == set(nodes)
    states = {n: "active" if n in {"planner", "odometry", "lqr"} else "inactive" for n in nodes}
    assert configuration_of(arch, states) == "a1"
    assert transitions(arch, nodes, states, "a2") == [
        ("ekf", "activate"), ("lqr_fused", "activate"), ("odometry", "deactivate"),
        ("lqr", "deactivate")]
    half = {**states, "ekf": "active"}  # mid-transition: no configuration
    assert configuration_of(arch, half) is None
    # two configurations with the same nodes (a rewire): the current one is kept
    from archself.model.loader import load_text

    text = DIFFDRIVE.read_text(encoding="utf-8").replace(
        "configurations:\n",
        "configurations:\n  a5:\n    modules: [chassis, wheel_left, wheel_right, encoders, imu, "
        "gps, planner, odometry, lqr, kinematic_model, dynamic_model, actuator_model]\n"
        "    disabled_edges: [[gps, odometry]]\n", 1)
    arch5 = load_text(text, "rewired.yaml").arch
    assert configuration_of(arch5, states) is None
    assert configuration_of(arch5, states, "a1") == "a1"
    assert configuration_of(arch5, states, "a5") == "a5"


@needs_ros
def test_array_messages_keep_shape_and_nan() -> None:
    code = (
        "import math, numpy as np\n"
        "from archself.ros2.bridge import array_msg, array_value\n"
        "m = np.arange(9.0).reshape(3, 3)\n"
        "np.testing.assert_array_equal(array_value(array_msg(m)), m)\n"
        "v = array_value(array_msg([1.0, float('nan')]))\n"
        "assert v.shape == (2,) and v[0] == 1.0 and math.isnan(v[1])\n"
        "assert array_value(array_msg(2.5)) == 2.5\n"
        "print('ok')\n"
    )
    proc = subprocess.run(_netns(sys.executable, "-c", code), capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr


@needs_ros
@pytest.mark.slow
def test_timer_clock_with_a_free_running_plant_on_sim_time() -> None:
    """The robot's way: the plant does not wait (publishes every step, /clock), the
    loop runs on its timer on ROS time. actuator_fault at twice real time: the loop
    switches as simulate does and the plant follows the lifecycle states within 1 s."""
    want = _simulated(DIFFDRIVE, "actuator_fault", 1, 30.0)
    proc = subprocess.run(
        _netns(*_archself("ros2", str(DIFFDRIVE), "--demo", "--clock", "timer", "--rate", "2",
                          "--scenario", "actuator_fault", "--duration", "30", "--json",
                          "--timeout", "60")),
        capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads(proc.stdout)
    Ros2Doc.model_validate(res, strict=True)
    got = [(s["from"], s["to"], float(s["t_s"])) for s in res["switches"]]
    applied = [(s["from"], s["to"], float(s["t_s"])) for s in res["ros2"]["plant"]["switches"]]
    assert [g[:2] for g in got] == [w[:2] for w in want] == [g[:2] for g in applied]
    for g, a, w in zip(got, applied, want, strict=True):
        assert abs(g[2] - w[2]) <= 1.0 and 0.0 <= a[2] - g[2] <= 1.0, (got, applied, want)
    assert res["ros2"]["plant"]["measurements"] == 600


@needs_ros
def test_ros2_log_is_locked_like_every_output(tmp_path: Path) -> None:
    """`archself ros2 --log F` while another process writes F: refused before ROS starts
    (in the namespace all the same: a regression would start a node)."""
    log = tmp_path / "decisions.json"
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time\n"
         "from archself.io.files import protect\n"
         f"with protect([], [{str(log)!r}]):\n"
         "    print('held', flush=True)\n"
         "    time.sleep(60)\n"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        proc = subprocess.run(_netns(*_archself("ros2", str(PLANT), "--log", str(log))),
                              capture_output=True, text=True, timeout=120)
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
    assert proc.returncode == 1, proc.stderr
    line = proc.stderr.strip()
    assert "\n" not in line and f"is being written by pid {holder.pid}" in line
    assert not log.exists()
