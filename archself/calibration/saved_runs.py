"""Saved calibration runs: the ``--save-runs``/``--from-runs`` file and its digest.

:func:`save_runs` writes the recorded residuals of every run with the metadata that
ties them to the file (an ``.npz``, no pickles); :func:`load_runs` reads them back;
:func:`band_free_digest` is the file's identity without its bands, which
``--from-runs`` checks.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["band_free_digest", "load_runs", "save_runs"]


def band_free_digest(data: dict[str, Any]) -> str:
    """SHA-256 of the architecture's data without its bands (``modules.*.residual.nominal``).

    The nominal runs are fixed, so their residuals do not depend on the bands: runs
    saved from a file stay valid for the same file with other bands (e.g. its
    calibrated copy), and for nothing else.
    """
    import copy
    import json

    d = copy.deepcopy(data)
    for spec in (d.get("modules") or {}).values():
        if isinstance(spec, dict) and isinstance(spec.get("residual"), dict):
            spec["residual"].pop("nominal", None)
    text = json.dumps(d, sort_keys=True, default=str, ensure_ascii=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def save_runs(path: str | Path, meta: dict[str, Any], results: Sequence[dict[str, Any]]) -> None:
    """Write runs (``run_calibration_job`` results) and ``meta`` to an ``.npz`` file, atomically.

    Arrays ``x<k>``/``forced<k>``/``t<k>`` per run, ``meta`` as a JSON string, a
    :class:`~archself.io.jsondata.SavedRunsMeta` (no pickles: the file is safe to load).
    """
    import io
    import json

    import numpy as np

    from archself.io.files import write_bytes
    from archself.io.jsondata import SavedRunsMeta, document

    arrays: dict[str, Any] = {}
    rows = []
    for k, r in enumerate(results):
        rows.append(
            {
                key: r[key]
                for key in ("scenario", "configuration", "replicate", "seed", "error", "phase")
            }
        )
        if r["error"] is None:
            arrays.update({f"{name}{k}": r[name] for name in ("x", "forced", "t")})
    doc = document(SavedRunsMeta, {**meta, "runs": rows})
    arrays["meta"] = np.array(json.dumps(doc, ensure_ascii=False))
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    write_bytes(path, buf.getvalue())


def load_runs(path: str | Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """``(meta, results)`` of a file written by :func:`save_runs`.

    Raises
    ------
    LoadError
        When the file is missing or not such a file.
    """
    import zipfile

    import numpy as np

    from archself.errors import LoadError
    from archself.io.jsondata import JsonLimitError, SavedRunsMeta, loads, problem

    try:
        with np.load(path, allow_pickle=False) as z:
            meta = loads(str(z["meta"]))  # JsonLimitError: a ValueError
            why = problem(SavedRunsMeta, meta, "meta")
            if why:
                raise LoadError(f"not a runs file of archself calibrate ({why})", str(path))
            results = []
            for k, row in enumerate(meta.pop("runs")):
                r = dict(row)
                if r["error"] is None:
                    r["x"], r["forced"], r["t"] = z[f"x{k}"], z[f"forced{k}"], z[f"t{k}"]
                    x, forced, t = r["x"], r["forced"], r["t"]
                    if (x.ndim != 2 or x.dtype.kind not in "fiu" or forced.ndim != 1
                            or t.ndim != 1 or not len(x) == len(forced) == len(t)):
                        raise LoadError(f"not a runs file of archself calibrate (the arrays "
                                        f"of run {k} have the wrong shape or type)", str(path))
                results.append(r)
    except FileNotFoundError:
        raise LoadError("no such file", str(path)) from None
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
        why = str(exc) if isinstance(exc, JsonLimitError) else type(exc).__name__
        raise LoadError(f"not a runs file of archself calibrate ({why})", str(path)) from None
    return meta, results
