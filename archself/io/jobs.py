"""The job records: what ``campaign``, ``calibrate`` and ``identify`` print with ``--json``.

A job runs many simulations of one file; its record starts with the fields the three
share (:class:`JobDoc`): the file, the seeds, the executor, the time, the archself that
wrote it. :class:`CampaignDoc` is ``campaign --json``; ``calibrate`` and ``identify``
extend :class:`JobDoc` in :mod:`archself.calibration.result` and
:mod:`archself.calibration.identify_results`. These are output documents: a key the
model does not name is refused (``extra="forbid"``), as docs/json.md's schemas say.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from archself import __version__

__all__ = ["CampaignDoc", "JobDoc", "OutDoc"]


class OutDoc(BaseModel):
    """An output document: the keys its fields name, no other."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)


class JobDoc(OutDoc):
    """The leading fields of every job record (campaign, calibrate, identify)."""

    architecture: str = Field(description="the file's name: key")
    file: str
    seeds: int = Field(description="seeds per scenario (and configuration)")
    root_seed: int
    executor: str
    elapsed_s: float
    archself_version: str = Field(default_factory=lambda: __version__)


class CampaignDoc(JobDoc):
    """``archself campaign --json``: what the run did (with ``--resume``, ``skipped`` runs
    were already in ``out``); ``errors``, the first failed runs' messages."""

    out: str
    planned: int
    skipped: int
    ran: int
    failed: int
    rows: int
    workers: int
    errors: list[str]
