"""Campaign throughput: 1 worker against all workers (400 s adaptive diffdrive runs).

Each benchmark is one campaign, process start-up included; ``extra_info`` also has
the steady rate (from the first finished run of every worker to the last run),
which is what a long campaign sees.
"""

from __future__ import annotations

import time

import pytest

from archself.campaign.executors import default_workers

from conftest import DIFFDRIVE

RUNS = 64  # seeds of imu_drift, adaptive


@pytest.mark.parametrize("workers", sorted({1, default_workers()}))
def test_campaign_throughput(benchmark, workers: int, tmp_path) -> None:
    from archself.campaign.driver import plan_campaign, run_campaign

    jobs, meta = plan_campaign(DIFFDRIVE, ["imu_drift"], RUNS, modes=("adaptive",))
    outcomes = []
    stamps: list[float] = []

    def run():
        out = tmp_path / f"w{workers}-{len(outcomes)}.parquet"
        stamps.clear()
        t0 = time.perf_counter()
        outcomes.append(
            run_campaign(
                jobs,
                meta,
                out,
                workers=workers,
                progress=lambda done, total: stamps.append(time.perf_counter() - t0),
            )
        )

    benchmark.pedantic(run, rounds=1, iterations=1)
    o = outcomes[-1]
    assert o.ran == RUNS and o.failed == 0
    # stamps[0] is the progress call before any run; stamps[k] the k-th finished run
    first, last = stamps[workers], stamps[-1]
    steady = (RUNS - workers) / (last - first)
    benchmark.extra_info.update(
        workers=workers,
        runs_per_s=RUNS / benchmark.stats.stats.mean,
        steady_runs_per_s=steady,
        first_result_s=stamps[1],
    )
    print(
        f"\n{workers} worker(s): {RUNS} runs in {benchmark.stats.stats.mean:.1f} s "
        f"({RUNS / benchmark.stats.stats.mean:.2f} runs/s), first result after "
        f"{stamps[1]:.2f} s, steady {steady:.2f} runs/s"
    )
