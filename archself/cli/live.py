"""``archself live``: the MAPE-K loop of a plant in another process (docs/live.md)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

import typer

from archself.cli.base import _die, _fail, _inputs, _known_configuration, _load, _numeric
from archself.errors import ArchselfError
from archself.io.jsondata import DecisionRecordDoc, TraceDocument, document, jsonable


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
    if rollout not in ("refuse", "reject"):
        raise _fail(f"--rollout must be refuse or reject, not {rollout!r}", 2)
    if max_jump is not None and not (math.isfinite(max_jump) and max_jump > 0):
        raise _fail(f"--max-jump {max_jump:g}: expected a finite number of seconds > 0", 2)
    from archself.live import parse_address

    try:
        return parse_address(connect)
    except ArchselfError as exc:
        raise _fail(f"--connect: {exc}", 2) from None


def _run_live(arch_path: Path, host: str, port: int, *, config: str | None, rollout: str,
              timeout: float, log: Path | None, token: str | None,
              max_jump: float | None) -> tuple[Any, Any, str, int]:
    """Load the file, serve the plant until it ends; (arch, loop, start, measurements)."""
    from archself.io.files import protect
    from archself.live import LiveLoop, run_remote

    try:
        _inputs(arch_path)
        _check_log(arch_path, log)
        with protect([arch_path], [log]), _numeric(arch_path):
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
    except ArchselfError as exc:
        raise _die(exc) from None
    return arch, loop, start, served


def _print_live(name: str, loop: Any, start: str, served: int, json_out: bool) -> None:
    """The run's summary: one JSON object, or a line and the commands in time order."""
    if json_out:
        from archself.io.jsondata import LiveDoc

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
    from archself.errors import Terminated

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
        self.fh.write(json.dumps(jsonable(data), separators=(",", ":")) + "\n")
        self.fh.flush()

    def add(self, record: Any) -> None:
        """Append one decision record (a write error: warned once, the run goes on)."""
        if self.fh is None:
            return
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
