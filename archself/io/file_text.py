"""Reading an input file: regular files only, a size cap, UTF-8, one-line errors.

:func:`read_text` refuses a FIFO, a socket or a device before it is opened for
reading (a FIFO without a writer would block forever) and again on the open
descriptor; every failure is a located :class:`~archself.errors.LoadError`.
"""

from __future__ import annotations

from pathlib import Path

from archself.errors import LoadError

__all__ = ["MAX_FILE_BYTES", "decode_text", "read_text"]

#: Any document (JSON text, which the json module parses at tens of MB/s).
MAX_FILE_BYTES = 64 * 1024 * 1024


def read_text(path: str | Path, max_bytes: int = MAX_FILE_BYTES) -> str:
    """Read a regular file as UTF-8 with a size cap; errors become :class:`LoadError`.

    A FIFO, a socket or a device is refused before it is opened for reading (a
    FIFO without a writer would block forever, ``/dev/zero`` never ends); the
    file is opened non-blocking and checked again on the open descriptor, so a
    path swapped for a FIFO in between is refused too.
    """
    import os
    import stat

    from archself.io.outputs import stat_input

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
    from archself.io.outputs import file_kind

    return file_kind(mode) or "not a regular file"
