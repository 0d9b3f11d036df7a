"""Campaign throughput: 1 worker against all workers (400 s adaptive diffdrive runs)."""

from __future__ import annotations

import pytest

from archself.campaign.executors import default_workers

from conftest import DIFFDRIVE

RUNS = 16  # seeds of imu_drift, adaptive


@pytest.mark.parametrize("workers", sorted({1, default_workers()}))
def test_campaign_throughput(benchmark, workers: int, tmp_path) -> None:
    from archself.campaign.driver import plan_campaign, run_campaign

    jobs, meta = plan_campaign(DIFFDRIVE, ["imu_drift"], RUNS, modes=("adaptive",))
    outcomes = []

    def run():
        out = tmp_path / f"w{workers}-{len(outcomes)}.parquet"
        outcomes.append(run_campaign(jobs, meta, out, workers=workers))

    benchmark.pedantic(run, rounds=1, iterations=1)
    o = outcomes[-1]
    assert o.ran == RUNS and o.failed == 0
    benchmark.extra_info["runs_per_s"] = RUNS / benchmark.stats.stats.mean
    benchmark.extra_info["workers"] = workers
