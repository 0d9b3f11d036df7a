"""The hand-written floor (bench/floor_diffdrive.py, issue 16) is the framework's a1 run.

The floor writes the diff-drive a1 fixed run out as one loop and draws the modules'
random streams as the framework does, so its J equals the framework's to 1e-9 (in
fact bit for bit on this machine), per run and vectorized over seeds. No time is
asserted (``python bench/floor_diffdrive.py`` measures).
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
from archself.system.live import module_rng

ROOT = Path(__file__).resolve().parents[1]
SEEDS = (1, 2)
METRICS = ("max_error", "final_error", "rms_error", "peak_time_s")


@cache
def floor() -> ModuleType:
    """Import ``bench/floor_diffdrive.py`` (bench/ is not a package)."""
    path = ROOT / "bench" / "floor_diffdrive.py"
    spec = importlib.util.spec_from_file_location("bench_floor_diffdrive", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@cache
def framework(seed: int) -> archself.RunResult:
    arch = archself.load(ROOT / "architectures" / "diffdrive.yaml")
    return archself.simulate(arch, "nominal", configuration="a1", seed=seed)


def test_streams_are_the_frameworks() -> None:
    for name in ("chassis", "encoders", "imu"):
        assert_allclose(
            floor().stream(7, name).standard_normal(5),
            module_rng(7, name).standard_normal(5),
            rtol=0,
            atol=0,
        )


@pytest.mark.parametrize("seed", SEEDS)
def test_run_floor_is_the_framework_run(seed: int) -> None:
    fw = framework(seed)
    out = floor().run_floor(seed)
    assert_allclose(out["t"], fw.series["t"], rtol=0, atol=1e-12)
    assert_allclose(out["J"], fw.series["J"], rtol=0, atol=1e-9)
    for key in METRICS:
        assert out[key] == pytest.approx(fw.metrics[key], rel=0, abs=1e-9), key
    assert out["mean_error"] == pytest.approx(float(np.mean(fw.series["J"])), abs=1e-9)
    assert 0.0 < out["max_error"] < 0.5  # the nominal run tracks the path


def test_vectorized_floor_is_the_framework_run() -> None:
    out = floor().run_floor_lanes(list(SEEDS), record=True, block=300)  # blocks cut mid-run
    assert out["J"].shape == (len(framework(1).series["J"]), len(SEEDS))
    for lane, seed in enumerate(SEEDS):
        fw = framework(seed)
        assert_allclose(out["J"][:, lane], fw.series["J"], rtol=0, atol=1e-9)
        for key in METRICS:
            assert out[key][lane] == pytest.approx(fw.metrics[key], rel=0, abs=1e-9), key
        assert out["mean_error"][lane] == pytest.approx(float(np.mean(fw.series["J"])), abs=1e-9)


@pytest.mark.parametrize("seed", SEEDS)
def test_same_work_floor_records_the_frameworks_series(seed: int) -> None:
    """The same-work floor (GPS, every residual signal, the covariance, the recording)
    gives J and every recorded series of the run, to 1e-9 (bit for bit here)."""
    fw = framework(seed)
    out = floor().run_floor_same_work(seed)
    keys = ["J", "reference", "actual", "estimate", "command",
            *(f"residual.{m}" for m in floor().RESIDUALS)]
    for key in keys:
        assert_allclose(out[key], fw.series[key], rtol=0, atol=1e-9, err_msg=key)
    # the residuals are signals, not constants: the drift test has values, the wheels react
    assert np.isfinite(out["residual.odometry"]).sum() > 1000
    assert np.ptp(out["residual.wheel_left"][np.isfinite(out["residual.wheel_left"])]) > 0.01
    assert out["covariance"][0, 0] > 0.01  # grown from its start


def test_vectorized_same_work_floor_is_the_frameworks_lanes() -> None:
    """The vectorized same-work floor records what the framework's lanes record, to 1e-9."""
    from archself.lanes import simulate_lanes

    arch = archself.load(ROOT / "architectures" / "diffdrive.yaml")
    runs = simulate_lanes(arch, "nominal", list(SEEDS), configuration="a1")
    out = floor().run_floor_lanes_same_work(list(SEEDS), block=300)  # blocks cut mid-run
    for lane, run in enumerate(runs):
        for key in ("J", "reference", "actual", "estimate", "command"):
            assert_allclose(out[key][:, lane], run.series[key], rtol=0, atol=1e-9, err_msg=key)
        for j, name in enumerate(floor().RESIDUALS):
            assert_allclose(out["residual"][:, lane, j], run.series[f"residual.{name}"],
                            rtol=0, atol=1e-9, err_msg=name)
        assert out["max_error"][lane] == pytest.approx(run.metrics["max_error"], abs=1e-9)


def _same_series(out: dict, runs: list) -> None:
    """Every lane's recorded series of the switching floor against the framework's lanes."""
    for lane, run in enumerate(runs):
        for key in ("J", "reference", "actual", "estimate", "command"):
            assert_allclose(out[key][:, lane], run.series[key], rtol=0, atol=1e-9, err_msg=key)
        for j, name in enumerate(floor().SWITCHING_RESIDUALS):
            assert_allclose(out["residual"][:, lane, j], run.series[f"residual.{name}"],
                            rtol=0, atol=1e-9, err_msg=name)
        assert out["max_error"][lane] == pytest.approx(run.metrics["max_error"], abs=1e-9)


def test_fixed_a2_floor_is_the_frameworks_lanes() -> None:
    """The a2 floor (EKF with the GPS through the edge's latency, lqr_fused) records what
    the framework's lanes record, to 1e-9 (bit for bit here)."""
    from archself.lanes import simulate_lanes

    arch = archself.load(ROOT / "architectures" / "diffdrive.yaml")
    runs = simulate_lanes(arch, "nominal", list(SEEDS), configuration="a2")
    out = floor().run_floor_lanes_switching(list(SEEDS), start="a2", block=300)
    _same_series(out, runs)
    ekf = out["residual"][:, :, floor().SWITCHING_RESIDUALS.index("ekf")]
    assert np.isfinite(ekf).sum() > 1000 and np.isnan(out["residual"][:, :, 2]).all()


def test_adaptive_floor_replays_the_frameworks_switches() -> None:
    """Adaptive imu_drift: the floor, given the framework's switch steps, hands over as the
    framework does (the drift estimate into the EKF) and records the same series."""
    from archself.lanes import simulate_lanes

    arch = archself.load(ROOT / "architectures" / "diffdrive.yaml")
    seeds = [1, 2, 3]
    runs = simulate_lanes(arch, "imu_drift", seeds, adapt=True)
    S = floor().load_setup(scenario="imu_drift")
    steps = [int(round(r.switches[0]["t_s"] / S.dt)) - 1 for r in runs]
    assert len(set(steps)) > 1  # the lanes switch at different steps: mixed groups run
    out = floor().run_floor_lanes_switching(seeds, S, switches=steps, block=300)
    _same_series(out, runs)
    assert out["band_crossings"] > 0  # the Monitor's bands by hand saw the drift
