"""Simulation steps per second, fixed and adaptive (MAPE-K overhead), 400 s diffdrive scenarios."""

from __future__ import annotations

import pytest

SCENARIOS = ["nominal", "imu_drift", "actuator_fault"]


@pytest.mark.parametrize("mode", ["fixed", "adaptive"])
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_simulate_400s(benchmark, diffdrive, scenario: str, mode: str) -> None:
    from archself.runtime import MapeK
    from archself.sim.run import simulate

    simulate(diffdrive, scenario)  # warm: python-control, filterpy imported once

    def run():
        adapt = MapeK(diffdrive) if mode == "adaptive" else None
        return simulate(diffdrive, scenario, adapt=adapt)

    res = benchmark.pedantic(run, rounds=3, iterations=1)
    steps = len(res.series["t"])
    benchmark.extra_info["steps"] = steps
    benchmark.extra_info["steps_per_s"] = steps / benchmark.stats.stats.mean
