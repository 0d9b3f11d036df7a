"""Atomic file output: write a temporary file beside the target, then rename.

An interrupted or failed write never leaves a half-written file over a good one,
and never replaces a file registered with :func:`protect` (the inputs of the
running command): ``--force`` allows replacing an old output, never an input.
"""

from __future__ import annotations

import os
import secrets
import stat
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from archself.errors import OutputError

#: ``(st_dev, st_ino)`` of the files no write may replace (see :func:`protect`).
_PROTECTED: dict[tuple[int, int], str] = {}


@contextmanager
def protect(paths: Iterable[str | Path]) -> Iterator[None]:
    """While in the block, no :func:`write_bytes` replaces one of ``paths`` (same inode).

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
    for p in paths:
        for fid in file_ids(p):
            if fid not in _PROTECTED:
                _PROTECTED[fid] = str(p)
                added.append(fid)
    try:
        yield
    finally:
        for fid in added:
            _PROTECTED.pop(fid, None)


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
