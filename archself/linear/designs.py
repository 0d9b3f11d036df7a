"""Controller designs computed once: in the process, and across processes on disk.

:func:`lqr` is ``control.lqr`` (python-control designs every gain) behind two caches,
both keyed by the exact design inputs — the bytes, shapes and dtypes of ``A``, ``B``,
``Q``, ``R`` and python-control's version:

* an in-process memo: a campaign worker's runs and a batch's lanes share a gain;
* a persistent cache, one small JSON file per design with the gain's entries as
  ``float.hex`` (bit-exact), in ``$ARCHSELF_CACHE_DIR``, else
  ``$XDG_CACHE_HOME/archself``, else ``~/.cache/archself`` (folder ``designs``). A hit
  needs neither python-control nor scipy: a plain ``archself simulate`` of a file whose
  gains were designed before does not import them (≈ 0.7 s of a process).
  ``ARCHSELF_CACHE=off`` switches it off. Entries are written atomically
  (:mod:`archself.io.files`); one that cannot be read, is corrupt or was written for
  other inputs is ignored and the gain designed again (and the entry rewritten); a
  cache folder that cannot be written is no error (the gain is designed per process).

A hit and a miss give the same gain to the bit (tests/test_modules.py).
"""

from __future__ import annotations

import hashlib
import json
import os
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from archself.errors import ArchselfError
from archself.io.files import write_text

__all__ = ["cache_dir", "lqr"]

_MEMO: dict[str, np.ndarray] = {}


def cache_dir() -> Path | None:
    """The folder of the persistent design cache, or None when ``ARCHSELF_CACHE=off``."""
    if os.environ.get("ARCHSELF_CACHE", "").strip().lower() in ("off", "0", "no", "false"):
        return None
    root = os.environ.get("ARCHSELF_CACHE_DIR")
    if not root:
        xdg = os.environ.get("XDG_CACHE_HOME")
        try:
            root = str(Path(xdg) / "archself") if xdg else str(Path.home() / ".cache" / "archself")
        except RuntimeError:  # no home folder to be found: no cache
            return None
    return Path(root) / "designs"


@cache
def _control_version() -> str:
    """python-control's version from its metadata (without importing it)."""
    from importlib.metadata import PackageNotFoundError, version  # not at start-up

    try:
        return version("control")
    except PackageNotFoundError:  # pragma: no cover - a declared dependency
        return "none"


def _key(kind: str, *arrays: np.ndarray) -> str:
    h = hashlib.sha256(f"{kind} control {_control_version()}".encode())
    for a in arrays:
        h.update(f"|{a.dtype.str}{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _read(path: Path, key: str) -> np.ndarray | None:
    """The gain stored for ``key`` at ``path``; None if absent, unreadable or foreign."""
    try:
        entry = json.loads(path.read_text(encoding="utf-8"))
        if entry.get("key") != key:
            return None
        shape = tuple(int(n) for n in entry["shape"])
        values = [float.fromhex(v) for v in entry["gain"]]
        return np.array(values, dtype=float).reshape(shape)
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return None


def _write(path: Path, key: str, K: np.ndarray) -> None:
    """Store ``K`` atomically; a folder that cannot be made or written is left alone."""
    entry = {"key": key, "design": "control.lqr", "control": _control_version(),
             "shape": list(K.shape), "gain": [float(v).hex() for v in K.ravel()]}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, json.dumps(entry) + "\n")
    except (OSError, ArchselfError):
        pass


def lqr(A: Any, B: Any, Q: Any, R: Any) -> np.ndarray:
    """The LQR gain ``K`` of ``control.lqr(A, B, Q, R)``, designed once (module doc).

    Returns
    -------
    numpy.ndarray
        ``K`` (inputs × states), read-only: shared by every caller.

    Examples
    --------
    >>> K = lqr([[0.0]], [[1.0]], [[4.0]], [[1.0]])   # ẋ = u, J = ∫ 4x² + u²
    >>> K.tolist()
    [[2.0]]
    """
    mats = [np.ascontiguousarray(m, dtype=float) for m in (A, B, Q, R)]
    key = _key("lqr", *mats)
    K = _MEMO.get(key)
    if K is not None:
        return K
    folder = cache_dir()
    path = None if folder is None else folder / f"{key}.json"
    K = None if path is None else _read(path, key)
    if K is None or K.shape != (mats[1].shape[1], mats[0].shape[0]):
        import control

        K = np.array(control.lqr(*mats)[0], dtype=float)
        if path is not None:
            _write(path, key, K)
    K.setflags(write=False)
    _MEMO[key] = K
    return K
