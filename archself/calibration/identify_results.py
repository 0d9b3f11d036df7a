"""What ``archself identify`` found: per edge declared vs fitted W, the experiments, the error.

:class:`Identification` is the result of :func:`archself.calibration.identify.identify`
(rows :class:`EdgeRow`, :class:`Experiment`, the fits per target) with its JSON form
and the weights pooled over configurations; :class:`IdentifyError` is the one-line
refusal of the command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from archself.calibration.identify_fit import TargetFit
from archself.errors import ArchselfError
from archself.io.jsondata import finite_or_none

__all__ = ["FLAG_SE", "EdgeRow", "Experiment", "Identification", "IdentifyError"]

#: Flag a fitted weight as different from the declared one beyond this many SE.
FLAG_SE = 2.0


class IdentifyError(ArchselfError):
    """The identification cannot be done as asked (one-line message, exit 1)."""


@dataclass
class EdgeRow:
    """One edge pair (source → target) of one configuration: declared vs fitted."""

    configuration: str
    source: str
    target: str
    carries: list[str]
    declared: float
    effective: float
    fitted: float
    se: float
    identifiable: bool
    reason: str

    @property
    def differs(self) -> bool | None:
        """|fitted − effective| > 2 SE (None when not identifiable or without an SE)."""
        if not self.identifiable or not math.isfinite(self.se):
            return None
        return abs(self.fitted - self.effective) > max(FLAG_SE * self.se, 1e-9)


@dataclass
class Experiment:
    """One perturbed module of one configuration and what it excited."""

    configuration: str
    module: str
    kind: str
    magnitude: float
    seeds: int
    own_delta: float  # mean Δr of the module itself (NaN when hidden)
    max_delta: float  # largest mean |Δr| over the observed modules


@dataclass
class Identification:
    """What :func:`identify` found."""

    architecture: str
    file: str
    scenario: str
    configurations: list[str]
    seeds: int
    root_seed: int
    w_scale: float
    settle_s: float
    rows: list[EdgeRow]
    fits: dict[str, dict[str, TargetFit]]
    experiments: list[Experiment]
    skipped: dict[str, list[str]]  # configuration -> active modules not perturbed (why)
    failed: list[str]
    runs: int
    elapsed_s: float
    executor: str
    text: str = ""

    def fitted_weights(self) -> dict[tuple[str, str], tuple[float, float]]:
        """(source, target) -> (weight, SE) pooled over configurations.

        Inverse-variance weighted where every estimate has an SE > 0, the mean
        otherwise.
        """
        by: dict[tuple[str, str], list[EdgeRow]] = {}
        for r in self.rows:
            if r.identifiable:
                by.setdefault((r.source, r.target), []).append(r)
        out: dict[tuple[str, str], tuple[float, float]] = {}
        for key, rows in by.items():
            se = np.array([r.se for r in rows])
            w = np.array([r.fitted for r in rows])
            if np.all(np.isfinite(se)) and np.all(se > 0):
                iv = 1.0 / se**2
                out[key] = (float(iv @ w / iv.sum()), float(1.0 / math.sqrt(iv.sum())))
            else:
                out[key] = (float(w.mean()), float(se[0]) if len(rows) == 1 else math.nan)
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON data (``--json``)."""

        num = finite_or_none
        return {
            "architecture": self.architecture,
            "file": self.file,
            "scenario": self.scenario,
            "configurations": self.configurations,
            "seeds": self.seeds,
            "root_seed": self.root_seed,
            "runs": self.runs,
            "failed": self.failed,
            "w_scale": self.w_scale,
            "settle_s": self.settle_s,
            "edges": [
                {
                    "configuration": r.configuration,
                    "source": r.source,
                    "target": r.target,
                    "carries": r.carries,
                    "declared": r.declared,
                    "effective": r.effective,
                    "fitted": num(r.fitted),
                    "se": num(r.se),
                    "identifiable": r.identifiable,
                    "reason": r.reason,
                    "differs": r.differs,
                }
                for r in self.rows
            ],
            "targets": {
                c: {
                    t: {"rows": f.rows, "r2": num(f.r2), "rms": num(f.rms), "moved": num(f.moved)}
                    for t, f in fits.items()
                }
                for c, fits in self.fits.items()
            },
            "experiments": [
                {
                    "configuration": e.configuration,
                    "module": e.module,
                    "kind": e.kind,
                    "magnitude": e.magnitude,
                    "seeds": e.seeds,
                    "own_delta": num(e.own_delta),
                    "max_delta": num(e.max_delta),
                }
                for e in self.experiments
            ],
            "not_perturbed": self.skipped,
            "executor": self.executor,
            "elapsed_s": round(self.elapsed_s, 3),
        }
