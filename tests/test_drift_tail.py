"""The drift tail of the robustness matrix: a hand-over that overstates the drift.

Seed 1780620601 of the matrix's 1× drift from 2 s (docs/robustness.md) is switched early,
34.5 s after the onset, when the GPS noise happens to lie along the drift's template:
the heading error and rate handed over to the EKF are several times the true ones. With
the paper's soft LQR in a2 (9 m of lateral offset per radian of heading error in the
estimate) that run peaked at 1.06 m half a minute after the switch; a2's ``lqr_fused``
(q_lateral 0.1, 1.9 m per radian) keeps it near the switch's error.
"""

from __future__ import annotations

import pytest

from archself.campaign.sweep import apply_values, parse_sweep
from archself.model.loader import load_architecture
from archself.resources import data_dir
from archself.runtime import MapeK
from archself.sim.run import simulate

SEED = 1780620601


def _run(extra: tuple[str, ...] = ()):
    data = load_architecture(data_dir("architectures") / "diffdrive.yaml").data
    sweeps = [parse_sweep(s) for s in (
        "scenarios.imu_drift.faults[0].onset_s=2",
        "scenarios.imu_drift.faults[0].magnitude=0.0007",
        *extra,
    )]
    arch = apply_values(data, sweeps, [s.values[0] for s in sweeps])
    return simulate(arch, "imu_drift", seed=SEED, adapt=MapeK(arch))


@pytest.mark.slow
def test_early_drift_alarm_stays_near_the_switch_error() -> None:
    res = _run()
    switch = res.switches[0]
    assert switch["to"] == "a2" and len(res.switches) == 1
    t, err = res.series["t"], res.series["J"]
    peak = float(t[err.argmax()])
    assert float(err.max()) < 0.75
    assert peak - switch["t_s"] < 10.0  # the worst is at the switch, not after the hand-over


@pytest.mark.slow
def test_the_soft_lateral_loop_on_the_fused_estimate_is_what_made_the_tail() -> None:
    soft = _run(("modules.lqr_fused.params.q_lateral.value=0.001",))
    stiff = _run()
    assert [s["t_s"] for s in soft.switches] == [s["t_s"] for s in stiff.switches]
    t = soft.series["t"]
    assert float(soft.series["J"].max()) > 1.0
    assert float(t[soft.series["J"].argmax()]) - soft.switches[0]["t_s"] > 20.0
