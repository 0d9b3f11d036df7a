"""What ``archself calibrate`` found: the bands, the false-alarm rates per cell, its JSON.

:class:`Calibration` is :func:`archself.calibration.driver.calibrate`'s result (the
report and the terminal summary read it); :class:`ModuleBand` is one module's band
old and new, :class:`CellResult` one (scenario, configuration) cell's rates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from pydantic import Field

from archself.calibration.bands import Cell, Prediction
from archself.errors import ArchselfError
from archself.io.html import card, table
from archself.io.jsondata import JobDoc, OutDoc, document

__all__ = ["Calibration", "CalibrationDoc", "CalibrationError", "CellResult", "ModuleBand"]


class CalibrationError(ArchselfError):
    """The calibration cannot be done as asked (one-line message, exit 1)."""


@dataclass
class ModuleBand:
    """The band of one module: old, shape, new, and why it was (not) changed."""

    name: str
    old: float
    new: float
    base: float
    sensitivity: float
    signal: str
    configurations: list[str]
    calibrated: bool
    note: str = ""
    weight: float = 1.0  # its weight in the split of the false-alarm budget


@dataclass
class CellResult:
    """False alarms of one (scenario, configuration) cell, old and new bands."""

    scenario: str
    configuration: str
    runs: int
    failed: list[str]
    forced: int
    scale_needed: float
    old_predicted: float
    old_empirical: float
    new_predicted: float
    new_empirical: float
    fit_old: Prediction
    fit_new: Prediction
    verify_runs: int = 0
    verify_old: float = math.nan
    verify_new: float = math.nan


@dataclass
class Calibration:
    """What :func:`calibrate` found."""

    architecture: str
    file: str
    tau: float
    false_switch: float
    seeds: int
    root_seed: int
    scenarios: list[str]
    configurations: list[str]
    scale: float
    modules: dict[str, ModuleBand]
    cells: list[CellResult]
    data: list[Cell]
    text: str
    comment: str
    executor: str
    workers: int | None
    elapsed_s: float
    runs: int
    verify_seeds: int = 0
    verify_elapsed_s: float = 0.0

    def __repr__(self) -> str:
        """One line: the file, the rate asked for, the runs, the bands changed."""
        changed = sum(b.calibrated for b in self.modules.values())
        return (f"Calibration(architecture={self.architecture!r}, "
                f"false_switch={self.false_switch:g}, runs={self.runs}, "
                f"modules={len(self.modules)}, calibrated={changed})")

    def _repr_html_(self) -> str:
        """A short card for notebooks: the setting, the worst rates, the bands old → new."""

        rates = self.rates()
        rows = [(b.name, f"{b.old:.4g}", f"{b.new:.4g}", "yes" if b.calibrated else b.note)
                for b in self.modules.values()]
        return card(f"{self.architecture}: calibration for {self.false_switch:g} false "
                    f"switches per run", [
                        ("runs", f"{self.runs} ({self.seeds} seeds × "
                                 f"{len(self.scenarios)} scenarios × "
                                 f"{len(self.configurations)} configurations)"),
                        ("worst cell, predicted", f"{rates['predicted_old']:.3g} → "
                                                  f"{rates['predicted_new']:.3g}"),
                        ("worst cell, measured", f"{rates['empirical_old']:.3g} → "
                                                 f"{rates['empirical_new']:.3g}"),
                    ], table(["module", "band before", "band after", "calibrated"], rows))

    @property
    def bands(self) -> dict[str, float]:
        """module -> new band (as written to the file)."""
        return {m: b.new for m, b in self.modules.items()}

    def rates(self) -> dict[str, float]:
        """The worst cell's rates (a run of any cell is a run the loop may be in)."""

        def worst(attr: str) -> float:
            vals = [getattr(c, attr) for c in self.cells]
            vals = [v for v in vals if v == v]
            return max(vals) if vals else math.nan

        return {
            "predicted_new": worst("new_predicted"),
            "empirical_new": worst("new_empirical"),
            "predicted_old": worst("old_predicted"),
            "empirical_old": worst("old_empirical"),
            "verify_new": worst("verify_new"),
            "verify_old": worst("verify_old"),
        }

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON data (``--json``; ``calibration.json`` of the report): a
        :class:`CalibrationDoc` (NaN: null)."""
        return document(
            CalibrationDoc, self, complete=True, rates=self.rates(),
            bands={m: {f: getattr(b, f) for f in BandDoc.model_fields}
                   for m, b in self.modules.items()},
            cells=[{**{f: getattr(c, f) for f in _SAME_CELL}, "failed": len(c.failed),
                    "gumbel": {"loc": c.fit_new.all.loc, "scale": c.fit_new.all.scale},
                    "tail": {"u": c.fit_new.all.tail_u, "beta": c.fit_new.all.tail_beta,
                             "share": c.fit_new.all.tail_share},
                    **{f"{k}_{age}": getattr(c, f"{age}_{k}") for age in ("new", "old")
                       for k in ("predicted", "empirical")}} for c in self.cells],
            elapsed_s=round(self.elapsed_s, 3), verify_elapsed_s=round(self.verify_elapsed_s, 3))


# ------------------------------------------------------------------ the JSON document
Number = int | float  # as given: an int stays an int in the JSON
Rate = float | None  # a rate or a fit's value; null when it could not be had


class BandDoc(OutDoc):
    """One module's band, old and new ``residual.nominal``."""

    old: Number | None
    new: Number | None
    calibrated: bool
    signal: str
    configurations: list[str]
    note: str = Field(description="why the band was not calibrated ('' when it was)")
    weight: Number = Field(description="its share of the false-alarm budget (--weight)")


class GumbelDoc(OutDoc):
    """The Gumbel fit of the cell's largest residual per run (new bands)."""

    loc: Rate
    scale: Rate


class TailDoc(OutDoc):
    """The generalized-Pareto tail above ``u`` (``beta``, its ``share`` of the runs)."""

    u: Rate
    beta: Rate
    share: Rate


class RatesDoc(OutDoc):
    """False-switch rates: the worst cell's, predicted and counted, new and old bands."""

    predicted_new: Rate
    empirical_new: Rate
    predicted_old: Rate
    empirical_old: Rate
    verify_new: Rate = Field(description="on --verify-seeds fresh seeds; null without")
    verify_old: Rate


class CellDoc(OutDoc):
    """False switches of one (scenario, configuration) cell."""

    scenario: str
    configuration: str
    runs: int
    failed: int
    forced: int
    gumbel: GumbelDoc
    tail: TailDoc
    predicted_new: Rate
    empirical_new: Rate
    predicted_old: Rate
    empirical_old: Rate
    verify_runs: int
    verify_new: Rate
    verify_old: Rate


class CalibrationDoc(JobDoc):
    """``archself calibrate --json`` and the report's ``calibration.json``."""

    tau: Number
    false_switch: Number
    scenarios: list[str]
    configurations: list[str]
    runs: int
    scale: Rate
    bands: dict[str, BandDoc]
    rates: RatesDoc
    cells: list[CellDoc]
    verify_seeds: int
    verify_elapsed_s: float


#: The fields a :class:`CellResult` and its document share as they are.
_SAME_CELL = ("scenario", "configuration", "runs", "forced", "verify_runs", "verify_new",
              "verify_old")
