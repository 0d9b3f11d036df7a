"""Designs computed once: in the process, and across processes on disk.

A design is a pure function of numeric inputs whose result is a few named float
arrays: :func:`lqr` (``control.lqr``: python-control designs every gain), :func:`place`
(an observer's poles), :func:`zoh` (an LTI block's discretization at the run's step),
:func:`tf2ss` (a transfer function's realization) and, through :func:`cached`, any other
(the diff-drive pack's spline path, ``scipy.interpolate``).
Both caches are keyed by the exact design inputs — the design's name, the version of the
library that computes it, the bytes, shapes and dtypes of the input arrays:

* an in-process memo: a campaign worker's runs and a batch's lanes share a design;
* a persistent cache, one small JSON file per design with each array's bytes
  (little-endian float64, base64: bit-exact), in ``$ARCHSELF_CACHE_DIR``, else
  ``$XDG_CACHE_HOME/archself``, else ``~/.cache/archself`` (folder ``designs``). A hit
  imports neither the library nor scipy: a plain ``archself simulate`` of a file whose
  designs were computed before imports neither python-control (≈ 0.7 s of a process)
  nor scipy.interpolate (≈ 0.35 s). ``ARCHSELF_CACHE=off`` switches it off. Entries are
  written atomically (:mod:`archself.io.files`); one that cannot be read, is corrupt or
  was written for other inputs is ignored and the design computed again (and the entry
  rewritten); a cache folder that cannot be written is no error (the design is computed
  per process).

A hit and a miss give the same arrays to the bit (tests/test_modules.py).
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
from collections.abc import Callable, Sequence
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from archself.errors import ArchselfError
from archself.io.files import write_text

__all__ = ["cache_dir", "cached", "lqr", "place", "tf2ss", "zoh"]

Arrays = dict[str, np.ndarray]

_MEMO: dict[str, Arrays] = {}


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
def _version(distribution: str) -> str:
    """The installed version of ``distribution`` from its metadata (without importing it)."""
    from importlib.metadata import PackageNotFoundError, version  # not at start-up

    try:
        return version(distribution)
    except PackageNotFoundError:  # pragma: no cover - a declared dependency
        return "none"


def _key(design: str, library: str, arrays: Sequence[np.ndarray]) -> str:
    # "base64": the entry's format (an older archself's float.hex entries have other keys)
    h = hashlib.sha256(f"{design} {library} {_version(library)} base64".encode())
    for a in arrays:
        h.update(f"|{a.dtype.str}{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _read(path: Path, key: str) -> Arrays | None:
    """The arrays stored for ``key`` at ``path``; None if absent, unreadable or foreign."""
    try:
        entry = json.loads(path.read_text(encoding="utf-8"))
        if entry.get("key") != key:
            return None
        return {name: np.frombuffer(base64.b64decode(a["data"], validate=True), dtype="<f8")
                .astype(float).reshape(tuple(int(n) for n in a["shape"]))
                for name, a in entry["arrays"].items()}
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return None


def _write(path: Path, key: str, design: str, library: str, arrays: Arrays) -> None:
    """Store ``arrays`` atomically; a folder that cannot be made or written is left alone."""
    entry = {"key": key, "design": design, library: _version(library),
             "arrays": {name: {"shape": list(a.shape), "data": base64.b64encode(
                 np.ascontiguousarray(a, dtype="<f8").tobytes()).decode("ascii")}
                 for name, a in arrays.items()}}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, json.dumps(entry) + "\n")
    except (OSError, ArchselfError):
        pass


def cached(design: str, library: str, inputs: Sequence[Any], compute: Callable[[], Arrays],
           shapes: Callable[[Arrays], bool]) -> Arrays:
    """The arrays ``compute()`` makes of ``inputs``, computed once (module doc).

    Parameters
    ----------
    design : str
        Name of the design (part of the key; change it when ``compute`` changes).
    library : str
        Distribution that computes it (its installed version is part of the key).
    inputs : sequence of array_like
        Every numeric input of the design (converted to float arrays for the key).
    compute : callable
        ``compute()`` → ``{name: float array}``: called on a miss only, so it is where
        the library is imported.
    shapes : callable
        ``shapes(arrays)`` is True when a stored entry has the names and shapes of a
        design of these inputs (an entry that fails is computed again).

    Returns
    -------
    dict
        ``{name: numpy.ndarray}``, read-only: shared by every caller.
    """
    key = _key(design, library, [np.ascontiguousarray(m, dtype=float) for m in inputs])
    found = _MEMO.get(key)
    if found is not None:
        return found
    folder = cache_dir()
    path = None if folder is None else folder / f"{key}.json"
    found = None if path is None else _read(path, key)
    if found is None or not shapes(found):
        found = {name: np.array(a, dtype=float) for name, a in compute().items()}
        if path is not None:
            _write(path, key, design, library, found)
    for a in found.values():
        a.setflags(write=False)
    _MEMO[key] = found
    return found


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

    def design() -> Arrays:
        import control

        return {"gain": control.lqr(*mats)[0]}

    shape = (mats[1].shape[1], mats[0].shape[0])
    return cached("lqr", "control", mats, design,
                  lambda found: set(found) == {"gain"} and found["gain"].shape == shape)["gain"]


def place(A: Any, B: Any, poles: Sequence[float | complex]) -> np.ndarray:
    """The gain ``K`` of ``control.place(A, B, poles)`` (eig(A − B K) at ``poles``), placed once.

    ``poles`` are passed to python-control as given (floats and complex numbers).

    Examples
    --------
    >>> place([[0.0, 0.0], [1.0, 0.0]], [[1.0], [0.0]], [-2.0, -3.0]).round(6).tolist()
    [[5.0, 6.0]]
    """
    given = [np.asarray(m, dtype=float) for m in (A, B)]  # designed as given (their layout)
    mats = [np.ascontiguousarray(m) for m in given]
    wanted = list(poles)
    # each pole's real part, imaginary part and kind (1: given complex): the key's input
    spec = np.array([[complex(p).real, complex(p).imag, float(isinstance(p, complex))]
                     for p in wanted], dtype=float).reshape(-1, 3)

    def design() -> Arrays:
        import control

        return {"gain": control.place(*given, wanted)}

    shape = (mats[1].shape[1], mats[0].shape[0])
    return cached("place", "control", [*mats, spec], design,
                  lambda found: set(found) == {"gain"} and found["gain"].shape == shape)["gain"]


def zoh(A: Any, B: Any, C: Any, D: Any, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(Ad, Bd)`` of ``control.c2d(control.ss(A, B, C, D), dt, method="zoh")``, once.

    Examples
    --------
    >>> Ad, Bd = zoh([[0.0]], [[1.0]], [[1.0]], [[0.0]], 0.5)   # ẋ = u
    >>> Ad.tolist(), Bd.tolist()
    ([[1.0]], [[0.5]])
    """
    given = [np.asarray(m, dtype=float) for m in (A, B, C, D)]  # designed as given
    mats = [np.ascontiguousarray(m) for m in given]
    step = float(dt)

    def design() -> Arrays:
        import control

        sysd = control.c2d(control.ss(*given), step, method="zoh")
        return {"A": sysd.A, "B": sysd.B}

    n, m = mats[1].shape
    got = cached("zoh", "control", [*mats, np.array(step)], design,
                 lambda found: set(found) == {"A", "B"} and found["A"].shape == (n, n)
                 and found["B"].shape == (n, m))
    return got["A"], got["B"]


def tf2ss(num: Sequence[float], den: Sequence[float], dt: float) -> Arrays:
    """``A, B, C, D`` of ``control.ss(control.tf(num, den, dt))``, realized once.

    Examples
    --------
    >>> m = tf2ss([2.0], [1.0, 1.0], 0.0)
    >>> sorted(m), m["A"].shape
    (['A', 'B', 'C', 'D'], (1, 1))
    """
    coeffs = [list(np.ravel(np.asarray(c, dtype=float))) for c in (num, den)]
    step = float(dt)

    def design() -> Arrays:
        import control

        sys = control.ss(control.tf(coeffs[0], coeffs[1], step))
        return {"A": sys.A, "B": sys.B, "C": sys.C, "D": sys.D}

    def shapes(found: Arrays) -> bool:
        if set(found) != {"A", "B", "C", "D"} or any(a.ndim != 2 for a in found.values()):
            return False
        n = found["A"].shape[0]
        return (found["A"].shape == (n, n) and found["B"].shape == (n, 1)
                and found["C"].shape == (1, n) and found["D"].shape == (1, 1))

    return cached("tf2ss", "control", [np.array(c) for c in coeffs] + [np.array(step)],
                  design, shapes)
