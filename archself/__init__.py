"""archself: systems that carry their own architecture as data.

An architecture file (YAML) describes modules, weighted dependency edges,
admissible configurations and actions; archself validates it, compiles it into
runtime modules, simulates scenarios and runs a generic MAPE-K loop that
reconfigures the architecture itself (Franz & Yasin, Algorithm 1).

The public Python API (docs/python.md) is importable from here; the names are
resolved lazily (PEP 562), so ``import archself`` loads none of numpy, scipy,
python-control, filterpy, matplotlib or pandas until a name that needs them is used.

==========================  ===================================================
name                        what it is
==========================  ===================================================
:func:`load`                an architecture file → :class:`Architecture` (checked)
:func:`validate`            every finding of a file (schema and semantic rules)
:func:`simulate`            run a scenario, fixed or adaptive → :class:`RunResult`
:class:`MapeK`              the adaptation loop of Algorithm 1 (``adapt=MapeK(arch)``)
:func:`explain`             a decision log as text: why it switched
:func:`read_trace`          a saved trace (Parquet or JSON) → :class:`RunResult`
:func:`plan_campaign`       the jobs of a Monte Carlo campaign (``parse_sweep`` for sweeps)
:func:`run_campaign`        run them into a Parquet results file
:func:`read_results`        that file → (``pyarrow.Table``, metadata)
:func:`calibrate`           residual bands from nominal runs for a false-alarm rate
==========================  ===================================================

Examples
--------
>>> import archself
>>> sorted(archself.__all__)[:4]
['Architecture', 'ArchselfError', 'Finding', 'LoadError']
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

# name -> module that defines it (imported on first use)
_LAZY = {
    "Architecture": "archself.model.architecture",
    "ArchselfError": "archself.errors",
    "LoadError": "archself.errors",
    "Finding": "archself.findings",
    "simulate": "archself.sim.run",
    "RunResult": "archself.sim.run",
    "read_trace": "archself.sim.result",
    "MapeK": "archself.runtime.mapek",
    "explain": "archself.runtime.explanation",
    "parse_sweep": "archself.campaign.sweep",
    "plan_campaign": "archself.campaign.driver",
    "run_campaign": "archself.campaign.driver",
    "read_results": "archself.campaign.results",
    "calibrate": "archself.calibration.driver",
}

__all__ = [
    "Architecture",
    "ArchselfError",
    "Finding",
    "LoadError",
    "MapeK",
    "RunResult",
    "calibrate",
    "explain",
    "load",
    "parse_sweep",
    "plan_campaign",
    "read_results",
    "read_trace",
    "run_campaign",
    "simulate",
    "validate",
]

if TYPE_CHECKING:  # pragma: no cover
    from pathlib import Path

    from archself.calibration.driver import calibrate
    from archself.campaign.driver import plan_campaign, run_campaign
    from archself.campaign.results import read_results
    from archself.campaign.sweep import parse_sweep
    from archself.errors import ArchselfError, LoadError
    from archself.findings import Finding
    from archself.model.architecture import Architecture
    from archself.runtime.explanation import explain
    from archself.runtime.mapek import MapeK
    from archself.sim.result import read_trace
    from archself.sim.run import RunResult, simulate


def load(path: str | Path, *, check: bool = True) -> Architecture:
    """Load an architecture file: the :class:`~archself.Architecture` it describes.

    The file is read (YAML 1.2), checked against the schema and, unless
    ``check=False``, against the semantic rules of ``archself validate``.

    Parameters
    ----------
    path : str or Path
        The architecture file.
    check : bool
        Refuse a file with semantic errors (warnings are accepted).

    Returns
    -------
    Architecture
        The model; change it in place (``arch.scenarios["nominal"].duration_s = 60``)
        before :func:`simulate`.

    Raises
    ------
    LoadError
        The file cannot be read or parsed, or has errors; ``str(err)`` is the first
        one located ``file:line:col``, and a ``findings`` attribute, when present,
        lists all of them.
    """
    from archself.model.loader import SchemaError, load_architecture

    loaded = load_architecture(path)
    if check:
        from archself.check import check as check_rules

        errors = [f for f in check_rules(loaded) if f.severity == "error"]
        if errors:
            raise SchemaError(errors)
    return loaded.arch


def validate(path: str | Path) -> list[Finding]:
    """Every finding of ``archself validate`` for one file, as data.

    A file that cannot be read or does not match the schema gives its findings
    too (code ``load`` or ``schema``); nothing is raised for a bad file.

    Parameters
    ----------
    path : str or Path
        The architecture file.

    Returns
    -------
    list of Finding
        Sorted by position; ``[f for f in findings if f.severity == "error"]`` are
        the errors (``validate`` exits 1 on them).
    """
    from archself.check import check as check_rules
    from archself.errors import ArchselfError
    from archself.findings import Finding
    from archself.model.loader import SchemaError, load_architecture

    try:
        return check_rules(load_architecture(path))
    except SchemaError as exc:
        return list(exc.findings)
    except ArchselfError as exc:
        return [Finding("error", "load", getattr(exc, "message", str(exc)),
                        getattr(exc, "path", ""), str(path), getattr(exc, "line", None),
                        getattr(exc, "col", None))]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'archself' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public API (tab completion shows it, not the module's own imports)."""
    return sorted([*__all__, "__version__"])
