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

    res = benchmark.pedantic(run, rounds=7, iterations=1)
    steps = len(res.series["t"])
    benchmark.extra_info["steps"] = steps
    benchmark.extra_info["steps_per_s"] = steps / benchmark.stats.stats.mean


class _Replay:
    """A fixed run that follows a recorded configuration schedule, with no MAPE-K work.

    Called like the loop (every ``runtime.period_s``), it applies each recorded switch
    at its time, so the adaptive run and this replay execute the same modules for the
    same time and their difference is the cost of the loop itself.
    """

    def __init__(self, switches: list[dict]) -> None:
        self.todo = [(float(s["t_s"]), s["to"]) for s in switches]

    def __call__(self, system) -> list:
        if self.todo and system.t >= self.todo[0][0] - 1e-9:
            system.apply_configuration(self.todo.pop(0)[1])
        return []


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_replay_of_the_adaptive_schedule(benchmark, diffdrive, scenario: str) -> None:
    """The adaptive run's configurations without the loop: the MAPE-K overhead's baseline."""
    from archself.runtime import MapeK
    from archself.sim.run import simulate

    adaptive = simulate(diffdrive, scenario, adapt=MapeK(diffdrive))
    res = benchmark.pedantic(
        lambda: simulate(diffdrive, scenario, adapt=_Replay(adaptive.switches)),
        rounds=7,
        iterations=1,
    )
    assert res.final_configuration == adaptive.final_configuration
    assert res.metrics["max_error_m"] == adaptive.metrics["max_error_m"]  # the same run
    benchmark.extra_info["switches"] = len(adaptive.switches)
