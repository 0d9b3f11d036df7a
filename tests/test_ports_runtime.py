"""Named ports at run time: a renamed port delivers the source's value (the executor)."""

from __future__ import annotations

from archself.check import check
from archself.model.loader import load_text

from conftest import ROOT

MOTOR = (ROOT / "architectures" / "motor_drive.yaml").read_text()
VIA_GAIN = ("  - {from: voltage_input.u, to: kf_tacho.u, weight: 0.3}\n"
            "  - {from: voltage_input.u, to: kf_encoder.u, weight: 0.3}\n")
PORTED = ("  - {from: volt_meter.measurement, to: kf_tacho.u, weight: 0.3}\n"
          "  - {from: volt_meter.measurement, to: kf_encoder.u, weight: 0.3}\n")


def test_a_renamed_port_runs_like_the_unit_gain_it_replaces() -> None:
    """volt_meter.measurement straight into the filters' u: no gain block to rename it."""
    import numpy as np

    from archself.sim.run import simulate
    from archself.system.live import compile_system

    assert VIA_GAIN in MOTOR
    before = load_text(MOTOR, "motor.yaml")
    after = load_text(MOTOR.replace(VIA_GAIN, PORTED), "motor.yaml")
    assert not [f for f in check(after) if f.severity == "error"]
    e = after.arch.edges[10]
    assert (e.source, e.carries, e.target, after.arch.edge_ports.into(10)) == (
        "volt_meter", "measurement", "kf_tacho", "u")
    # the filters receive the meter's value under 'u' (a unit gain passed it on exactly)
    for conf, scenario in (("m1", "tacho_drift"), ("m2", "drive_loss")):
        j0 = simulate(before.arch, scenario, seed=2, configuration=conf).series["J"]
        j1 = simulate(after.arch, scenario, seed=2, configuration=conf).series["J"]
        assert np.allclose(j0, j1, rtol=0, atol=1e-12, equal_nan=True)
        # and the closed loop wires the port: the same eigenvalues as through the gain
        eig = [np.sort_complex(np.linalg.eigvals(
            compile_system(x.arch, conf, seed=2).linearization())) for x in (before, after)]
        assert np.allclose(eig[0], eig[1], atol=1e-9)
