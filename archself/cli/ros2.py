"""``archself ros2``: the MAPE-K loop as a ROS 2 node (docs/ros2.md)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from archself.cli.base import _die, _fail, _inputs, _known_configuration, _load, _numeric
from archself.errors import ArchselfError
from archself.io.jsondata import jsonable


def ros2(
    arch_path: Annotated[Path, typer.Argument(metavar="ARCH", help="Architecture file.")],
    nodes: Annotated[
        str | None,
        typer.Option("--nodes", metavar="M1,M2,...",
                     help="The modules that are ROS 2 nodes (default: the functional ones)."),
    ] = None,
    clock: Annotated[
        str | None,
        typer.Option("--clock", metavar="timer|tick",
                     help="A cycle every period_s on the node's clock (timer, the default), "
                     "or in lock step with a plant's ticks (tick, the default of --demo; "
                     "--demo --clock timer: a free-running plant on /clock)."),
    ] = None,
    demo: Annotated[
        bool,
        typer.Option("--demo", help="Also start the simulated robot as ROS 2 nodes (a plant "
                     "node and lifecycle nodes; needs --scenario)."),
    ] = False,
    scenario: Annotated[
        str | None, typer.Option("--scenario", "-s", help="--demo: the scenario to run.")
    ] = None,
    seed: Annotated[
        int | None, typer.Option("--seed", min=0, help="--demo: seed (default: the scenario's).")
    ] = None,
    duration: Annotated[
        float | None,
        typer.Option("--duration", min=0.0, help="--demo: seconds to run (default: the "
                     "scenario's)."),
    ] = None,
    linger: Annotated[
        float,
        typer.Option("--linger", min=0.0, max=3600.0,
                     help="--demo: seconds the robot's nodes stay up after the run."),
    ] = 0.0,
    rate: Annotated[
        float | None,
        typer.Option("--rate", min=0.001, help="--demo: simulated seconds per second (1: real "
                     "time; default: as fast as the loop answers)."),
    ] = None,
    config: Annotated[
        str | None,
        typer.Option("--config", "-c", help="Configuration the robot starts in (default: "
                     "initial)."),
    ] = None,
    timeout: Annotated[
        float,
        typer.Option("--timeout", min=0.1, max=86400.0,
                     help="Seconds of silence (or a service's delay) before giving up (exit 1)."),
    ] = 30.0,
    rollout: Annotated[
        str,
        typer.Option("--rollout", metavar="refuse|reject",
                     help="Actions only a rollout could judge: refuse the file or reject them."),
    ] = "refuse",
    json_out: Annotated[
        bool, typer.Option("--json", help="Print one JSON object {architecture, measurements, "
                           "cycles, configuration, final_configuration, switches, updates, ros2} "
                           "(docs/json.md).")
    ] = False,
    log: Annotated[
        Path | None,
        typer.Option("--log", metavar="FILE",
                     help="Write the decision log to FILE (JSON, read by `archself explain`)."),
    ] = None,
) -> None:
    """Run the MAPE-K loop as a ROS 2 node: topics in, lifecycle and parameter services out.

    Run it inside a network namespace with only loopback when trying it
    (`unshare -n sh -c 'ip link set lo up; exec archself ros2 ...'`) or set
    ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; see docs/ros2.md.
    """
    _ros2(arch_path, nodes, clock, demo, scenario, seed, duration, linger, rate, config,
          timeout, rollout, json_out, log)


def _ros2(arch_path: Path, nodes: str | None, clock: str | None, demo: bool,
          scenario: str | None, seed: int | None, duration: float | None, linger: float,
          rate: float | None, config: str | None, timeout: float, rollout: str,
          json_out: bool, log: Path | None) -> None:
    """The command's work: check the options and the file, start the demo plant if asked,
    run the bridge until the plant ends (or the timeout), write the log, print the result."""
    clock = _check_options(clock, rollout, demo, scenario)
    from archself.cli.live import _check_log, _log, _say_command, _write_log
    from archself.io.files import protect
    from archself.ros2.base import require_rclpy

    child: subprocess.Popen[str] | None = None
    try:
        _inputs(arch_path)
        _check_log(arch_path, log)
        with protect([arch_path], [log]), _numeric(arch_path):
            arch = _load(arch_path)
            _known_configuration(arch, config, arch_path)
            if demo and scenario not in arch.scenarios:
                raise _fail(f"{arch_path}: error: --scenario: no scenario {scenario!r}; "
                            f"scenarios: {', '.join(arch.scenarios)}")
            part_list = [n.strip() for n in nodes.split(",") if n.strip()] if nodes else None
            from archself.reports.export import node_modules

            node_modules(arch, part_list)  # unknown names: one line before ROS starts
            require_rclpy()
            from archself.ros2.bridge import Ros2Bridge, run_bridge

            if demo:
                cmd = _demo_command(arch_path, str(scenario), timeout, linger, rate, clock, seed,
                                    duration, nodes)
                child = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
            bridge = Ros2Bridge(arch, nodes=part_list, clock=clock, configuration=config,
                                rollout=rollout, service_timeout_s=timeout,
                                use_sim_time=demo and clock == "timer")
            start = bridge.loop.configuration
            bridge.loop.on_command(_say_command)
            bridge.start()
            until = (lambda: child.poll() is not None) if child is not None else None
            stats = run_bridge(bridge, timeout_s=timeout, until=until)
            loop = bridge.loop
            if log is not None:
                _write_log(log, json.dumps(jsonable(_log(loop, arch_path, start,
                                                         loop.measurements)),
                                           separators=(",", ":")) + "\n")
            bridge.destroy()
    except ArchselfError as exc:
        raise _die(exc) from None
    finally:
        if child is not None:
            _end(child, linger)
    if child is not None and child.returncode != 0:
        raise _fail(f"{arch_path}: error: the demo plant ended with exit {child.returncode}")
    _print_result(arch.name, start, loop, stats, json_out)


def _end(child: subprocess.Popen[str], linger: float) -> None:
    """Wait for the demo plant (it ends with the run); terminate it if it does not."""
    try:
        child.wait(timeout=10.0 + linger)
    except subprocess.TimeoutExpired:
        child.terminate()
        try:
            child.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
    if child.stdout is not None:
        child.stdout.close()


def _check_options(clock: str | None, rollout: str, demo: bool, scenario: str | None) -> str:
    """The clock to run (``tick`` for the demo, else ``timer``); usage errors, exit 2."""
    clock = clock or ("tick" if demo else "timer")
    if clock not in ("timer", "tick"):
        raise _fail(f"--clock must be timer or tick, not {clock!r}", 2)
    if rollout not in ("refuse", "reject"):
        raise _fail(f"--rollout must be refuse or reject, not {rollout!r}", 2)
    if demo and scenario is None:
        raise _fail("--demo needs --scenario", 2)
    return clock


def _demo_command(arch_path: Path, scenario: str, timeout: float, linger: float,
                  rate: float | None, clock: str, seed: int | None, duration: float | None,
                  nodes: str | None) -> list[str]:
    """The command line of the demo plant (``python -m archself.ros2.demo``)."""
    cmd = [sys.executable, "-m", "archself.ros2.demo", str(arch_path),
           "--scenario", scenario, "--timeout", str(timeout), "--linger", str(linger)]
    cmd += ["--rate", str(rate)] if rate is not None else []
    cmd += ["--free"] if clock == "timer" else []
    cmd += ["--seed", str(seed)] if seed is not None else []
    cmd += ["--duration", str(duration)] if duration is not None else []
    cmd += ["--nodes", nodes] if nodes else []
    return cmd


def _print_result(name: str, start: str, loop: Any, stats: dict[str, Any],
                  json_out: bool) -> None:
    """The run's summary on stdout: JSON, or one line and the switches, updates and figures."""
    from archself.cli.live import _result

    if json_out:
        from archself.io.jsondata import Ros2Doc, document

        result = {**_result(name, start, loop, loop.measurements), "ros2": stats}
        typer.echo(json.dumps(document(Ros2Doc, result, complete=True), indent=1))
        return
    path = " → ".join([start, *(str(s["to"]) for s in loop.switches)])
    typer.echo(f"{name} · ros2 · {loop.measurements} measurements · {loop.mapek.cycle} "
               f"cycles · {path}")
    for s in loop.switches:
        typer.echo(f"  t = {s['t_s']:g} s: {s['from']} → {s['to']} ({s['action']})")
    for u in loop.updates:
        typer.echo(f"  t = {u['t_s']:g} s: {u['module']} ← {u['set']} ({u['action']})")
    rt = (stats["plant"] or {}).get("round_trip_ms") or {}
    typer.echo(f"  {stats['messages_per_s']:.0f} messages/s in, bridge CPU "
               f"{stats['cpu_percent']:.0f} %" + (
                   f", measurement → answer p50 {rt['p50']:.2f} ms, p95 {rt['p95']:.2f} ms"
                   if rt else ""))
