"""The per-run adaptive floor (bench/floor_per_run.py, issue 38 item 2) is the framework's run.

The floor writes the adaptive imu_drift run out by hand, replaying the switch the
framework's MAPE-K loop takes (its time and target) and doing the monitoring work by
hand; its J and every recorded series equal the framework's to 1e-9 (bit for bit on
this machine). No time is asserted (``python bench/floor_per_run.py`` measures).
"""

from __future__ import annotations

import importlib.util
import sys
from functools import cache
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from numpy.testing import assert_allclose

import archself
from archself.runtime import MapeK

ROOT = Path(__file__).resolve().parents[1]


@cache
def floor() -> ModuleType:
    """Import ``bench/floor_per_run.py`` (bench/ is not a package)."""
    path = ROOT / "bench" / "floor_per_run.py"
    spec = importlib.util.spec_from_file_location("bench_floor_per_run", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("seed", [1, 2])
def test_adaptive_floor_records_the_frameworks_series(seed: int) -> None:
    """J, the poses, the estimate, the command, every residual column and the
    configuration of the adaptive imu_drift run, before and after the replayed switch."""
    arch = archself.load(ROOT / "architectures" / "diffdrive.yaml")
    fw = archself.simulate(arch, "imu_drift", seed=seed, adapt=MapeK(arch))
    switches = [(float(s["t_s"]), str(s["to"])) for s in fw.switches]
    assert [to for _, to in switches] == ["a2"]  # the run the floor replays
    out = floor().run_floor_adaptive(seed, switches)
    keys = ["J", "reference", "actual", "estimate", "command", "configuration",
            *(f"residual.{m}" for m in floor().load_adaptive().res_names)]
    for key in keys:
        assert_allclose(out[key], fw.series[key], rtol=0, atol=1e-9, err_msg=key)
    assert out["max_error"] == pytest.approx(fw.metrics["max_error"], abs=1e-9)
    # both estimators ran: the EKF's innovation after the switch, the drift test before
    at = int(round(switches[0][0] / 0.05))
    assert np.isfinite(out["residual.ekf"][at:]).sum() > 1000
    assert np.isfinite(out["residual.odometry"][:at]).sum() > 100


def test_adaptive_floor_refuses_a_decision_it_cannot_replay() -> None:
    with pytest.raises(ValueError, match="replays one switch to a2"):
        floor().run_floor_adaptive(1, [(60.0, "a3")])
