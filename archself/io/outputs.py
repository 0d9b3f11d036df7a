"""The inputs and outputs of one command: inputs are files, outputs never land on an input.

Every command that reads a file and writes another checks, before it starts,
that no output is an input (the same file: same ``st_dev`` and ``st_ino``,
whatever the path, a hard link or a symbolic link), that no input lies inside
an output folder that is replaced as a whole, and that every input is a
regular file (``/dev/zero`` is refused, not read until memory runs out; a FIFO is
refused, not opened: without a writer the open would block forever). The
inputs are also registered with :func:`archself.io.atomic.protect`, so that a write
the up-front check could not foresee is refused at the moment it would happen.
``--force`` never lifts these checks: it allows replacing an old *output*.

Examples
--------
>>> import tempfile, pathlib
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> (d / "a.yaml").write_text("x")
1
>>> try:
...     refuse_same_file([d / "a.yaml"], d / "a.yaml", "--trace")
... except OutputError as err:
...     print(str(err).split(": ", 1)[1])
error: --trace is the input file a.yaml; refusing to write over it (even with --force)
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterable
from pathlib import Path

from archself.errors import LoadError, OutputError

__all__ = [
    "check_input",
    "file_kind",
    "file_ids",
    "input_inside",
    "refuse_input_inside",
    "refuse_foreign_folder",
    "refuse_same_file",
    "stat_input",
]

_KINDS = (
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISDIR, "a directory"),
)


def file_kind(mode: int) -> str | None:
    """What a file of ``st_mode`` ``mode`` is when it is not a regular file, else None.

    Examples
    --------
    >>> file_kind(stat.S_IFIFO), file_kind(stat.S_IFREG)
    ('a FIFO (named pipe)', None)
    """
    return next((kind for test, kind in _KINDS if test(mode)), None)


def check_input(path: str | Path, what: str = "file") -> None:
    """Refuse an input that is missing or not a regular file (a FIFO, a device, a socket).

    Only ``stat`` is called: nothing is opened, so a FIFO cannot block.

    Raises
    ------
    LoadError
        ``PATH: error: no such file`` or ``PATH: error: is a FIFO (named pipe), expected ...``.
    """
    kind = file_kind(stat_input(path).st_mode)
    if kind is not None:
        raise LoadError(f"is {kind}, expected {what}", str(path))


def path_problem(path: object) -> str | None:
    """Why ``path`` (an argument of the Python API) names no file, or None.

    ``os.stat`` takes an ``int`` as a file descriptor and YAML text as a long name;
    ``None``, an :class:`~archself.model.architecture.Architecture` or a list are not paths.

    Examples
    --------
    >>> path_problem("a.yaml") is None
    True
    >>> path_problem(None)
    'expected the path of a file (str or Path), got NoneType'
    """
    if not isinstance(path, str | bytes | os.PathLike):
        return f"expected the path of a file (str or Path), got {type(path).__name__}"
    text = os.fsdecode(path)
    if not text:
        return "expected the path of a file, got an empty string"
    if "\n" in text:
        return (f"expected the path of a file, got a text of {text.count(chr(10)) + 1} lines "
                "(the file's content?)")
    return None


def stat_input(path: str | Path) -> os.stat_result:
    """``os.stat`` of an input; a missing or unreadable one is a :class:`LoadError`."""
    problem = path_problem(path)
    if problem is not None:
        raise LoadError(problem, "<argument>")
    try:
        return os.stat(path)
    except FileNotFoundError:
        raise LoadError("no such file", str(path)) from None
    except OSError as exc:
        raise LoadError(f"cannot read: {exc.strerror or exc}", str(path)) from None


def file_ids(path: str | Path) -> set[tuple[int, int]]:
    """``(st_dev, st_ino)`` of ``path`` and, for a symbolic link, of what it points to."""
    out: set[tuple[int, int]] = set()
    for fn in (os.lstat, os.stat):
        try:
            st = fn(path)
        except (OSError, ValueError):
            continue
        out.add((st.st_dev, st.st_ino))
    return out


def refuse_same_file(inputs: Iterable[str | Path], target: str | Path, what: str) -> None:
    """Raise :class:`OutputError` if ``target`` is one of ``inputs`` (same inode).

    Parameters
    ----------
    inputs : paths
        The files the command reads.
    target : path
        A file the command is about to write.
    what : str
        The option that names ``target`` (``--trace``, ``--out``), for the message.
    """
    ids = file_ids(target)
    if not ids:
        return
    for inp in inputs:
        if ids & file_ids(inp):
            raise OutputError(
                f"{target}: error: {what} is the input file {Path(inp).name}; "
                "refusing to write over it (even with --force)"
            )


def input_inside(inputs: Iterable[str | Path], folder: str | Path) -> Path | None:
    """The first input that lies inside ``folder`` (at any depth), or None."""
    fids = file_ids(folder)
    if not fids:
        return None
    for inp in inputs:
        try:
            parent = Path(os.path.realpath(inp)).parent
        except (OSError, ValueError):
            continue
        for d in (parent, *parent.parents):
            if file_ids(d) & fids:
                return Path(inp)
    return None


def refuse_input_inside(inputs: Iterable[str | Path], folder: str | Path, what: str) -> None:
    """Raise :class:`OutputError` if an input lies inside ``folder`` (replaced as a whole)."""
    inp = input_inside(inputs, folder)
    if inp is not None:
        raise OutputError(
            f"{folder}: error: {what} folder holds the input file {inp}; it would be "
            "replaced with the folder: choose another folder (even --force does not)"
        )


def refuse_foreign_folder(folder: str | Path, marker: str, what: str) -> None:
    """Refuse to write a report into a folder that holds other files and no earlier report.

    A run or calibration report writes fixed names (``index.html``, ``summary.json``,
    figures) into ``folder``; over files of the user's own (``-o .``) they would be
    overwritten. A new or empty folder, or one holding an earlier report of the same
    kind (its ``marker`` file), is fine. Called before any run starts.

    Raises
    ------
    OutputError
        ``DIR: error: --report holds other files and no earlier report ...``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> refuse_foreign_folder(d / "new", "summary.json", "--report")   # new: fine
    >>> _ = (d / "notes.txt").write_text("mine")
    >>> try:
    ...     refuse_foreign_folder(d, "summary.json", "--report")
    ... except OutputError as err:
    ...     print(str(err).split(": ", 1)[1].split(";")[0])
    error: --report holds other files and no earlier report (summary.json)
    """
    p = Path(folder)
    try:
        busy = p.is_dir() and any(p.iterdir())
    except OSError:
        return  # unreadable: the write says why
    if busy and not (p / marker).is_file():
        raise OutputError(f"{p}: error: {what} holds other files and no earlier report "
                          f"({marker}); choose a new or empty folder")

