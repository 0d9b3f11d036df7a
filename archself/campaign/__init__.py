"""Campaigns: many runs of an architecture, on all cores or a Dask cluster, summarized.

============================  ==============================================
file                          role
============================  ==============================================
``sweep.py``                  PATH parsing, sweep values, applying them to the data
``executors.py``              the ``Executor`` interface: local process pool (forkserver,
                              dies with the driver), Dask, inline (debugging, tests)
``worker.py``                 one job → one results row (architecture cached per process)
``results.py``                the Parquet results table and its schema
``plan.py``                   validate, size and list the jobs (seeds, run ids)
``driver.py``                 run, save incrementally, resume, Ctrl-C
``report.py``                 ``campaign-report``: rates, distributions, τ sweep (HTML)
============================  ==============================================

Names are imported lazily, so ``import archself.campaign`` costs nothing.

Examples
--------
>>> from archself.campaign import plan_campaign, run_campaign       # doctest: +SKIP
>>> jobs, meta = plan_campaign("diffdrive.yaml", ["imu_drift"], 10)  # doctest: +SKIP
>>> run_campaign(jobs, meta, "results.parquet")                      # doctest: +SKIP
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY = {
    "CampaignError": "sweep",
    "Sweep": "sweep",
    "parse_path": "sweep",
    "parse_sweep": "sweep",
    "apply_values": "sweep",
    "Executor": "executors",
    "LocalExecutor": "executors",
    "DaskExecutor": "executors",
    "make_executor": "executors",
    "Job": "worker",
    "run_job": "worker",
    "read_results": "results",
    "write_results": "results",
    "CampaignInterrupted": "driver",
    "CampaignOutcome": "driver",
    "plan_campaign": "plan",
    "run_campaign": "driver",
    "run_seeds": "plan",
    "campaign_report": "report",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'archself.campaign' has no attribute {name!r}")
    return getattr(importlib.import_module(f"archself.campaign.{mod}"), name)


def __dir__() -> list[str]:
    return sorted(list(globals()) + list(_LAZY))
