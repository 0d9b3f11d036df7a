"""Pure kinematics: conversions, exact integration, error coordinates, linearization."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.integrate import solve_ivp

from archself_diffdrive.kinematics import (
    body_to_wheels,
    error_dynamics,
    integrate_pose,
    tracking_error,
    unicycle_rhs,
    wheels_to_body,
    wrap_angle,
)

R, B = 0.1, 0.5
P = {"dt": 0.05, "wheel_radius_m": R, "wheel_base_m": B}


def test_wheels_body_roundtrip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        v, w = rng.normal(0, 1), rng.normal(0, 1)
        wl_wr = body_to_wheels(v, w, R, B)
        v2, w2 = wheels_to_body(wl_wr, R, B)
        assert_allclose([v2, w2], [v, w], atol=1e-12)


def test_wheels_to_body_vectorized():
    ws = np.array([[4.0, 5.0], [6.0, 5.0]])  # (2, n)
    v, w = wheels_to_body(ws, R, B)
    assert_allclose(v, [0.5, 0.5])
    assert_allclose(w, [0.4, 0.0])


def test_integrate_straight_and_limits():
    p = integrate_pose(0.0, [0, 0, 0], [5.0, 5.0], {**P, "dt": 2.0})
    assert_allclose(p, [1.0, 0.0, 0.0], atol=1e-12)
    lim = integrate_pose(
        0.0, [0, 0, 0], [50.0, 50.0], {**P, "dt": 1.0, "max_wheel_speed_rad_s": 10}
    )
    assert_allclose(lim, [1.0, 0.0, 0.0], atol=1e-12)


def test_integrate_full_circle_returns_home():
    # ω = r (wr - wl) / b; one full turn in T = 2π/ω
    wl, wr = 4.0, 6.0
    w = R * (wr - wl) / B
    n = 400
    dt = 2 * math.pi / w / n
    pose = np.zeros(3)
    for _ in range(n):
        pose = integrate_pose(0.0, pose, [wl, wr], {**P, "dt": dt})
    assert_allclose(pose[:2], [0.0, 0.0], atol=1e-9)
    assert pose[2] == pytest.approx(2 * math.pi)


def test_integrate_matches_ode_solution():
    wl, wr = 3.0, 7.0
    v, w = wheels_to_body([wl, wr], R, B)
    sol = solve_ivp(
        lambda t, x: unicycle_rhs(t, x, [v, w]), (0, 3.0), [1.0, 2.0, 0.3], rtol=1e-10, atol=1e-12
    )
    exact = integrate_pose(0.0, [1.0, 2.0, 0.3], [wl, wr], {**P, "dt": 3.0})
    assert_allclose(exact, sol.y[:, -1], atol=1e-7)


def test_effectiveness_scales_wheels():
    full = integrate_pose(0.0, [0, 0, 0], [4.0, 4.0], {**P, "dt": 1.0, "effectiveness": [0.5, 1.0]})
    same = integrate_pose(0.0, [0, 0, 0], [2.0, 4.0], {**P, "dt": 1.0})
    assert_allclose(full, same)
    assert full[2] > 0  # the weak left wheel turns the robot left


def test_tracking_error_frames():
    # robot 1 m ahead of a reference heading north
    e = tracking_error([0.0, 1.0, math.pi / 2], [0.0, 0.0, math.pi / 2])
    assert_allclose(e, [1.0, 0.0, 0.0], atol=1e-12)
    # 1 m to the left of a reference heading east, heading error wrapped
    e = tracking_error([0.0, 1.0, 2 * math.pi + 0.1], [0.0, 0.0, 0.0])
    assert_allclose(e, [0.0, 1.0, 0.1], atol=1e-12)


def test_tracking_error_rotation_invariant():
    rng = np.random.default_rng(1)
    for _ in range(20):
        pose, ref = rng.normal(size=3), rng.normal(size=3)
        a = rng.uniform(-np.pi, np.pi)
        assert_allclose(
            tracking_error(_rotate(pose, a), _rotate(ref, a)), tracking_error(pose, ref), atol=1e-12
        )


def _rotate(p, a):
    c, s = math.cos(a), math.sin(a)
    return np.array([c * p[0] - s * p[1], s * p[0] + c * p[1], p[2] + a])


def _error_rhs(e, du, v, w):
    """Nonlinear error dynamics for a reference moving at (v, w)."""
    ex, ey, et = e
    return np.array(
        [w * ey + (v + du[0]) * math.cos(et) - v, -w * ex + (v + du[0]) * math.sin(et), du[1]]
    )


@pytest.mark.parametrize("v,w", [(0.5, 0.0), (0.8, 0.1)])
def test_error_dynamics_is_the_jacobian(v, w):
    A, B_ = error_dynamics(v, w)
    h = 1e-6
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        col = (_error_rhs(d, [0, 0], v, w) - _error_rhs(-d, [0, 0], v, w)) / (2 * h)
        assert_allclose(A[:, i], col, atol=1e-8)
    for j in range(2):
        d = np.zeros(2)
        d[j] = h
        col = (_error_rhs(np.zeros(3), d, v, w) - _error_rhs(np.zeros(3), -d, v, w)) / (2 * h)
        assert_allclose(B_[:, j], col, atol=1e-8)


def test_wrap_angle():
    assert_allclose(
        wrap_angle(np.array([0.0, 2 * np.pi + 0.5, -np.pi - 0.5])), [0.0, 0.5, np.pi - 0.5]
    )
