"""The files of one command: inputs read safely, outputs written atomically, never over an input.

Reading an input file: regular files only, a size cap, UTF-8, one-line errors.
:func:`read_text` refuses a FIFO, a socket or a device before it is opened for
reading (a FIFO without a writer would block forever) and again on the open
descriptor; every failure is a located :class:`~archself.errors.LoadError`.

Inputs are files, outputs never land on an input. Every command that reads a file and
writes another checks, before it starts, that no output is an input (the same file: same
``st_dev`` and ``st_ino``, whatever the path, a hard link or a symbolic link), that no
input lies inside an output folder that is replaced as a whole, and that every input is
a regular file (``/dev/zero`` is refused, not read until memory runs out; a FIFO is
refused, not opened: without a writer the open would block forever). The inputs are also
registered with :func:`archself.io.files.protect`, so that a write the up-front check
could not foresee is refused at the moment it would happen. ``--force`` never lifts
these checks: it allows replacing an old *output*.

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

Atomic file output (:func:`write_bytes`): write a temporary file beside the target,
then rename. An interrupted or failed write never leaves a half-written file over a good one,
and never replaces a file registered with :func:`protect` (the inputs of the
running command): ``--force`` allows replacing an old output, never an input.

The outputs given to :func:`protect` are locked for the whole command: an
exclusive ``flock`` on a sidecar ``<output>.lock`` (for a folder, ``<folder>.lock``
beside it) that holds ``pid N: archself ...`` and is removed at the end. A second
command writing the same output is refused with one line naming the holder; a
holder killed outright (SIGKILL) leaves the file, but not the lock, behind.
"""

from __future__ import annotations

import errno
import os
import secrets
import stat
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from archself.errors import LoadError, OutputError

__all__ = [
    "MAX_FILE_BYTES", "check_input", "decode_text", "file_ids", "file_kind", "input_inside",
    "read_text", "refuse_foreign_folder", "refuse_input_inside", "refuse_same_file",
    "stat_input"
]


#: Any document (JSON text, which the json module parses at tens of MB/s).
MAX_FILE_BYTES = 64 * 1024 * 1024


def read_text(path: str | Path, max_bytes: int = MAX_FILE_BYTES) -> str:
    """Read a regular file as UTF-8 with a size cap; errors become :class:`LoadError`.

    A FIFO, a socket or a device is refused before it is opened for reading (a
    FIFO without a writer would block forever, ``/dev/zero`` never ends); the
    file is opened non-blocking and checked again on the open descriptor, so a
    path swapped for a FIFO in between is refused too.
    """
    file = str(path)
    st = stat_input(path)
    if stat.S_ISDIR(st.st_mode):
        raise LoadError("is a directory, expected an architecture file", file)
    if not stat.S_ISREG(st.st_mode):
        raise LoadError(f"is {_file_kind(st.st_mode)}, expected a regular file", file)
    if st.st_size > max_bytes:
        raise LoadError(f"file is {st.st_size} bytes, larger than the {max_bytes}-byte cap", file)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    except OSError as exc:
        raise LoadError(f"cannot read: {exc.strerror}", file) from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise LoadError(f"is {_file_kind(mode)}, expected a regular file", file)
        with os.fdopen(fd, "rb", closefd=False) as fh:
            raw = fh.read(max_bytes + 1)  # the file may have grown since stat()
    except OSError as exc:
        raise LoadError(f"cannot read: {exc.strerror}", file) from None
    finally:
        os.close(fd)
    return decode_text(raw, file, max_bytes)


def decode_text(raw: bytes, file: str, max_bytes: int = MAX_FILE_BYTES) -> str:
    """``raw`` (read up to ``max_bytes + 1``) as UTF-8 text; over the cap or not UTF-8 is a
    :class:`LoadError` located at ``file`` (the line of the first bad byte)."""
    if len(raw) > max_bytes:
        raise LoadError(f"input is larger than the {max_bytes}-byte cap", file)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise LoadError("not UTF-8 text", file, line, 1) from None


def _file_kind(mode: int) -> str:
    return file_kind(mode) or "not a regular file"


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


#: ``(st_dev, st_ino)`` of the files no write may replace (see :func:`protect`).
_PROTECTED: dict[tuple[int, int], str] = {}
#: Why a lock file cannot be made where no output can be written either.
_UNWRITABLE = {errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOENT, errno.ENOTDIR}
#: The output locks this process holds: lock file → descriptor (see :func:`lock_output`).
_LOCKS: dict[Path, int] = {}


@contextmanager
def protect(paths: Iterable[str | Path],
            outputs: Iterable[str | Path | None] = ()) -> Iterator[None]:
    """While in the block, no :func:`write_bytes` replaces one of ``paths`` (same inode),
    and no other process writes one of ``outputs`` (each one locked, :func:`lock_output`).

    ``outputs`` are the files and folders the command writes (None and ``-``, stdout,
    are skipped).

    Raises
    ------
    OutputError
        An output is locked by another command (the message names its pid and
        command line), or its lock cannot be made.

    Examples
    --------
    >>> import tempfile
    >>> f = Path(tempfile.mkdtemp()) / "in.yaml"
    >>> write_text(f, "a: 1")
    >>> with protect([f]):
    ...     try:
    ...         write_text(f, "trace")
    ...     except OutputError as err:
    ...         print("refused")
    refused
    >>> f.read_text()
    'a: 1'
    """
    added = []
    locks: list[tuple[Path, int]] = []
    try:
        for out in outputs:
            held = lock_output(out)
            if held is not None:
                locks.append(held)
        for p in paths:
            for fid in file_ids(p):
                if fid not in _PROTECTED:
                    _PROTECTED[fid] = str(p)
                    added.append(fid)
        yield
    finally:
        for fid in added:
            _PROTECTED.pop(fid, None)
        for lock, fd in reversed(locks):
            unlock_output(lock, fd)


def _holder_line() -> str:
    """``pid N: archself ARGS`` (at most 200 characters) for a lock file."""
    import shlex

    args = " ".join(shlex.quote(a) for a in sys.argv[1:])
    text = f"pid {os.getpid()}: archself {args}".strip()
    return text if len(text) <= 200 else text[:199] + "…"


def lock_path(target: str | Path) -> Path | None:
    """The lock file of the output ``target``: ``<real path>.lock`` beside it.

    None for stdout (``-``), a character device or a FIFO (``/dev/null``), or a
    target whose folder does not exist (nothing can be written there; the write
    says so).

    Examples
    --------
    >>> lock_path("-") is None, lock_path("/dev/null") is None
    (True, True)
    >>> lock_path("/tmp/r.parquet")
    PosixPath('/tmp/r.parquet.lock')
    """
    if str(target) == "-":
        return None
    try:
        mode = os.stat(target).st_mode
    except OSError:
        mode = None
    if mode is not None and not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        return None
    real = Path(os.path.realpath(target))  # a link and its file share one lock
    if not real.name or not real.parent.is_dir():
        return None
    return real.with_name(real.name + ".lock")


def lock_output(target: str | Path | None) -> tuple[Path, int] | None:
    """Lock the output ``target`` for this process: ``(lock file, descriptor)``, or None.

    None when ``target`` needs no lock (:func:`lock_path`), this process holds its
    lock already, or the lock file cannot be made because nothing can be written
    there (a read-only or missing folder: the command's write says so, located).
    Release with :func:`unlock_output`.

    Raises
    ------
    OutputError
        ``TARGET: error: is being written by pid N: archself ...`` when another
        process holds the lock; ``cannot lock`` when the lock file cannot be made.
    """
    import fcntl

    lock = None if target is None else lock_path(target)
    if lock is None or lock in _LOCKS:
        return None
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        except OSError as exc:
            if exc.errno in _UNWRITABLE:
                return None
            raise OutputError(f"{target}: cannot lock: {exc.strerror or exc} ({lock})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            try:
                holder = os.read(fd, 512).decode("utf-8", "replace").strip() or "another process"
            except OSError:
                holder = "another process"
            os.close(fd)
            raise OutputError(f"{target}: error: is being written by {holder.splitlines()[0]}; "
                              f"wait for it to end or choose another output ({lock})") from None
        try:  # the previous holder may have removed the file between our open and flock
            same = os.path.samestat(os.fstat(fd), os.stat(lock))
        except OSError:
            same = False
        if not same:
            os.close(fd)
            continue
        try:
            os.ftruncate(fd, 0)
            os.write(fd, (_holder_line() + "\n").encode("utf-8"))
        except OSError:
            pass  # the lock holds; only the holder's name is missing
        _LOCKS[lock] = fd
        return lock, fd


def unlock_output(lock: Path, fd: int) -> None:
    """Remove the lock file and release the lock (:func:`lock_output`)."""
    _LOCKS.pop(lock, None)
    try:
        os.unlink(lock)
    except OSError:
        pass
    os.close(fd)


def refuse_protected(path: str | Path) -> None:
    """Raise :class:`OutputError` if ``path`` is a file registered with :func:`protect`."""
    if not _PROTECTED:
        return
    for fid in file_ids(path):
        if fid in _PROTECTED:
            raise OutputError(
                f"{path}: error: is the input file {Path(_PROTECTED[fid]).name}; "
                "refusing to write over it (even with --force)"
            )


def write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (same-directory temp file + ``os.replace``).

    Raises
    ------
    OutputError
        If the folder does not exist or cannot be written, or ``path`` is protected.

    A symbolic link is followed (the file it points to is replaced, the link kept);
    a character device or a pipe (``/dev/stdout``) is written to directly, never
    replaced by a file; a folder or another special file is refused.
    """
    p = Path(path)
    refuse_protected(p)
    try:
        mode: int | None = os.stat(p).st_mode  # follows a symbolic link
    except OSError:
        mode = None
    if mode is not None and stat.S_ISREG(mode) and p.is_symlink():
        p = Path(os.path.realpath(p))  # replace the file it points to; the link stays a link
    if mode is not None and not stat.S_ISREG(mode):
        if stat.S_ISDIR(mode):
            raise OutputError(f"{path}: cannot write: is a folder")
        if stat.S_ISCHR(mode) or stat.S_ISFIFO(mode):  # /dev/stdout, /dev/null, a pipe
            try:
                with open(p, "wb") as fh:
                    fh.write(data)
            except OSError as exc:
                raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
            return
        raise OutputError(f"{path}: cannot write: not a regular file")
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(f"{p}: cannot write: folder {folder} does not exist")
    # named first and made inside the clean-up block: a signal between making it and
    # entering the block would leave it behind
    tmp = folder / f".{p.name}.{secrets.token_hex(8)}.tmp"
    try:
        # O_EXCL: never an existing file; mode 0666 less the umask, like any new file
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, p)
    except BaseException as exc:
        if not isinstance(exc, FileExistsError):  # that one is someone else's file
            try:
                os.unlink(tmp)
            except OSError:
                pass
        if isinstance(exc, OSError):
            raise OutputError(f"{p}: cannot write: {exc.strerror or exc}") from None
        raise


def write_text(path: str | Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    write_bytes(path, text.encode("utf-8"))
