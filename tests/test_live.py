"""archself.live: the MAPE-K loop on a plant that pushes measurements (docs/live.md).

The live runs are compared with :func:`archself.simulate` on the same scenario and
seed: a plant that waits for the loop's answer before its next step acts on every
decision at the step a simulation does, so the switch sequence and the switch times
must be the same (no tolerance). Timeouts below are hang guards only.
"""

from __future__ import annotations

import json
import os
import re
import selectors
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from archself.live import (
    NO_ROLLOUT,
    Command,
    LiveError,
    LiveLoop,
    MeasuredSystem,
    PlantLink,
    live_problems,
    parse_address,
    run_remote,
)
from archself.model.loader import load_text
from archself.runtime.mapek import MapeK
from archself.sim.run import simulate
from archself.system.live import compile_system

from conftest import ROOT

PLANT = ROOT / "architectures" / "process_plant.yaml"
SCENARIO = "drift_then_valve"  # two switches: transmitter A drifts, then the valve clogs
DURATION = 240.0  # shortened from 600 s: both switches happen before 180 s
HANG_GUARD_S = 120.0


def _plant_text(duration: float = DURATION) -> str:
    """process_plant.yaml with the scenario shortened to ``duration``.

    With ``localization: influence`` (the paper's z): it takes a parameter update (the PI
    gain, during the dwell time) between the two switches, so the live path of both kinds
    of action is exercised; the default fit acts on the valve only.
    """
    text = PLANT.read_text(encoding="utf-8")
    head, sep, tail = text.partition(f"  {SCENARIO}:\n")
    tail = tail.replace("duration_s: 600", f"duration_s: {duration:g}", 1)
    head2, sep2, tail2 = (head + sep + tail).rpartition("\nruntime:\n")
    return f"{head2}{sep2}  localization: influence\n{tail2}"


@pytest.fixture(scope="module")
def arch():
    return load_text(_plant_text(), str(PLANT)).arch


@pytest.fixture(scope="module")
def simulated(arch):
    loop = MapeK(arch)
    res = simulate(arch, SCENARIO, adapt=loop)
    return res, loop


def _drive(arch, loop: LiveLoop, *, every: int = 1, until: float = DURATION) -> list[Command]:
    """Run the scenario's plant in this process, pushing every ``every`` steps."""
    sc = arch.scenarios[SCENARIO]
    plant = compile_system(arch, seed=sc.seed, scenario=sc)
    applied = []
    for k in range(1, int(round(until / plant.dt)) + 1):
        plant.step()
        if k % every:
            continue
        for c in loop.push(plant.t, plant.outputs, plant.local_signals(), plant.health(),
                           plant.configuration):
            if c.kind == "configuration":
                plant.apply_configuration(c.configuration)
            else:
                plant.set_params(c.module, c.values)
            applied.append(c)
    return applied


def _switches(items) -> list[tuple[float, str, str, str]]:
    return [(float(s["t_s"]), s["from"], s["to"], s["action"]) for s in items]


# ---------------------------------------------------------------------- MeasuredSystem
def test_measured_system_reads_what_was_pushed(arch) -> None:
    s = MeasuredSystem(arch)
    assert s.configuration == arch.initial_configuration()
    assert np.isnan(s.objective_error())
    s.update(2.0, outputs={"tank": {"level": 1.25}, "setpoint": {"setpoint": [1.0, 0.0]}},
             signals={"observer_a": {"innovation": 0.01}, "observer_b": {"innovation": 9.0}},
             health={"level_a": "stale level_measured (4 identical values)"})
    assert s.t == 2.0
    assert_allclose(s.objective_error(), 0.25)
    assert_allclose(s.state_error(), [0.25])
    local = s.local_signals()
    assert local["observer_a"] == {"innovation": 0.01}
    assert "observer_b" not in local  # not active in the initial configuration
    assert s.available()["level_a"] is False
    assert s.health()["level_a"].startswith("stale")
    assert s.available()["tank"] is True
    s.update(3.0, health={"level_a": None}, configuration="p2")
    assert s.available()["level_a"] is True
    assert s.configuration == "p2" and "observer_b" in s.active
    assert s.history[-1]["by"] == "plant"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"t": float("nan")}, "not finite"),
        ({"t": "soon"}, "not a number"),
        ({"t": 1.0, "configuration": "p9"}, "unknown configuration 'p9'"),
        ({"t": 1.0, "outputs": [1, 2]}, "outputs must be a mapping"),
        # each was an internal error (AttributeError, unhashable list)
        ({"t": 1.0, "outputs": {"tank": 5}}, "outputs of module 'tank' must be a mapping"),
        ({"t": 1.0, "signals": {"observer_a": 5}}, "signals of module 'observer_a' must be"),
        ({"t": 1.0, "configuration": ["p1"]}, r"configuration \['p1'\], not a name"),
        # strings and huge integers in numeric fields: refused, the field named
        ({"t": 1.0, "outputs": {"tank": {"level": "1.0"}}},
         r"outputs\.tank\.level: expected a number or null, got a string '1\.0'"),
        ({"t": 1.0, "outputs": {"setpoint": {"setpoint": [1.0, "x"]}}},
         r"outputs\.setpoint\.setpoint\[1\]: expected a number"),
        ({"t": 1.0, "signals": {"observer_a": {"innovation": "0.1"}}},
         r"signals\.observer_a\.innovation: expected a number"),
        ({"t": 1.0, "outputs": {"tank": {"level": 10 ** 400}}}, "integer of 401 digits"),
        ({"t": 1.0, "outputs": {"tank": {"level": {"v": 1}}}}, "got dict"),
    ],
)
def test_measured_system_refuses_bad_measurements(arch, kwargs, message) -> None:
    with pytest.raises(LiveError, match=message):
        MeasuredSystem(arch).update(**kwargs)


def test_measurement_time_is_finite_non_decreasing_and_bounded(arch) -> None:
    """t = 1e4 or 1e308 among normal times was accepted and the loop stopped deciding."""
    loop = LiveLoop(arch)
    assert loop.system.max_jump_s == 100 * arch.runtime.period_s
    out = {"tank": {"level": 1.0}, "setpoint": {"setpoint": [1.0, 0.0]}}
    loop.push(1.0, out)
    loop.push(2.0, out)
    for bad, why in ((1e4, "jumps 9998 s past the last one, 2 s (at most 100 s)"),
                     (1e308, "jumps 1e+308 s past"), (1.5, "goes back before the last one"),
                     (float("inf"), "not finite")):
        with pytest.raises(LiveError, match=re.escape(why)):
            loop.push(bad, out)
    assert loop.system.t == 2.0 and loop.measurements == 2  # the refused ones changed nothing
    for k in range(3, 17):
        loop.push(float(k), out)
    assert loop.mapek.cycle == 16  # one per period, as if the bad times had not come
    loop.push(16.0, out)  # the same time again: not a decrease
    with pytest.raises(LiveError, match="at most 5 s"):
        bounded = LiveLoop(arch, max_jump_s=5.0)
        bounded.push(1.0, out)
        bounded.push(7.0, out)
    with pytest.raises(LiveError, match="max_jump_s must be"):
        LiveLoop(arch, max_jump_s=float("nan"))


def test_snapshot_is_the_models_never_a_rollout(arch) -> None:
    s = MeasuredSystem(arch)
    before = s.linearization()
    snap = s.snapshot()
    snap.set_params("pi", {"kp": 5.0, "ki": 0.213})
    # the same update on a compiled system gives the same closed loop
    ref = compile_system(arch, seed=0)
    ref.set_params("pi", {"kp": 5.0, "ki": 0.213})
    assert_allclose(snap.linearization(), ref.linearization(), rtol=1e-12)
    assert not np.allclose(snap.linearization(), before)
    assert_allclose(s.linearization(), before, rtol=0)  # the live models did not change
    for call in (snap.step, snap.state_error, snap.objective_error, s.step):
        with pytest.raises(LiveError, match="no rollout"):
            call()


# ---------------------------------------------------------------------- LiveLoop
@pytest.mark.parametrize("every", [1, 5])  # every step; every MAPE-K period (1 s = 5 steps)
def test_live_loop_decides_as_the_simulation(arch, simulated, every) -> None:
    res, sim_loop = simulated
    heard: list[Command] = []
    loop = LiveLoop(arch, on_command=heard.append)
    applied = _drive(arch, loop, every=every)

    assert len(res.switches) == 2
    assert _switches(loop.switches) == _switches(res.switches)
    assert [(c.t_s, c.configuration) for c in applied if c.kind == "configuration"] == [
        (s["t_s"], s["to"]) for s in res.switches
    ]
    assert [(c.t_s, c.action) for c in applied if c.kind == "parameters"] == [
        (u["t_s"], u["action"]) for u in sim_loop.updates
    ]
    queued = [loop.commands.get_nowait() for _ in range(loop.commands.qsize())]
    assert heard == queued == applied
    assert loop.updates == sim_loop.updates

    # cycle by cycle, the loop saw the same numbers as in simulation
    live, sim = loop.decisions, sim_loop.decisions
    assert [d.t for d in live] == [d.t for d in sim]
    assert_allclose([d.j_obs for d in live], [d.j_obs for d in sim], rtol=1e-12)
    for a, b in zip(live, sim, strict=True):
        assert a.configuration == b.configuration
        assert a.candidates == b.candidates
        assert_allclose([a.z[m] for m in a.z], [b.z[m] for m in b.z], rtol=1e-12, atol=1e-15)
        assert_allclose([a.r[m] for m in a.r], [b.r[m] for m in b.r], rtol=1e-12, atol=1e-15)
        assert [(e.action, e.rejected, e.delta) for e in a.evaluations] == [
            (e.action, e.rejected, e.delta) for e in b.evaluations
        ]
        assert [e.stability["ok"] for e in a.evaluations if e.stability] == [
            e.stability["ok"] for e in b.evaluations if e.stability
        ]


def test_decision_log_says_where_delta_and_stability_came_from(arch) -> None:
    loop = LiveLoop(arch)
    _drive(arch, loop, until=175.0)
    chosen = [d for d in loop.decisions if d.chosen]
    assert [d.chosen["action"] for d in chosen] == [
        "use_transmitter_b", "raise_pi_gain", "compensate_valve_on_b"]  # the update in T_min
    for d in chosen:
        assert d.note == (
            "live (no plant snapshot): Δ by sensitivity; "
            "stability by eigenvalue margin of the compiled models"
        )
        stab = [e.stability for e in d.evaluations if e.stability]
        assert stab and all(s["source"] == "models" and s["method"] == "eigenvalue"
                            for s in stab)
    quiet = [d for d in loop.decisions if not d.evaluations]
    assert quiet and all(d.note == "" for d in quiet)


def test_cycles_follow_the_plant_clock(arch) -> None:
    loop = LiveLoop(arch, start_s=100.0)
    out = {"tank": {"level": 1.0}, "setpoint": {"setpoint": [1.0, 0.0]}}
    for t in (100.2, 100.8, 101.0, 101.2, 104.6, 104.8, 105.0):
        loop.push(t, outputs=out)
    # due at 101 (on 101.0), 102 (first measurement after: 104.6, one cycle), 105
    assert [d.t for d in loop.decisions] == [101.0, 104.6, 105.0]
    assert loop.measurements == 7


def test_a_huge_finite_residual_signal_is_capped_not_a_crash(arch) -> None:
    """1e308 over a nominal of 2.47 overflowed r to inf; the influence solve refused it."""
    from archself.runtime.monitor import MAX_RESIDUAL

    loop = LiveLoop(arch)
    out = {"tank": {"level": 1.0}, "setpoint": {"setpoint": [1.0, 0.0]}}
    huge = {"observer_a": {"disagreement": 1e308}, "observer_b": {"innovation": 1e308}}
    for k in range(1, 40):
        loop.push(float(k), outputs=out, signals=huge)
    logs = [d.to_dict() for d in loop.decisions]
    assert max(d["r"].get("observer_a", 0.0) for d in logs) == MAX_RESIDUAL
    assert all(np.isfinite(v) for d in logs for v in d["z"].values())
    assert loop.switches and loop.switches[0]["from"] == "p1"  # the fault is acted on


# ---------------------------------------------------------------------- refusals
def _with_rollout(action: str) -> str:
    """The plant's text with ``action``'s Δ estimated by rollout."""
    text = _plant_text()
    head, sep, tail = text.partition(f"  - id: {action}\n")
    tail = tail.replace("improvement: {method: sensitivity, delta_theta: -0.9}",
                        "improvement: {method: rollout, horizon_s: 5}", 1)
    return head + sep + tail


def test_rollout_action_is_refused_in_one_line() -> None:
    arch = load_text(_with_rollout("use_transmitter_b"), "plant.yaml").arch
    assert live_problems(arch) == ["action use_transmitter_b: its Δ is estimated by rollout"]
    with pytest.raises(LiveError) as err:
        LiveLoop(arch)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith("process_plant: action use_transmitter_b: its Δ is estimated by "
                          "rollout, which needs a snapshot of the plant")


def test_rollout_action_is_rejected_at_run_time_when_asked() -> None:
    arch = load_text(_with_rollout("use_transmitter_b"), "plant.yaml").arch
    loop = LiveLoop(arch, rollout="reject")
    assert loop.problems
    _drive(arch, loop, until=128.0)  # the drift is seen at ≈ 120 s; the valve clogs at 130 s
    assert loop.switches == []
    evs = [e for d in loop.decisions for e in d.evaluations if e.action == "use_transmitter_b"]
    assert evs and all(e.rejected == "no improvement" for e in evs)
    assert evs[0].detail == f"estimate failed: {NO_ROLLOUT}"


RELAYS = """
archself: 1
name: relays
modules:
  a: {kind: physical, type: generic.relay, residual: {signal: deviation, nominal: 0.1}}
  b: {kind: functional, type: generic.relay, residual: {signal: deviation, nominal: 0.1}}
  c: {kind: functional, type: generic.relay, residual: {signal: deviation, nominal: 0.1}}
edges:
  - {from: a, to: b, weight: 0.5, carries: signal}
  - {from: a, to: c, weight: 0.5, carries: signal}
configurations:
  one: {initial: true, modules: [a, b]}
  two: {modules: [a, c]}
actions:
  - {id: to_c, module: b, kind: substitute, to: two, cost: 0.1,
     improvement: {method: sensitivity, delta_theta: -0.9}}
runtime:
  step_s: 0.1
  period_s: 1.0
  objective: {actual: b.signal, reference: a.signal}
  threshold: 1.0
  cost_weight: 0.1
  stability: {margin: 0.001, lyapunov_alpha: 0.01, horizon_steps: 10}
"""


def test_target_without_a_linear_model_is_refused() -> None:
    arch = load_text(RELAYS, "relays.yaml").arch
    assert live_problems(arch) == ["action to_c: configuration two has no linear model"]
    with pytest.raises(LiveError, match="to_c: configuration two has no linear model"):
        LiveLoop(arch)
    # with the stability filter off nothing needs a model
    off = load_text(RELAYS + "  ablation: {stability: false}\n", "relays.yaml").arch
    assert live_problems(off) == []
    assert LiveLoop(off).problems == []


# ---------------------------------------------------------------------- wire
def test_parse_address() -> None:
    assert parse_address("localhost:8080") == ("localhost", 8080)
    assert parse_address("[::1]:1") == ("::1", 1)
    for bad in ("8080", "host:", ":80", "h:99999", "h:x"):
        with pytest.raises(LiveError, match="not HOST:PORT"):
            parse_address(bad)


def test_plant_listens_on_loopback_only() -> None:
    with pytest.raises(LiveError, match="loopback address only"):
        PlantLink("0.0.0.0", 0)


def test_command_round_trip() -> None:
    c = Command(3.0, "parameters", "raise", "pi", "p1", "p1", {"kp": 5.0})
    assert Command.from_dict(json.loads(json.dumps(c.to_dict()))) == c


def test_loop_gives_up_on_a_silent_plant(arch) -> None:
    link = PlantLink(port=0, timeout_s=10.0)
    accepted = threading.Thread(target=link.accept, daemon=True)
    accepted.start()
    try:
        with pytest.raises(LiveError, match="no message from the peer for 0.3 s"):
            run_remote(LiveLoop(arch), "127.0.0.1", link.port, timeout_s=0.3,
                       token=link.token)
    finally:
        accepted.join(timeout=10.0)
        link.close()


@pytest.mark.parametrize(
    ("line", "message"),
    [  # a plant's malformed lines: one-line LiveErrors (a deep nesting was a RecursionError)
        (b'{"type":"measurement","t":0,"outputs":' + b'{"a":' * 100_000 + b"1"
         + b"}" * 100_000 + b"}", "nested too deeply"),
        (b"\xff\xfe{}", "'utf-8' codec can't decode"),
        (b'{"type":"measurement","t":0,"outputs":{"tank":5}}', "must be a mapping of signals"),
        # an integer of 5,000 digits was an internal error (ValueError)
        (b'{"type":"measurement","t":' + b"7" * 5000 + b"}",
         r"message 1: malformed message: Exceeds the limit \(4300 digits\)"),
    ],
)
def test_loop_refuses_a_malformed_line(arch, line: bytes, message: str) -> None:
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)

        def plant() -> None:
            conn, _ = server.accept()
            with conn:
                conn.makefile("rb").readline()  # hello
                conn.sendall(line + b"\n")
                conn.recv(1)  # until the loop closes the connection

        t = threading.Thread(target=plant, daemon=True)
        t.start()
        with pytest.raises(LiveError, match=message):
            run_remote(LiveLoop(arch), "127.0.0.1", server.getsockname()[1], timeout_s=10.0)
        t.join(timeout=10.0)


def test_loop_reports_a_plant_that_is_not_there(arch) -> None:
    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(LiveError, match="cannot connect to the plant"):
        run_remote(LiveLoop(arch), "127.0.0.1", port, timeout_s=5.0)


# ---------------------------------------------------------------------- two processes
def _first_line(proc: subprocess.Popen, timeout: float) -> str:
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)  # type: ignore[arg-type]
    if not sel.select(timeout):
        proc.kill()
        pytest.fail(f"the plant printed no address within {timeout} s")
    return proc.stdout.readline()  # type: ignore[union-attr]


def test_two_processes_switch_as_the_simulation(tmp_path: Path, simulated) -> None:
    """The plant in one process, `archself live` in another, over loopback TCP."""
    res, _ = simulated
    arch_file = tmp_path / "plant.yaml"
    arch_file.write_text(_plant_text(), encoding="utf-8")
    log = tmp_path / "log.json"
    plant = subprocess.Popen(
        [sys.executable, str(ROOT / "examples" / "live" / "plant_process.py"), str(arch_file),
         "--scenario", SCENARIO, "--port", "0", "--timeout", "60"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        m = re.fullmatch(r"listening on 127\.0\.0\.1:(\d+) token ([0-9a-f]{32})\n",
                         _first_line(plant, 60.0))
        assert m, "the plant did not say where it listens"
        loop = subprocess.run(
            [sys.executable, "-m", "archself", "live", str(arch_file),
             "--connect", f"127.0.0.1:{m.group(1)}", "--json", "--log", str(log),
             "--timeout", "60"],
            env={**os.environ, "ARCHSELF_LIVE_TOKEN": m.group(2)},
            capture_output=True, text=True, timeout=HANG_GUARD_S,
        )
        out, err = plant.communicate(timeout=HANG_GUARD_S)
    except subprocess.TimeoutExpired:
        plant.kill()
        pytest.fail(f"the live run did not finish within {HANG_GUARD_S} s")
    finally:
        if plant.poll() is None:
            plant.kill()
            plant.wait()
    assert loop.returncode == 0, loop.stderr
    assert plant.returncode == 0, err
    result = json.loads(loop.stdout)
    assert result["measurements"] == int(DURATION / 0.2)
    assert _switches(result["switches"]) == _switches(res.switches)
    assert result["final_configuration"] == res.final_configuration == "p4"
    applied = json.loads(out.splitlines()[-1])["applied"]
    assert [(c["t_s"], c["configuration"]) for c in applied if c["kind"] == "configuration"] == [
        (s["t_s"], s["to"]) for s in res.switches
    ]
    assert [c["action"] for c in applied if c["kind"] == "parameters"] == ["raise_pi_gain"]
    first = res.switches[0]  # the console names the switch the simulation made
    assert (f"t = {first['t_s']:g} s: {first['from']} → {first['to']} ({first['action']})"
            in loop.stderr)
    decisions = json.loads(log.read_text(encoding="utf-8"))["decisions"]
    notes = {d["note"] for d in decisions if d["chosen"]}
    assert notes == {"live (no plant snapshot): Δ by sensitivity; stability by eigenvalue "
                     "margin of the compiled models"}


def test_cli_live_refuses_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "plant.yaml"
    bad.write_text(_with_rollout("use_transmitter_b"), encoding="utf-8")
    proc = subprocess.run(
        [sys.executable, "-m", "archself", "live", str(bad), "--connect", "127.0.0.1:9"],
        capture_output=True, text=True, timeout=HANG_GUARD_S,
    )
    assert proc.returncode == 1
    assert proc.stdout == ""
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and "its Δ is estimated by rollout" in lines[0]
    usage = subprocess.run(
        [sys.executable, "-m", "archself", "live", str(bad), "--connect", "nowhere"],
        capture_output=True, text=True, timeout=HANG_GUARD_S,
    )
    assert usage.returncode == 2 and "not HOST:PORT" in usage.stderr


def test_commands_name_the_exported_ros2_modes(arch) -> None:
    from archself.reports.export import ros2_modes

    doc = ros2_modes(arch)
    for conf in arch.configurations:
        part, mode = Command(1.0, "configuration", "a", "m", conf, "p1").ros2_mode(arch.name)
        assert doc[part]["ros__parameters"]["type"] == "system"
        assert mode in doc[part]["ros__parameters"]["modes"]
    updates = [a for a in arch.actions if a.kind == "parameter_update"]
    assert updates
    for a in updates:
        c = Command(1.0, "parameters", a.id, a.module, "p1", "p1", dict(a.set or {}))
        part, mode = c.ros2_mode(arch.name)
        assert part == a.module
        assert doc[part]["ros__parameters"]["modes"][mode]["ros__parameters"] == a.set


def test_cli_live_log_is_checked_first_and_never_lost(tmp_path: Path, monkeypatch) -> None:
    """A --log in a missing folder is refused before connecting; a log that cannot be
    written after the run is kept in a temporary file the message names."""
    import threading

    from typer.testing import CliRunner

    import archself.io.files
    from archself.cli import app
    from archself.errors import OutputError

    arch_file = tmp_path / "plant.yaml"
    arch_file.write_text(_plant_text(), encoding="utf-8")
    early = CliRunner().invoke(app, ["live", str(arch_file), "--connect", "127.0.0.1:9",
                                     "--log", str(tmp_path / "no" / "log.json")])
    assert early.exit_code == 1 and "does not exist" in early.stderr
    assert "connect" not in early.stderr.lower()

    link = PlantLink(port=0, timeout_s=30.0)

    def plant() -> None:
        link.accept()
        for k in range(1, 6):
            link.send(0.2 * k, outputs={"tank": {"level": 1.0},
                                        "setpoint": {"setpoint": [1.0, 0.0]}})
        link.close()

    thread = threading.Thread(target=plant, daemon=True)
    thread.start()

    def refuse(path, text):
        raise OutputError("disk full", str(path))

    monkeypatch.setattr(archself.io.files, "write_text", refuse)
    log = tmp_path / "log.json"
    late = CliRunner().invoke(app, ["live", str(arch_file), "--connect",
                                    f"127.0.0.1:{link.port}", "--log", str(log),
                                    "--token", link.token])
    thread.join(timeout=HANG_GUARD_S)
    assert late.exit_code == 1, late.stderr
    line = late.stderr.strip()
    assert "\n" not in line and "disk full" in line
    kept = Path(line.rsplit("the decision log is kept in ", 1)[1])
    try:
        doc = json.loads(kept.read_text(encoding="utf-8"))
        assert doc["meta"]["measurements"] == 5 and doc["meta"]["mode"] == "live"
    finally:
        kept.unlink()


# ---------------------------------------------------------------------- a hostile link
OUT = {"tank": {"level": 1.0}, "setpoint": {"setpoint": [1.0, 0.0]}}


def _serve(link: PlantLink, times: list[float], got: list) -> threading.Thread:
    """The plant in a thread: accept the loop, send a measurement at each of ``times``."""
    def plant() -> None:
        try:
            got.append(link.accept())
            for t in times:
                got.append(link.send(t, outputs=OUT))
        except LiveError as exc:
            got.append(exc)
        finally:
            link.close()

    thread = threading.Thread(target=plant, daemon=True)
    thread.start()
    return thread


@pytest.mark.parametrize("before", [1, 200])
def test_idle_connections_do_not_lock_the_loop_out(arch, before: int) -> None:
    """An idle local connection (or 200) before the loop: the plant serves the loop."""
    link = PlantLink(port=0, timeout_s=30.0)
    idle = [socket.create_connection(("127.0.0.1", link.port)) for _ in range(before)]
    got: list = []
    try:
        thread = _serve(link, [1.0, 2.0, 3.0], got)
        loop = LiveLoop(arch)
        assert run_remote(loop, "127.0.0.1", link.port, timeout_s=30.0, token=link.token) == 3
        thread.join(timeout=HANG_GUARD_S)
    finally:
        for s in idle:
            s.close()
    assert got[0]["type"] == "hello" and got[1:] == [[], [], []]
    assert loop.mapek.cycle == 3
    assert link.refused == before  # each closed once the loop was in


def test_an_unauthenticated_peer_is_refused(arch) -> None:
    """An impostor connecting first (no token, a wrong one) is refused; the loop is served."""
    link = PlantLink(port=0, timeout_s=30.0)
    got: list = []
    thread = _serve(link, [1.0], got)
    answers = []
    for hello in ({"type": "hello", "protocol": 1}, {"type": "hello", "token": "0" * 32}):
        with socket.create_connection(("127.0.0.1", link.port)) as impostor:
            impostor.sendall(json.dumps(hello).encode() + b"\n")
            answers.append(json.loads(impostor.makefile("rb").readline()))
    assert answers == [{"type": "refused", "reason": "no hello with the plant's token"}] * 2
    with pytest.raises(LiveError, match="the plant refused the loop: no hello with the plant's "
                                        "token .pass the token it printed"):
        run_remote(LiveLoop(arch), "127.0.0.1", link.port, timeout_s=30.0, token="wrong")
    assert run_remote(LiveLoop(arch), "127.0.0.1", link.port, timeout_s=30.0,
                      token=link.token) == 1
    thread.join(timeout=HANG_GUARD_S)
    assert link.refused == 3 and got[-1] == []


def _raw_plant(serve) -> tuple[socket.socket, threading.Thread]:
    """A plant of raw bytes: ``serve(conn)`` after reading the loop's hello."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)

    def plant() -> None:
        conn, _ = server.accept()
        with conn:
            conn.makefile("rb").readline()  # hello
            try:
                serve(conn)
            except OSError:
                pass

    thread = threading.Thread(target=plant, daemon=True)
    thread.start()
    return server, thread


def test_a_trickling_peer_cannot_hold_the_loop(arch) -> None:
    """1 byte per 50 ms of a valid measurement: the timeout is on the whole message
    (per read, the loop took the message after 5 s and went on)."""
    import time

    line = json.dumps({"type": "measurement", "t": 1.0, "outputs": OUT}).encode() + b"\n"

    def trickle(conn: socket.socket) -> None:
        for b in line:
            conn.sendall(bytes([b]))
            time.sleep(0.05)
        conn.recv(1)

    server, thread = _raw_plant(trickle)
    with server, pytest.raises(LiveError, match=r"no whole message from the peer for 1 s "
                                                r"\(\d+ bytes of one came\)"):
        run_remote(LiveLoop(arch), "127.0.0.1", server.getsockname()[1], timeout_s=1.0)
    thread.join(timeout=HANG_GUARD_S)


@pytest.mark.parametrize(("t", "why"), [(1e4, "jumps 9998 s"), (1e308, "jumps 1e+308 s"),
                                        ("3", "'3' is not a number")])
def test_the_wire_refuses_bad_times_located(arch, t, why: str) -> None:
    def plant(conn: socket.socket) -> None:
        f = conn.makefile("rb")
        for k, tk in enumerate([1.0, 2.0, t, 4.0]):
            conn.sendall(json.dumps({"type": "measurement", "t": tk, "outputs": OUT}).encode()
                         + b"\n")
            if k < 2:
                f.readline()
        conn.recv(1)

    server, thread = _raw_plant(plant)
    where = r"^message 3 \(measurement 3\): t: .*"
    with server, pytest.raises(LiveError, match=where + re.escape(why)):
        run_remote(LiveLoop(arch), "127.0.0.1", server.getsockname()[1], timeout_s=30.0)
    thread.join(timeout=HANG_GUARD_S)


# ---------------------------------------------------------------------- the log on every end
def _ending(conn: socket.socket, how: str) -> None:
    if how == "disconnect":
        conn.shutdown(socket.SHUT_RDWR)
        return
    elif how == "malformed":
        conn.sendall(b'{"type": "measurement", "t": 4.0, "outputs": {"tank": 5}}\n')
    conn.recv(1)  # silent (and the others): until the loop closes the connection


@pytest.mark.parametrize(("how", "code", "ended"), [
    ("disconnect", 1, "the plant closed the connection without ending the run"),
    ("silent", 1, "no message from the peer for 2 s"),
    ("malformed", 1, "message 4 (measurement 4): measurement outputs of module 'tank' must be "
                     "a mapping of signals"),
    ("SIGINT", 130, "interrupted (SIGINT)"),
    ("SIGTERM", 143, "terminated (SIGTERM)"),
    ("SIGKILL", -9, None),
])
def test_live_log_keeps_every_decision_on_every_end(tmp_path: Path, how: str, code: int,
                                                    ended: str | None) -> None:
    """Three measurements (three cycles), then the run ends badly: --log holds the three."""
    import signal

    arch_file = tmp_path / "plant.yaml"
    arch_file.write_text(_plant_text(), encoding="utf-8")
    log = tmp_path / "log.json"
    answered = threading.Event()

    def plant(conn: socket.socket) -> None:
        f = conn.makefile("rb")
        for k in (1.0, 2.0, 3.0):
            conn.sendall(json.dumps({"type": "measurement", "t": k, "outputs": OUT}).encode()
                         + b"\n")
            f.readline()
        answered.set()
        _ending(conn, how if how in ("disconnect", "malformed") else "silent")

    server, thread = _raw_plant(plant)
    with server:
        proc = subprocess.Popen(
            [sys.executable, "-m", "archself", "live", str(arch_file), "--connect",
             f"127.0.0.1:{server.getsockname()[1]}", "--log", str(log),
             "--timeout", "2" if how == "silent" else "60"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        try:
            assert answered.wait(HANG_GUARD_S), "the loop answered no measurement"
            if how.startswith("SIG"):
                proc.send_signal(getattr(signal, how))
            _, err = proc.communicate(timeout=HANG_GUARD_S)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        thread.join(timeout=HANG_GUARD_S)
    assert proc.returncode == code, err
    if ended is None:  # killed outright: the journal holds the run
        lines = [json.loads(x) for x in (tmp_path / "log.json.part").read_text().splitlines()]
        assert lines[0]["meta"]["mode"] == "live" and not log.exists()
        decisions = lines[1:]
    else:
        assert len(err.strip().splitlines()) == 1
        assert ended in err if code == 1 else err.strip() == ended.split()[0]
        doc = json.loads(log.read_text(encoding="utf-8"))
        assert doc["meta"]["ended"] == ended
        assert doc["meta"]["measurements"] == 3
        assert not (tmp_path / "log.json.part").exists()
        decisions = doc["decisions"]
    assert [d["cycle"] for d in decisions] == [0, 1, 2]
    assert_allclose([d["t"] for d in decisions], [1.0, 2.0, 3.0], atol=1e-12)
