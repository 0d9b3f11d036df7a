"""The one error hierarchy of archself.

Every error a user can cause derives from :class:`ArchselfError` and carries a
one-line, user-facing message. The CLI prints ``str(err)`` and exits with
``err.exit_code``; it never shows a traceback for these.
"""

from __future__ import annotations


def unknown(what: str, name: str, known: object) -> str:
    """``unknown <what> '<name>'; did you mean '<closest>'? known: a, b, c``, the one message
    of a name that is not there (a scenario, a configuration, a format).

    Examples
    --------
    >>> unknown("scenario", "nomnal", ["nominal", "heater_loss"])
    "unknown scenario 'nomnal'; did you mean 'nominal'? known: nominal, heater_loss"
    """
    import difflib

    options = [str(k) for k in known]  # type: ignore[attr-defined]
    close = difflib.get_close_matches(str(name), options, n=1)
    hint = f" did you mean '{close[0]}'?" if close else ""
    return f"unknown {what} '{name}';{hint} known: {', '.join(options) or 'none'}"


def located(file: str, line: int | None, col: int | None, path: str, message: str,
            severity: str = "") -> str:
    """``file:line:col: [severity:] path: message``, the one format of every located message.

    Examples
    --------
    >>> located("a.yaml", 3, 5, "edges[0].weight", "expected a number", "error")
    'a.yaml:3:5: error: edges[0].weight: expected a number'
    """
    where = file if line is None else f"{file}:{line}:{col or 1}"
    sev = f" {severity}:" if severity else ""
    at = f" {path}:" if path else ""
    return f"{where}:{sev}{at} {message}"


class ArchselfError(Exception):
    """Root of all archself errors; ``str(err)`` is a one-line message for users."""

    exit_code = 1


class LoadError(ArchselfError):
    """A file could not be read or parsed into an architecture.

    Parameters
    ----------
    message : str
        What was expected.
    file : str
        The file the error is in.
    line, col : int, optional
        1-based position of the offending node.
    path : str, optional
        Dotted path of the offending node (``modules.imu.params``).
    """

    def __init__(
        self,
        message: str,
        file: str = "<input>",
        line: int | None = None,
        col: int | None = None,
        path: str = "",
    ) -> None:
        self.message = message
        self.file = file
        self.line = line
        self.col = col
        self.path = path
        super().__init__(self.__str__())

    def __str__(self) -> str:
        return located(self.file, self.line, self.col, self.path, self.message, "error")


class RegistryError(ArchselfError):
    """A module type is unknown, or registered twice."""


class CompileError(ArchselfError):
    """An architecture could not be turned into runtime modules."""


class SimulationError(ArchselfError):
    """A simulation was asked for something the file does not declare."""


class TraceError(ArchselfError):
    """A file (or a decision log) that is not an archself trace."""


class OutputError(ArchselfError):
    """An output file or folder cannot be written."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C would be so that the same clean-up runs; exit code 143.

    A subclass of :class:`KeyboardInterrupt` (not of :class:`Exception`): code that
    catches ``Exception`` (a module's failure, a failed run) does not swallow it.
    """


def raise_terminated(signum: int, frame: object) -> None:
    """A SIGTERM handler: raise :class:`Terminated` in the main thread."""
    raise Terminated()


#: Exit codes of the command line (docs/hardening.md).
EXIT_CODES = {
    0: "success",
    1: "findings, or a user error (bad file, bad value, output refused, work too large)",
    2: "usage error (an option or argument the command does not accept)",
    3: "internal error: a bug of archself (ARCHSELF_DEBUG=1 shows the traceback)",
    130: "interrupted (SIGINT, Ctrl-C); a campaign keeps its finished runs",
    143: "terminated (SIGTERM); a campaign keeps its finished runs",
}
