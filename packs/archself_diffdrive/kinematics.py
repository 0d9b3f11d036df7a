"""Pure kinematics of a differential-drive (unicycle) robot.

Stateless functions only: the stateful runtime modules in :mod:`archself.modules`
call them. Poses are ``[x, y, θ]`` (m, m, rad), wheel speeds ``[left, right]``
(rad/s), body velocities ``(v, ω)`` (m/s, rad/s). Where a function is a system
right-hand side or an integrator it takes ``t, x, u, params`` in that order
(python-control's convention).

Examples
--------
>>> import numpy as np
>>> v, w = wheels_to_body(np.array([5.0, 5.0]), 0.1, 0.5)
>>> float(v), float(w)
(0.5, 0.0)
>>> pose = integrate_pose(0.0, np.zeros(3), np.array([5.0, 5.0]), {"dt": 1.0,
...     "wheel_radius_m": 0.1, "wheel_base_m": 0.5})
>>> np.allclose(pose, [0.5, 0.0, 0.0])
True
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = [
    "wrap_angle",
    "wheels_to_body",
    "body_to_wheels",
    "unicycle_rhs",
    "arc_step",
    "integrate_pose",
    "tracking_error",
    "error_dynamics",
]


def wrap_angle(a):
    """Wrap an angle (or array of angles) to ``[-π, π)``.

    Examples
    --------
    >>> round(float(wrap_angle(3 * np.pi / 2)), 6)
    -1.570796
    """
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def wheels_to_body(wheel_speeds, wheel_radius: float, wheel_base: float):
    """Body velocities of a differential drive from its wheel speeds.

    Parameters
    ----------
    wheel_speeds : array_like, shape (2,) or (2, n)
        Left and right wheel angular speeds (rad/s).
    wheel_radius, wheel_base : float
        Wheel radius r and distance b between the wheels (m).

    Returns
    -------
    v, omega : ndarray
        Forward speed ``r (ω_l + ω_r) / 2`` (m/s) and yaw rate ``r (ω_r − ω_l) / b`` (rad/s).

    Examples
    --------
    >>> v, w = wheels_to_body([4.0, 6.0], 0.1, 0.5)
    >>> round(float(v), 6), round(float(w), 6)
    (0.5, 0.4)
    """
    wl, wr = np.asarray(wheel_speeds, dtype=float)
    return wheel_radius * (wl + wr) / 2.0, wheel_radius * (wr - wl) / wheel_base


def body_to_wheels(v, omega, wheel_radius: float, wheel_base: float) -> np.ndarray:
    """Wheel speeds ``[ω_l, ω_r]`` (rad/s) realising ``(v, ω)``; inverse of :func:`wheels_to_body`.

    Examples
    --------
    >>> body_to_wheels(0.5, 0.4, 0.1, 0.5)
    array([4., 6.])
    """
    half = omega * wheel_base / 2.0
    return np.array([(v - half) / wheel_radius, (v + half) / wheel_radius], dtype=float)


def unicycle_rhs(t: float, x, u, params: dict[str, Any] | None = None) -> np.ndarray:
    """Right-hand side ``ẋ = f(t, x, u)`` of the unicycle ``[ẋ, ẏ, θ̇] = [v cos θ, v sin θ, ω]``.

    Parameters
    ----------
    t : float
        Time (unused; the system is time invariant).
    x : array_like, shape (3,)
        Pose ``[x, y, θ]``.
    u : array_like, shape (2,)
        ``[v, ω]``.
    params : dict, optional
        Unused.

    Examples
    --------
    >>> unicycle_rhs(0.0, [0.0, 0.0, 0.0], [1.0, 0.5])
    array([1. , 0. , 0.5])
    """
    v, w = float(u[0]), float(u[1])
    th = float(x[2])
    return np.array([v * math.cos(th), v * math.sin(th), w])


def integrate_pose(t: float, x, u, params: dict[str, Any]) -> np.ndarray:
    """Advance a pose over ``dt`` under constant wheel speeds (exact arc integration).

    Parameters
    ----------
    t : float
        Time (unused).
    x : array_like, shape (3,)
        Pose ``[x, y, θ]`` at the start of the step.
    u : array_like, shape (2,)
        Commanded wheel speeds ``[ω_l, ω_r]`` (rad/s).
    params : dict
        ``dt`` (s), ``wheel_radius_m``, ``wheel_base_m``; optional
        ``effectiveness`` ``[e_l, e_r]`` (each wheel turns at ``e·ω``, default 1)
        and ``max_wheel_speed_rad_s`` (symmetric saturation, default none).

    Returns
    -------
    ndarray, shape (3,)
        The pose at ``t + dt`` (θ not wrapped).

    Examples
    --------
    >>> p = {"dt": 1.0, "wheel_radius_m": 0.1, "wheel_base_m": 0.5,
    ...      "effectiveness": [0.5, 1.0]}
    >>> integrate_pose(0.0, [0.0, 0.0, 0.0], [4.0, 4.0], p).round(4)
    array([0.2921, 0.0592, 0.4   ])
    """
    dt = float(params["dt"])
    r = float(params["wheel_radius_m"])
    b = float(params["wheel_base_m"])
    wl, wr = float(u[0]), float(u[1])
    eff = params.get("effectiveness")
    if eff is not None:
        wl *= float(eff[0])
        wr *= float(eff[1])
    lim = params.get("max_wheel_speed_rad_s")
    if lim is not None:
        lim = float(lim)
        wl = min(max(wl, -lim), lim)
        wr = min(max(wr, -lim), lim)
    return np.array(arc_step(float(x[0]), float(x[1]), float(x[2]), r, b, wl, wr, dt))


def arc_step(px: float, py: float, th: float, r: float, b: float, wl: float, wr: float,
             dt: float) -> tuple[float, float, float]:
    """The pose after ``dt`` at wheel speeds ``wl``, ``wr`` (exact arc; the midpoint
    rule when the heading barely turns), on floats: :func:`integrate_pose`'s step, also
    the plant's.

    Examples
    --------
    >>> [round(v, 4) for v in arc_step(0.0, 0.0, 0.0, 0.1, 0.5, 2.0, 4.0, 1.0)]
    [0.2921, 0.0592, 0.4]
    """
    v = r * (wl + wr) / 2.0
    w = r * (wr - wl) / b
    dth = w * dt
    if abs(dth) < 1e-9:
        mid = th + 0.5 * dth
        px += v * dt * math.cos(mid)
        py += v * dt * math.sin(mid)
    else:
        rad = v / w
        px += rad * (math.sin(th + dth) - math.sin(th))
        py -= rad * (math.cos(th + dth) - math.cos(th))
    return px, py, th + dth


def tracking_error(pose, reference) -> np.ndarray:
    """Tracking error ``[e_along, e_lateral, e_heading]`` in the reference frame.

    ``e = R(θ_ref)ᵀ (p − p_ref)`` for the position (along the reference heading and
    to its left), and ``wrap(θ − θ_ref)`` for the heading.

    Parameters
    ----------
    pose : array_like, shape (3,)
        Actual (or estimated) pose.
    reference : array_like, shape (>=3,)
        Reference ``[x, y, θ, ...]``.

    Examples
    --------
    >>> tracking_error([1.0, 2.0, 0.1], [1.0, 0.0, np.pi / 2]).round(4)
    array([ 2.    ,  0.    , -1.4708])
    """
    return np.array(tracking_error_floats(pose, reference))


def tracking_error_floats(pose, reference) -> tuple[float, float, float]:
    """:func:`tracking_error` as a tuple of floats (for per-step controller code).

    Examples
    --------
    >>> tuple(round(e, 4) for e in tracking_error_floats([1.0, 2.0, 0.1], [1.0, 0.0, 0.0]))
    (0.0, 2.0, 0.1)
    """
    dx = float(pose[0]) - float(reference[0])
    dy = float(pose[1]) - float(reference[1])
    thr = float(reference[2])
    c, s = math.cos(thr), math.sin(thr)
    dth = (float(pose[2]) - thr + math.pi) % (2.0 * math.pi) - math.pi
    return c * dx + s * dy, -s * dx + c * dy, dth


def error_dynamics(v: float, omega: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Linearized tracking-error dynamics ``ė = A e + B δu`` at reference speed ``v``.

    With ``e = [e_along, e_lateral, e_heading]`` (see :func:`tracking_error`) and
    ``δu = [v − v_ref, ω − ω_ref]``::

        ė_along   =  ω e_lateral + δv
        ė_lateral = −ω e_along   + v e_heading
        ė_heading =  δω

    Parameters
    ----------
    v : float
        Reference forward speed (m/s).
    omega : float, optional
        Reference yaw rate (rad/s); 0 gives the straight-line model.

    Returns
    -------
    A : ndarray, shape (3, 3)
    B : ndarray, shape (3, 2)

    Examples
    --------
    >>> A, B = error_dynamics(0.5)
    >>> A
    array([[0. , 0. , 0. ],
           [0. , 0. , 0.5],
           [0. , 0. , 0. ]])
    """
    A = np.array([[0.0, omega, 0.0], [-omega, 0.0, v], [0.0, 0.0, 0.0]]) + 0.0  # no -0.0
    B = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    return A, B
