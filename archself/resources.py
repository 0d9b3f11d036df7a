"""What archself takes from where it runs: its shipped data and its processes' BLAS threads.

The data (schemas, templates, example architectures) live in ``archself/_data/`` in
a wheel; in a source checkout (editable install) they are the top-level folders of
the repository. :func:`single_thread_blas` is called by the ``archself`` command
and by the campaign's local pool before numpy loads.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

_PKG = Path(__file__).resolve().parent


def data_dir(name: str) -> Path:
    """Path of the shipped folder ``name`` (``schemas``, ``templates``, ``architectures``)."""
    inside = _PKG / "_data" / name
    if inside.is_dir():
        return inside
    return _PKG.parent / name


def schema_path() -> Path:
    """Path of ``architecture.schema.json``."""
    return data_dir("schemas") / "architecture.schema.json"


#: Environment variables that set the thread count of the BLAS/OpenMP libraries.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_thread_blas(environ: MutableMapping[str, str] | None = None) -> None:
    """One BLAS thread for the processes started from now on (unless the user chose a number).

    A run multiplies 3×3 to 5×5 matrices, where a second BLAS thread gains nothing,
    but OpenBLAS's idle threads spin: one 400 s run took 0.84 s of wall time and
    1.08 s of CPU, and two runs side by side slowed each other by 16 %. With one
    thread per process, two workers run at the speed of one each (measured:
    0.841 s/run alone, 0.843 and 0.846 s/run side by side). The variables are read
    when a BLAS library loads, so this runs before a worker imports numpy: the
    local pool's forkserver inherits them (a Dask nanny sets the same by default,
    ``distributed.nanny.pre-spawn-environ``).

    Parameters
    ----------
    environ : mutable mapping, optional
        Where to set them (default ``os.environ``).
    """
    env = os.environ if environ is None else environ
    for name in BLAS_THREAD_VARIABLES:
        if not env.get(name):  # unset or empty
            env[name] = "1"
