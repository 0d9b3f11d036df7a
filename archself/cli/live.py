"""The MAPE-K loop on a plant outside archself: ``archself live`` (a plant in another
process over a local socket, docs/live.md) and ``archself ros2`` (the loop as a ROS 2
node, ``--demo`` starting the demo plant as a child process, docs/ros2.md); both keep
the decision log (``--log``) and print the same summary."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from archself.cli.base import _fail, _known_configuration, _load, guard
from archself.errors import ArchselfError, Terminated


def live(
    arch_path: Annotated[Path, typer.Argument(metavar="ARCH", help="Architecture file.")],
    connect: Annotated[
        str,
        typer.Option("--connect", metavar="HOST:PORT",
                     help="The plant's address (it listens; JSON lines, docs/live.md)."),
    ],
    config: Annotated[
        str | None,
        typer.Option("--config", "-c",
                     help="Configuration the plant starts in (default: initial)."),
    ] = None,
    timeout: Annotated[
        float,
        typer.Option("--timeout", min=0.1, max=86400.0,
                     help="Seconds of silence from the plant before giving up (exit 1)."),
    ] = 30.0,
    rollout: Annotated[
        str,
        typer.Option("--rollout", metavar="refuse|reject",
                     help="Actions only a rollout could judge: refuse the file (default) or "
                     "reject those actions at run time."),
    ] = "refuse",
    json_out: Annotated[
        bool,
        typer.Option("--json", help="Print one JSON object {architecture, measurements, cycles, "
                     "configuration, final_configuration, switches, updates} (docs/json.md)."),
    ] = False,
    log: Annotated[
        Path | None,
        typer.Option("--log", metavar="FILE",
                     help="Write the decision log to FILE (JSON, read by `archself explain`); "
                     "kept on every end, FILE.part holds it while the run lasts."),
    ] = None,
    token: Annotated[
        str | None,
        typer.Option("--token", metavar="TOKEN", envvar="ARCHSELF_LIVE_TOKEN",
                     show_envvar=True,
                     help="The token the plant printed (it refuses a loop without it)."),
    ] = None,
    max_jump: Annotated[
        float | None,
        typer.Option("--max-jump", metavar="SECONDS",
                     help="Longest forward jump of the plant's clock between two "
                     "measurements (default: 100 MAPE-K periods); longer: refused, exit 1."),
    ] = None,
) -> None:
    """Run the MAPE-K loop on a plant that pushes measurements over a local socket.

    The plant listens at HOST:PORT and sends a measurement each step; every one is
    answered with the reconfiguration commands decided on it. Δ and stability come
    from the architecture's compiled models (no snapshot of a real plant exists).
    Stops when the plant ends the run; on any other end (the plant gone, silent or
    malformed, Ctrl-C, SIGTERM) --log FILE still holds every decision taken.
    """
    host, port = _guards(connect, rollout, max_jump)
    arch, loop, start, served = _run_live(arch_path, host, port, config=config, rollout=rollout,
                                          timeout=timeout, log=log, token=token,
                                          max_jump=max_jump)
    _print_live(arch.name, loop, start, served, json_out)


def _guards(connect: str, rollout: str, max_jump: float | None) -> tuple[str, int]:
    """The options checked before anything is read: the plant's host and port."""
    _check_rollout(rollout)
    if max_jump is not None and not (math.isfinite(max_jump) and max_jump > 0):
        raise _fail(f"--max-jump {max_jump:g}: expected a finite number of seconds > 0", 2)
    from archself.live import parse_address

    try:
        return parse_address(connect)
    except ArchselfError as exc:
        raise _fail(f"--connect: {exc}", 2) from None


def _check_rollout(rollout: str) -> None:
    """``--rollout`` is refuse or reject (a usage error, exit 2)."""
    if rollout not in ("refuse", "reject"):
        raise _fail(f"--rollout must be refuse or reject, not {rollout!r}", 2)


def _run_live(arch_path: Path, host: str, port: int, *, config: str | None, rollout: str,
              timeout: float, log: Path | None, token: str | None,
              max_jump: float | None) -> tuple[Any, Any, str, int]:
    """Load the file, serve the plant until it ends; (arch, loop, start, measurements)."""
    from archself.live import LiveLoop, run_remote

    with guard(arch_path, check=lambda: _check_log(arch_path, log), locks=[log]):
        arch = _load(arch_path)
        _known_configuration(arch, config, arch_path)
        loop = LiveLoop(arch, configuration=config, rollout=rollout, max_jump_s=max_jump)
        start = loop.configuration
        loop.on_command(_say_command)
        journal = None if log is None else _Journal(log, loop, arch_path, start)
        try:
            served = run_remote(loop, host, port, timeout_s=timeout, token=token)
        except BaseException as exc:
            if journal is not None:
                journal.finish(_ending(exc))
            raise
        if journal is not None:
            journal.finish(None)
    return arch, loop, start, served


def _print_live(name: str, loop: Any, start: str, served: int, json_out: bool) -> None:
    """The run's summary: one JSON object, or a line and the commands in time order."""
    if json_out:
        from archself.io.jsondata import LiveDoc, document

        typer.echo(json.dumps(document(LiveDoc, _result(name, start, loop, served),
                                       complete=True), indent=1))
        return
    path = " → ".join([start, *(str(s["to"]) for s in loop.switches)])
    typer.echo(f"{name} · live · {served} measurements · {loop.mapek.cycle} cycles · {path}")
    lines = [(s["t_s"], f"{s['from']} → {s['to']} ({s['action']})") for s in loop.switches]
    lines += [(u["t_s"], f"{u['module']} ← {u['set']} ({u['action']})") for u in loop.updates]
    for t_s, what in sorted(lines, key=lambda line: line[0]):  # in time order
        typer.echo(f"  t = {t_s:g} s: {what}")


def _say_command(c: Any) -> None:
    """A command the loop sent to the plant, on stderr."""
    typer.echo(f"t = {c.t_s:g} s: {c.previous} → {c.configuration} ({c.action})"
               if c.kind == "configuration" else
               f"t = {c.t_s:g} s: {c.module} ← {c.values} ({c.action})", err=True)


def _result(name: str, start: str, loop: Any, measurements: int) -> dict[str, Any]:
    """The run's summary as ``--json`` prints it (``ros2`` adds its figures)."""
    return {
        "architecture": name, "measurements": measurements, "cycles": loop.mapek.cycle,
        "configuration": start, "final_configuration": loop.configuration,
        "switches": loop.switches, "updates": loop.updates,
    }


def _ending(exc: BaseException) -> str:
    """How a live run ended, for the log's ``meta.ended``."""

    if isinstance(exc, Terminated):
        return "terminated (SIGTERM)"
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted (SIGINT)"
    if isinstance(exc, ArchselfError):
        return str(exc)
    return type(exc).__name__


class _Journal:
    """``--log FILE`` while the run lasts: ``FILE.part``, one JSON line per cycle.

    The first line is ``{"meta": ...}`` (the run as it starts), every next one a
    decision record, appended and flushed as its cycle ends, so a loop killed
    outright (SIGKILL) leaves every decision behind. :meth:`finish` writes FILE
    (the document of a clean end, with ``meta.ended`` on any other) and removes
    the journal.
    """

    def __init__(self, log: Path, loop: Any, arch_path: Path, start: str) -> None:
        self.log, self.loop, self.arch_path, self.start = log, loop, arch_path, start
        self.part = log.with_name(log.name + ".part")
        try:
            self.fh: Any = open(self.part, "w", encoding="utf-8")  # noqa: SIM115
            self._line({"meta": _log(loop, arch_path, start, 0)["meta"]})
        except OSError as exc:
            raise _fail(f"{self.part}: cannot write: {exc.strerror or exc}") from None
        loop.on_cycle(self.add)

    def _line(self, data: Any) -> None:
        from archself.io.jsondata import jsonable

        self.fh.write(json.dumps(jsonable(data), separators=(",", ":")) + "\n")
        self.fh.flush()

    def add(self, record: Any) -> None:
        """Append one decision record (a write error: warned once, the run goes on)."""
        if self.fh is None:
            return
        from archself.io.jsondata import DecisionRecordDoc, document

        try:
            self._line(document(DecisionRecordDoc, record))
        except OSError as exc:
            typer.echo(f"warning: {self.part}: cannot write: {exc.strerror or exc}; the "
                       f"decision log is kept in memory until the end", err=True)
            self.fh.close()
            self.fh = None

    def finish(self, ended: str | None) -> None:
        """Write FILE (``ended``: why the run stopped, None for a clean end); drop the journal."""
        doc = _log(self.loop, self.arch_path, self.start, self.loop.measurements)
        if ended is not None:
            doc["meta"]["ended"] = ended
        try:
            _write_log(self.log, json.dumps(doc, separators=(",", ":")) + "\n")
        finally:
            if self.fh is not None:
                self.fh.close()
            try:
                self.part.unlink()
            except OSError:
                pass


def _check_log(arch_path: Path, log: Path | None) -> None:
    """Refuse a ``--log`` onto the input or where no file can be, before the run, not after."""
    if log is None:
        return
    from archself.io.files import refuse_same_file

    refuse_same_file([arch_path], log, "--log")
    if log.is_dir() or not log.parent.is_dir():
        what = "is a folder" if log.is_dir() else f"folder {log.parent} does not exist"
        raise _fail(f"{log}: error: --log {what}; the decision log needs a file")


def _write_log(log: Path, text: str) -> None:
    """Write the decision log; if FILE cannot be written, keep it in a temporary file.

    A live run cannot be repeated (the plant went its own way), so its log is never
    dropped: the one-line error names where it was kept.
    """
    from archself.io.files import write_text

    try:
        write_text(log, text)
    except ArchselfError as exc:
        import os
        import tempfile

        fd, spare = tempfile.mkstemp(prefix="archself-live-", suffix=".json")
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        raise _fail(f"{exc}; the decision log is kept in {spare}") from None


def _log(loop: Any, arch_path: Path, start: str, served: int) -> dict[str, Any]:
    """The run as a trace document without series: ``{meta, series, decisions}`` (a
    :class:`~archself.io.jsondata.TraceDocument`)."""
    from archself.io.jsondata import TraceDocument, document

    meta = {
        "architecture": loop.arch.name,
        "file": str(arch_path),
        "mode": "live",
        "scenario": "live",  # no scenario: the plant's own course
        "seed": 0,  # of the compiled models (never stepped)
        "metrics": {},
        "configuration": start,
        "final_configuration": loop.configuration,
        "step_s": float(loop.arch.runtime.step_s),
        "period_s": float(loop.arch.runtime.period_s),
        "measurements": served,
        "switches": loop.switches,
        "updates": loop.updates,
        "configurations": list(loop.arch.configurations),
    }
    return document(TraceDocument, {"meta": meta, "series": {}, "decisions": loop.decisions})


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
    from archself.ros2.base import require_rclpy

    child: subprocess.Popen[str] | None = None
    try:
        with guard(arch_path, check=lambda: _check_log(arch_path, log), locks=[log]):
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
                from archself.io.jsondata import jsonable

                _write_log(log, json.dumps(jsonable(_log(loop, arch_path, start,
                                                         loop.measurements)),
                                           separators=(",", ":")) + "\n")
            bridge.destroy()
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
    _check_rollout(rollout)
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
