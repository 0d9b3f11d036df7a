"""Atomic file output: write a temporary file beside the target, then rename.

An interrupted or failed write never leaves a half-written file over a good one,
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

from archself.errors import OutputError

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
    from archself.io.outputs import file_ids

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
    from archself.io.outputs import file_ids

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
