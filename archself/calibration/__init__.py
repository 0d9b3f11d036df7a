"""``archself calibrate``: residual bands from nominal runs for a stated false-alarm rate.

- :mod:`~archself.calibration.runs` — the nominal runs (fixed, every configuration,
  N seeds) on the campaign executors, the Monitor's filtered residuals recorded, and
  their ``--save-runs`` file;
- :mod:`~archself.calibration.bands` — per-run critical scales, Gumbel tails, bands;
- :mod:`~archself.calibration.driver` — :func:`calibrate`, the command without output;
- :mod:`~archself.calibration.prepare` — the checks before the runs (file, scenarios,
  configurations, ``--envelope``);
- :mod:`~archself.calibration.result` — :class:`Calibration`, what it found, and its JSON;
- :mod:`~archself.calibration.edit` — the calibrated copy of the file (text edited in
  place; also the identified weights of ``identify --write-back``);
- :mod:`~archself.calibration.report` — ``--report DIR`` (HTML, Markdown, figures);
- :mod:`~archself.calibration.identify` — ``archself identify``: the edge weights W
  from perturbation experiments (its runs, its write-back);
- :mod:`~archself.calibration.identify_results` — what it found, its JSON and its tables.

See docs/calibrate.md and docs/identify.md.
"""

from __future__ import annotations

from typing import Any

__all__ = ["Calibration", "CalibrationError", "calibrate"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from archself.calibration import driver

        return getattr(driver, name)
    raise AttributeError(name)
