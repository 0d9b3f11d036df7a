"""``archself identify``: edge weights W estimated from perturbation experiments.

(a) the fitting maths (:mod:`archself.calibration.identify_fit`) on synthetic Δr;
(b) end to end on a small architecture of a test-only module type whose residuals
    propagate exactly as the model says;
(c) the command line.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from archself.calibration.identify_fit import (
    fit_edges,
    fit_target,
    propagate,
    usable_targets,
)

# --------------------------------------------------------------------------- (a) maths

#: A graph with a diamond, a cycle (d → b) and a hidden module h (no residual).
NAMES = ["a", "b", "c", "d"]
TRUE = {("a", "b"): 0.5, ("a", "c"): 0.3, ("b", "c"): 0.2, ("b", "d"): 0.4, ("c", "d"): 0.6,
        ("d", "b"): 0.1}
EDGES = [*TRUE, ("h", "d"), ("a", "h")]


def _w() -> np.ndarray:
    W = np.zeros((4, 4))
    for (s, t), w in TRUE.items():
        W[NAMES.index(s), NAMES.index(t)] = w
    return W


def test_noiseless_recovers_w_exactly() -> None:
    dr = propagate(_w(), np.eye(4) * 0.7)  # one experiment per observed module
    est, fits = fit_edges(dr, NAMES, NAMES, EDGES)
    got = {(e.source, e.target): e.weight for e in est if e.identifiable}
    assert set(got) == set(TRUE)
    assert_allclose([got[k] for k in TRUE], list(TRUE.values()), rtol=0, atol=1e-12)
    assert all(f.r2 == pytest.approx(1.0) for f in fits.values())
    hidden = [e for e in est if "h" in (e.source, e.target)]
    assert [e.reason for e in hidden] == ["source has no residual", "target has no residual"]


def test_noisy_recovery_within_tolerance() -> None:
    # 5 seeds per experiment, Δr with noise of 2 % of the excitation: |ŵ − w| ≤ 0.03
    rng = np.random.default_rng(7)
    e = np.repeat(np.eye(4), 5, axis=0)
    dr = propagate(_w(), e) + 0.02 * rng.standard_normal((20, 4))
    exps = [NAMES[k] for k in np.repeat(np.arange(4), 5)]
    est, fits = fit_edges(dr, exps, NAMES, EDGES)
    got = {(e.source, e.target): e for e in est if e.identifiable}
    assert_allclose([got[k].weight for k in TRUE], list(TRUE.values()), atol=0.03)
    # the standard errors are of the size of the error made (within a factor 3)
    err = np.array([abs(got[k].weight - w) for k, w in TRUE.items()])
    se = np.array([got[k].se for k in TRUE])
    assert np.all(se > 0) and np.all(err < 3 * se + 1e-3)
    assert min(f.r2 for f in fits.values()) > 0.95


def test_nonnegative_and_unexcited_sources() -> None:
    X = np.array([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    fit = fit_target(X, np.array([-0.1, -0.2, -0.3]))
    assert fit.identifiable.tolist() == [True, False]
    assert fit.weights[0] == 0.0 and math.isnan(fit.weights[1])
    ols = fit_target(X, np.array([-0.1, -0.2, -0.3]), nonnegative=False)
    assert_allclose(ols.weights[0], -0.1)
    # collinear sources: the second is not identifiable
    col = fit_target(np.array([[1.0, 2.0], [2.0, 4.0]]), np.array([1.0, 2.0]))
    assert col.identifiable.tolist() == [True, False]


def test_hidden_paths_exclude_equations() -> None:
    edges = [("w", "chassis"), ("chassis", "enc"), ("enc", "odo"), ("enc", "w"),
             ("odo", "lqr"), ("lqr", "w"), ("imu", "odo")]
    obs = ["w", "odo", "lqr"]
    # a wheel perturbation reaches odometry past every observed residual
    assert usable_targets("w", obs, edges) == {"lqr"}
    assert usable_targets("imu", obs, edges) == {"w", "lqr"}
    assert usable_targets("enc", obs, edges) == {"lqr"}
    assert usable_targets("lqr", obs, edges) == {"w", "odo"}
