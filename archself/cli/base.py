"""The typer app of the ``archself`` command line and what its commands share.

The app with its root callback, the options shared by the commands that run many
simulations, the one-line error helpers (``_fail``, ``_die``), ``_emit`` (stdout or
an atomic file), :func:`guard` (the one input guard of every command), the
numeric-trouble guard and ``main`` (the
``archself`` script: signals, Ctrl-C, one-line errors, exit codes). The commands
live in the sibling modules; :func:`register` adds them to the app (``main``: only the
one it runs, so a command imports only its own module).
"""

from __future__ import annotations

import re
import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager, nullcontext
from enum import StrEnum
from importlib import import_module
from pathlib import Path
from typing import Annotated, Any

import typer

from archself import __version__
from archself.errors import ArchselfError, Terminated, raise_terminated, unknown
from archself.resources import single_thread_blas


def _version(value: bool) -> None:
    if value:
        typer.echo(f"archself {__version__}")
        raise typer.Exit()


def _root(
    version: Annotated[
        bool, typer.Option("--version", "-V", callback=_version, is_eager=True,
                           help="Print the version and exit.")
    ] = False,
) -> None:
    """Carry a system's architecture as data: validate it, simulate it, adapt it (MAPE-K)."""


def _new_app() -> typer.Typer:
    """The typer app with its root options, without commands (:func:`register` adds them)."""
    new = typer.Typer(
        name="archself",
        help="Carry a system's architecture as data: validate it, simulate it, adapt it (MAPE-K).",
        no_args_is_help=True,
        add_completion=True,
        pretty_exceptions_enable=False,
        rich_markup_mode=None,
        context_settings={"help_option_names": ["-h", "--help"]},
    )
    new.callback()(_root)
    return new


#: the app of every command (``archself.cli.app``; :func:`main` runs one of its own)
app = _new_app()


class FigureFormat(StrEnum):
    """File formats of the figures (``--format``)."""

    png = "png"
    pdf = "pdf"
    svg = "svg"


class Mode(StrEnum):
    """Which runs a campaign makes (``--mode``)."""

    both = "both"
    fixed = "fixed"
    adaptive = "adaptive"


class Executor(StrEnum):
    """Where the runs of a campaign or calibration go (``--executor``)."""

    local = "local"
    dask = "dask"


class IdentifyExecutor(StrEnum):
    """``identify --executor``: the campaign executors and ``inline`` (this process)."""

    local = "local"
    dask = "dask"
    inline = "inline"


# Options of the commands that write figures (simulate --report, report, campaign-report).
FormatOption = Annotated[
    list[FigureFormat] | None,
    typer.Option("--format", help="Figure format; repeat for several (e.g. --format pdf "
                 "--format svg). The HTML shows the SVG or PNG (written too if neither is "
                 "asked for)."),
]
DpiOption = Annotated[
    int, typer.Option("--dpi", min=50, max=1200, help="Resolution of PNG figures (dots per inch).")
]


def _formats(chosen: list[FigureFormat] | None, default: str = "png") -> tuple[str, ...]:
    """The ``--format`` values as strings, in order, without repeats (``default`` if none)."""
    if not chosen:
        return (default,)
    return tuple(dict.fromkeys(FigureFormat(c).value for c in chosen))


# Options shared by the commands that run many simulations (campaign, calibrate).
ExecutorOption = Annotated[
    Executor, typer.Option("--executor", help="local (process pool) or dask.")
]
AddressOption = Annotated[
    str | None, typer.Option("--address", help="Dask scheduler, tcp://HOST:PORT.")
]
WorkersOption = Annotated[
    int | None, typer.Option("--workers", min=1, help="Processes (default: all cores).")
]
RootSeedOption = Annotated[
    int, typer.Option("--root-seed", min=0, help="Root of the seed sequence (≥ 0).")
]
PastCapOption = Annotated[  # simulate, campaign
    bool, typer.Option("--yes", help="Run even past the size cap (see docs/hardening.md).")
]


class TraceFormat(StrEnum):
    """Formats of a campaign's run traces (``--trace-format``)."""

    json = "json"
    parquet = "parquet"


#: The name of stdin in findings and messages (``validate -``).
STDIN_NAME = "<stdin>"


def _read_stdin() -> str:
    """Standard input as UTF-8 text, capped like a file (``yaml_source.MAX_FILE_BYTES``)."""
    from archself.io.files import MAX_FILE_BYTES, decode_text

    return decode_text(sys.stdin.buffer.read(MAX_FILE_BYTES + 1), STDIN_NAME)


def color_enabled(stream: Any = None) -> bool:
    """Colour only on a terminal, and never when ``NO_COLOR`` is set (no-color.org).

    ``FORCE_COLOR`` (non-empty) turns it on even off a terminal, e.g. in CI logs.
    """
    import os

    if os.environ.get("NO_COLOR"):
        return False
    if os.environ.get("FORCE_COLOR"):
        return True
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


_SEVERITY_COLORS = {"error": "red", "warning": "yellow", "internal error": "red"}


def colorize(line: str, stream: Any = None) -> str:
    """``PATH: error: …`` with the severity word coloured, when :func:`color_enabled`."""
    if not color_enabled(stream):
        return line
    for word, color in _SEVERITY_COLORS.items():
        for at in (f": {word}:", f"{word}:"):
            i = line.find(at)
            if i == 0 or (i > 0 and at.startswith(":")):
                start = i + (2 if at.startswith(":") else 0)
                end = start + len(word)
                return line[:start] + typer.style(word, fg=color, bold=True) + line[end:]
    return line


#: The longest diagnostic line printed (a value quoted in a message is cut: the message
#: of a 3,000-byte ``!!binary`` scalar was one 4,094-character line).
MAX_ERROR_LINE = 300


def cut_line(line: str, limit: int = MAX_ERROR_LINE) -> str:
    """``line`` cut to ``limit`` characters (the cut marked ``...``), on one line.

    Examples
    --------
    >>> cut_line("a.yaml:1:1: error: " + "x" * 400, 40)
    'a.yaml:1:1: error: xxxxxxxxxxxxxxxxxx...'
    """
    line = " ".join(line.splitlines())
    return line if len(line) <= limit else line[: limit - 3] + "..."


def _err(line: str, *, failing: bool = False) -> None:
    """One diagnostic line on stderr (cut to :data:`MAX_ERROR_LINE`), its severity coloured
    on a terminal; a warning is left out with ``--quiet`` unless it fails the command
    (``failing``: ``validate --strict``)."""
    if LEVEL[0] < 0 and not failing and ": error:" not in line and not line.startswith("error"):
        return
    typer.echo(colorize(cut_line(line)), err=True, color=color_enabled())


#: How much a command says on stderr: -1 ``--quiet``, 0 by default, 1 ``--verbose``.
LEVEL = [0]

QuietOption = Annotated[bool, typer.Option(
    "--quiet", "-q", help="Say only errors on stderr: no warnings, notes or progress.")]
VerboseOption = Annotated[bool, typer.Option(
    "--verbose", "-v", help="Say more on stderr: every numeric warning, the progress bar "
    "also when stderr is not a terminal.")]


def _file_names(ctx: typer.Context, section: str) -> list[str]:
    """The names of ``section`` (scenarios, configurations) of the architecture file given
    on the command line so far; none when there is no readable one."""
    given = [v for v in ctx.params.values() if isinstance(v, Path)]  # parsed, or still
    given += [Path(a) for a in ctx.args if not a.startswith("-")]  # left over (completing)
    path = next((p for p in given if p.is_file()), None)
    if path is None:
        return []
    try:
        from archself.io.files import read_text
        from archself.io.yaml_source import load_data

        data, _ = load_data(read_text(path), str(path))
    except Exception:  # noqa: BLE001 - completion offers nothing rather than fail
        return []
    names = data.get(section) if isinstance(data, dict) else None
    return [str(n) for n in names] if isinstance(names, dict) else []


def complete_scenario(ctx: typer.Context, incomplete: str) -> list[str]:
    """Shell completion of ``--scenario``: the scenarios of the file on the command line."""
    return [n for n in _file_names(ctx, "scenarios") if n.startswith(incomplete)]


def complete_configuration(ctx: typer.Context, incomplete: str) -> list[str]:
    """Shell completion of ``--config``/``--configuration``: the file's configurations."""
    return [n for n in _file_names(ctx, "configurations") if n.startswith(incomplete)]


def complete_format(incomplete: str) -> list[str]:
    """Shell completion of ``export --to``: the export formats."""
    from archself.reports.export import FORMATS

    return [f for f in FORMATS if f.startswith(incomplete)]


#: Option flag → its completion (set by :func:`with_verbosity` where a command gives none).
COMPLETIONS: dict[str, Callable[..., list[str]]] = {
    "--scenario": complete_scenario, "--config": complete_configuration,
    "--configuration": complete_configuration, "--to": complete_format,
}


def _completed(param: Any) -> Any:
    """``param`` with the completion of its flag (:data:`COMPLETIONS`), if it has none."""
    from typing import get_args, get_origin

    from typer.models import OptionInfo

    if get_origin(param.annotation) is not Annotated:
        return param
    base, *meta = get_args(param.annotation)
    info = next((m for m in meta if isinstance(m, OptionInfo)), None)
    flags = () if info is None else (info.default, *(info.param_decls or ()))  # Annotated:
    flag = next((d for d in flags if isinstance(d, str) and d in COMPLETIONS), None)  # names
    if info is None or flag is None or info.autocompletion or info.shell_complete:
        return param
    import copy

    done = copy.copy(info)
    done.autocompletion = COMPLETIONS[flag]
    rest = [done if m is info else m for m in meta]
    return param.replace(annotation=Annotated[(base, *rest)])  # type: ignore[valid-type]


def with_verbosity(command: Any) -> Any:
    """``command`` with the shared ``--quiet``/``--verbose`` options (one shape for all),
    and completion of the scenario, configuration and format options (:data:`COMPLETIONS`).

    The wrapper takes the two options, sets :data:`LEVEL` for the command and calls it
    with its own parameters; giving both is a usage error (exit 2).
    """
    import functools
    import inspect

    sig = inspect.signature(command, eval_str=True)
    sig = sig.replace(parameters=[_completed(p) for p in sig.parameters.values()])

    @functools.wraps(command)
    def run(*args: Any, quiet: bool = False, verbose: bool = False, **kwargs: Any) -> Any:
        if quiet and verbose:
            raise typer.BadParameter("give --quiet or --verbose, not both")
        LEVEL[0] = -1 if quiet else (1 if verbose else 0)
        try:
            return command(*args, **kwargs)
        finally:
            LEVEL[0] = 0

    extra = [inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, default=False, annotation=t)
             for n, t in (("quiet", QuietOption), ("verbose", VerboseOption))]
    params = [*sig.parameters.values(), *extra]
    run.__signature__ = sig.replace(parameters=params)  # type: ignore[attr-defined]
    run.__annotations__ = {**{k: v.annotation for k, v in sig.parameters.items()},
                           "quiet": QuietOption, "verbose": VerboseOption}
    return run


def note(line: str) -> None:
    """An informational line on stderr (a file written, a report's place); not with ``--quiet``."""
    if LEVEL[0] >= 0:
        typer.echo(line, err=True)


def show_progress(json_out: bool = False) -> bool:
    """A progress bar: on a terminal or with ``--verbose``; not with ``--quiet``, ``--json``."""
    if json_out or LEVEL[0] < 0:
        return False
    return LEVEL[0] > 0 or sys.stderr.isatty()


def _fail(msg: str, code: int = 1) -> typer.Exit:
    _err(msg if ":" in msg else f"error: {msg}")
    return typer.Exit(code)


def _die(err: ArchselfError) -> typer.Exit:
    _err(str(err))
    return typer.Exit(err.exit_code)


#: The top-level key of an architecture file, YAML or JSON (``archself: 1``).
_ARCH_KEY = re.compile(r'^\s*\{?\s*"?archself"?\s*:\s*1\b', re.MULTILINE)


def _emit(text: str, output: Path | None, done: str) -> None:
    """Write ``text`` to stdout (no ``output``, or ``-``) or atomically to ``output``.

    An existing architecture file is never written over (``schema -o``, ``export -o``,
    ``generate -o`` pointed at the user's file by mistake), except one that
    ``archself generate`` wrote (``name: generated-N``).
    """
    if output is None or str(output) == "-":
        sys.stdout.write(text)
        return
    from archself.io.files import protect, write_text

    if output.is_file():
        try:
            with open(output, "rb") as fh:
                head = fh.read(65536).decode("utf-8", "replace")
        except OSError:
            head = ""
        if _ARCH_KEY.search(head) and '"name": "generated-' not in head:
            raise _fail(f"{output}: error: is an architecture file; refusing to write over "
                        "it (choose another name)")
    try:
        with protect([], [output]):
            write_text(output, text)
    except ArchselfError as exc:
        raise _die(exc) from None
    note(done)


#: Files ``simulate --report DIR`` writes that an input could be named like.
_RUN_REPORT_FILES = ("index.html", "summary.json")


def _inputs(*paths: Path, what: str = "an architecture file") -> None:
    """Every input must be a regular file: not missing, a folder, a FIFO or a device."""
    from archself.io.files import check_input

    for p in paths:
        if str(p) != "-":  # stdin, read by _load
            check_input(p, what)


@contextmanager
def guard(
    *inputs: Path | tuple[Path | None, str] | None,
    refuse: Iterable[tuple[str, Path | None]] = (),
    locks: Iterable[Path | None] = (),
    check: Callable[[], None] | None = None,
    what: str = "an architecture file",
    numeric: bool = True,
) -> Iterator[None]:
    """The one input guard of the commands, around a command's work.

    In this order: every input is a regular file (``-``, stdin, passes); no output of
    ``refuse`` is one of the inputs; ``check`` runs; then, while the block runs, the
    inputs are not written over, ``locks`` are locked against other commands
    (``io.atomic.protect``) and numeric trouble is a located line about the first input
    (:func:`_numeric`). An :class:`ArchselfError` of any step or of the block is its
    one-line message and exit code (:func:`_die`).

    Parameters
    ----------
    *inputs : path, (path, what) or None
        The files the command reads (None: left out); ``what`` names one in the message
        of a missing or wrong input (default: the ``what`` keyword).
    refuse : iterable of (flag, path)
        Outputs that must not be an input (None and ``-`` left out).
    locks : iterable of path
        The files and folders the command writes.
    check : callable, optional
        The command's own output checks, before anything is locked.
    numeric : bool
        Catch numeric trouble (False: the command has none or handles it).
    """
    from archself.io.files import protect, refuse_same_file

    pairs = [item if isinstance(item, tuple) else (item, what) for item in inputs]
    given = [p for p, _ in pairs if p is not None]
    try:
        for path, kind in pairs:
            if path is not None:
                _inputs(path, what=kind)
        for flag, target in refuse:
            if target is not None and str(target) != "-":
                refuse_same_file(given, target, flag)
        if check is not None:
            check()
        with protect(given, locks), _numeric(given[0]) if numeric else nullcontext():
            yield
    except ArchselfError as exc:
        raise _die(exc) from None


@contextmanager
def _numeric(path: Path) -> Iterator[None]:
    """Numeric trouble of the libraries as located one-line messages.

    Warnings of numpy/scipy (overflow, singular matrix, ...) are collected and
    printed once each (at most 5) as ``PATH: warning: ...`` when the command
    succeeds, and dropped when it fails (its one-line message says why);
    an OverflowError or FloatingPointError (a value of the file out of the range of
    a float, e.g. ``acceptable: 1e308`` squared) is a one-line error, exit 1.
    """
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        try:
            yield
        except (OverflowError, FloatingPointError) as exc:
            detail = str(exc.args[-1]) if exc.args else type(exc).__name__
            raise _fail(
                f"{path}: error: a value of the file is out of the range of the computation "
                f"({type(exc).__name__}: {detail}); use smaller magnitudes"
            ) from None
        # after a success only: an error's one-line message is not led by warnings
        lines = numeric_lines(caught, lambda w, text: f"{path}: warning: {w.category.__name__}: "
                              f"{text} (in {Path(w.filename).name})", LEVEL[0] <= 0)
        for line in lines if LEVEL[0] >= 0 else ():  # none with --quiet
            typer.echo(line, err=True)


def numeric_lines(caught: list[Any], form: Callable[[Any, str], str], cap: bool) -> list[str]:
    """The distinct lines ``form(warning, first line of its message)`` of the numeric
    warnings in ``caught`` (:func:`_numeric_warning`), in order; at most 5 with ``cap``."""
    out: list[str] = []
    for w in filter(_numeric_warning, caught):
        line = form(w, (str(w.message).splitlines() or [""])[0])
        if line not in out and (len(out) < 5 or not cap):
            out.append(line)
    return out


def _numeric_warning(w: Any) -> bool:
    """A warning worth showing: from numpy/scipy/the runtime, not a library's deprecation."""
    if issubclass(w.category, DeprecationWarning | PendingDeprecationWarning):
        return False
    return issubclass(w.category, RuntimeWarning) or "numpy" in w.category.__module__ or (
        "scipy" in w.category.__module__
    )


def _known_configuration(arch: Any, config: str | None, path: Path) -> None:
    """``--config`` must name a configuration of the file (one-line error, exit 1)."""
    if config is not None and config not in arch.configurations:
        raise _fail(f"{path}: {unknown('configuration', config, arch.configurations)}")


def _load(path: Path):
    from archself.check import check, has_errors
    from archself.model.loader import load_architecture

    if str(path) == "-":
        from archself.model.loader import load_text

        loaded = load_text(_read_stdin(), STDIN_NAME)
    else:
        loaded = load_architecture(path)
    findings = check(loaded)
    if has_errors(findings):
        for f in findings:
            if f.severity == "error":
                _err(str(f))
        raise typer.Exit(1)
    return loaded.arch


#: command → (module of :mod:`archself.cli`, function), in the order of ``--help``
COMMANDS = {
    "validate": ("files", "validate"),
    "schema": ("files", "schema"),
    "docs": ("files", "docs"),
    "init": ("files", "init"),
    "simulate": ("runs", "simulate"),
    "report": ("reports", "report"),
    "explain": ("runs", "explain"),
    "live": ("live", "live"),
    "ros2": ("live", "ros2"),
    "campaign": ("campaigns", "campaign"),
    "campaign-report": ("campaigns", "campaign_report_cmd"),
    "export": ("files", "export"),
    "info": ("files", "info"),
    "calibrate": ("calibration", "calibrate"),
    "identify": ("calibration", "identify"),
    "generate": ("files", "generate"),
}
_WRAPPED: dict[str, Any] = {}


def register(names: Any = None, into: typer.Typer | None = None) -> typer.Typer:
    """``into`` (default :data:`app`) with the commands ``names`` (default: all), in
    :data:`COMMANDS` order."""
    into = app if into is None else into
    into.registered_commands = []
    for name, (module, function) in COMMANDS.items():
        if names is None or name in names:
            if name not in _WRAPPED:
                command = getattr(import_module(f"archself.cli.{module}"), function)
                _WRAPPED[name] = with_verbosity(command)
            into.command(name)(_WRAPPED[name])
    return into


def main() -> None:
    """Entry point of the ``archself`` script: the command named, else every command, runs."""

    single_thread_blas()  # before numpy loads: small matrices, no use for BLAS threads
    first = sys.argv[1] if len(sys.argv) > 1 else None  # `archself --help x`: every command
    cli = register([first], _new_app()) if first in COMMANDS else register()
    import signal

    signal.signal(signal.SIGTERM, raise_terminated)  # the clean-up of Ctrl-C, exit 143
    def stopped(exc: KeyboardInterrupt) -> SystemExit:
        terminated = isinstance(exc, Terminated)
        typer.echo("terminated" if terminated else "interrupted", err=True)
        return SystemExit(143 if terminated else 130)

    try:
        cli()
    except SystemExit as exc:
        # typer turns Ctrl-C into a silent exit 130: say what happened
        cause = exc.__context__.__cause__ if exc.__context__ is not None else None
        if exc.code == 130 and isinstance(cause, KeyboardInterrupt):
            raise stopped(cause) from None
        raise
    except KeyboardInterrupt as exc:
        raise stopped(exc) from None
    except ArchselfError as exc:
        _err(str(exc))
        raise SystemExit(exc.exit_code) from None
    except MemoryError:
        typer.echo("error: out of memory; the work asked for is too large for this machine",
                   err=True)
        raise SystemExit(1) from None
    except OSError as exc:  # the system refused (permissions, disk full): not a bug
        where = f"{exc.filename}: " if exc.filename else ""
        typer.echo(f"{where}error: {exc.strerror or exc}", err=True)
        raise SystemExit(1) from None
    except Exception as exc:  # a bug, not a user error: say so in one line
        import os

        if os.environ.get("ARCHSELF_DEBUG"):
            raise
        _err(f"internal error: {cut_line(f'{type(exc).__name__}: {exc}', 200)} "
             "(set ARCHSELF_DEBUG=1 for the traceback; please report it)")
        raise SystemExit(3) from None
