"""Planner: a smooth spline reference through waypoints, travelled at constant speed."""

from __future__ import annotations

from typing import Any

import numpy as np

from archself.linear.designs import cached
from archself.modules.base import Param, RuntimeModule

__all__ = ["SplinePlanner", "spline_path"]


def path_points(waypoints) -> np.ndarray:
    """The distinct ``[x, y]`` points of ``waypoints``; ValueError saying what is wrong.

    Examples
    --------
    >>> path_points([[0, 0], [0, 0], [3, 4]]).tolist()
    [[0.0, 0.0], [3.0, 4.0]]
    >>> path_points([[5]])
    Traceback (most recent call last):
    ...
    ValueError: waypoints must be a list of at least two [x, y] points
    """
    try:
        pts = np.asarray(waypoints, dtype=float)
    except (TypeError, ValueError):  # ragged ([[0, 0], [5]]) or not numbers
        pts = np.empty(0)  # refused below
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise ValueError("waypoints must be a list of at least two [x, y] points")
    pts = pts[np.r_[True, np.hypot(*np.diff(pts, axis=0).T) > 1e-9]]
    if len(pts) < 2:
        raise ValueError("waypoints must contain two distinct points")
    return pts


def spline_path(waypoints, ds: float = 0.02) -> dict[str, Any]:
    """Arc-length table of a cubic spline through ``waypoints``.

    The spline (:class:`scipy.interpolate.CubicSpline`, not-a-knot) is
    parametrized by cumulative chord length, then resampled at equal arc-length
    steps ``ds`` so that a reference moving at constant speed is a table lookup.
    A pure function of the distinct waypoints and ``ds``: computed once and kept in the
    design cache (:func:`archself.linear.designs.cached`), so a later process reads the
    table bit for bit and imports no scipy.interpolate.

    Parameters
    ----------
    waypoints : array_like, shape (n, 2)
        At least two points (m); consecutive duplicates are dropped.
    ds : float
        Arc-length resolution of the table (m).

    Returns
    -------
    dict
        ``s`` (arc length), ``x``, ``y``, ``theta`` (unwrapped tangent heading) and
        ``kappa`` (signed curvature, 1/m), each of shape (m,), and ``length``.

    Examples
    --------
    >>> p = spline_path([[0, 0], [10, 0]])
    >>> round(float(p["length"]), 6), float(abs(p["kappa"]).max()) < 1e-9
    (10.0, True)
    """
    pts = path_points(waypoints)
    table = cached("spline_path", "scipy", [pts, [ds]], lambda: _spline_table(pts, ds),
                   _is_table)
    return {**{k: table[k] for k in _ROWS}, "length": float(table["length"])}


_ROWS = ("s", "x", "y", "theta", "kappa")


def _is_table(found: dict[str, np.ndarray]) -> bool:
    """Whether a stored entry has the arrays of :func:`_spline_table` (rows of one length)."""
    return (set(found) == {*_ROWS, "length"} and found["length"].shape == ()
            and len({found[k].shape for k in _ROWS}) == 1 and found["s"].ndim == 1)


def _spline_table(pts: np.ndarray, ds: float) -> dict[str, np.ndarray]:
    """The arrays of :func:`spline_path` of the distinct points ``pts`` (scipy imported)."""
    from scipy.interpolate import CubicSpline

    chord = np.r_[0.0, np.cumsum(np.hypot(*np.diff(pts, axis=0).T))]
    bc = "not-a-knot" if len(pts) > 3 else "natural"
    cs = CubicSpline(chord, pts, axis=0, bc_type=bc)
    u = np.linspace(0.0, chord[-1], max(2000, int(chord[-1] / ds) * 4))
    d1 = cs(u, 1)
    speed = np.hypot(d1[:, 0], d1[:, 1])
    arc = np.r_[0.0, np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(u))]
    s = np.arange(0.0, arc[-1], ds)
    s = np.r_[s, arc[-1]] if arc[-1] - s[-1] > 1e-9 else s
    us = np.interp(s, arc, u)
    xy = cs(us)
    d1 = cs(us, 1)
    d2 = cs(us, 2)
    theta = np.unwrap(np.arctan2(d1[:, 1], d1[:, 0]))
    kappa = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.maximum(
        np.hypot(d1[:, 0], d1[:, 1]) ** 3, 1e-12
    )
    return {
        "s": s,
        "x": xy[:, 0],
        "y": xy[:, 1],
        "theta": theta,
        "kappa": kappa,
        "length": np.array(arc[-1]),
    }


class _Table:
    """Immutable lookup table, shared (not copied) by ``copy.deepcopy`` snapshots."""

    def __init__(self, path: dict[str, np.ndarray]) -> None:
        self.xytk = tuple(path[k].tolist() for k in ("x", "y", "theta", "kappa"))

    def __deepcopy__(self, memo: dict) -> _Table:
        return self


#: Tables of the last paths made: (waypoints, resolution) -> (table, length, rows). A
#: campaign's runs, and the lanes of a batch, build the same planner again and again.
_TABLES: dict[bytes, tuple[_Table, float, int]] = {}


def _table(waypoints, ds: float) -> tuple[_Table, float, int]:
    """The lookup table of :func:`spline_path` (made once per path and resolution)."""
    try:
        pts = np.asarray(waypoints, dtype=float)
    except (TypeError, ValueError):  # ragged ([[0, 0], [5]]) or not numbers
        raise ValueError("waypoints must be a list of at least two [x, y] points") from None
    key = pts.tobytes() + repr((pts.shape, ds)).encode()
    found = _TABLES.get(key)
    if found is None:
        path = spline_path(waypoints, ds)
        found = (_Table(path), float(path["length"]), len(path["x"]))
        if len(_TABLES) >= 16:
            _TABLES.pop(next(iter(_TABLES)))
        _TABLES[key] = found
    return found


class SplinePlanner(RuntimeModule):
    """Smooth cubic-spline reference through ``waypoints`` at ``speed_mps``.

    The reference at time t is the point at arc length ``s = speed · t`` with its
    tangent heading, the speed and the yaw rate ``ω = κ(s) · speed``; after the
    end of the path it stops there (v = ω = 0).

    Optional input ``kinematics`` (unused; the path is kinematically smooth);
    output ``reference`` ``[x, y, θ, v, ω]``.

    Examples
    --------
    >>> pl = SplinePlanner("p", {"waypoints": [[0, 0], [10, 0]], "speed_mps": 0.5},
    ...                    np.random.default_rng(0))
    >>> pl.step(2.0, 0.05, {})["reference"].round(6)
    array([1. , 0. , 0. , 0.5, 0. ])
    """

    finite_outputs = True  # a precomputed table (archself.system.live.needs_checks)

    parameters = {
        "waypoints": Param(unit="m", doc="list of at least two [x, y] points", min=-1e6, max=1e6),
        "speed_mps": Param(0.5, "m/s", "speed along the path", min=0.001, max=50.0),
        "resolution_m": Param(
            0.02, "m", "arc-length step of the lookup table", min=0.001, max=10.0
        ),
    }
    role = "planner"
    optional_inputs = ("kinematics",)
    outputs = ("reference",)
    lanes = "archself_diffdrive.lanes_planning:SplinePlannerLanes"
    output_sizes = {"reference": 5}  # x, y, θ, v, ω
    output_elements = {"reference": ("x", "y", "theta", "v", "omega")}

    @classmethod
    def memory_estimate(cls, params: dict, dt: float) -> int:
        """Bytes of :func:`spline_path` and its table for these waypoints and resolution.

        The path's length is about the sum of the chords (L); the spline is sampled at
        ``4 L / ds`` points (about 8 float arrays alive at once: 64 bytes a sample),
        the table has ``L / ds`` rows (12 float arrays while it is made, then 4 lists
        of Python floats: 224 bytes a row): about 480 bytes per ``ds`` of path.

        Examples
        --------
        >>> n = SplinePlanner.memory_estimate({"waypoints": [[0, 0], [1e6, 0]],
        ...                                    "resolution_m": 0.02}, 0.05)
        >>> round(n / 2**30, 1)   # GiB: the waypoint at 1e6 m of issue 39
        22.4
        """
        try:
            pts = np.asarray(params["waypoints"], dtype=float)
        except (TypeError, ValueError):
            return 0  # not a path: check_params says why
        if pts.ndim != 2 or pts.shape[1:] != (2,) or len(pts) < 2:
            return 0
        length = float(np.hypot(*np.diff(pts, axis=0).T).sum())
        rows = length / float(params["resolution_m"])
        return int(64 * max(2000.0, 4 * rows) + 224 * rows)

    @classmethod
    def check_params(cls, name: str, params: dict, dt: float) -> str | None:
        """The waypoints' shape, checked without building the spline (no scipy at validate)."""
        try:
            path_points(params.get("waypoints"))
        except ValueError as exc:
            return str(exc)
        return None

    def configure(self) -> None:
        self.speed = float(self.params["speed_mps"])
        self.ds = float(self.params["resolution_m"])
        self._table, self.length, self._n = _table(self.params["waypoints"], self.ds)

    @property
    def duration_s(self) -> float:
        """Time the reference takes to reach the end of the path (s)."""
        return float(self.length / self.speed)

    def reference(self, t: float) -> np.ndarray:
        """``[x, y, θ, v, ω]`` of the reference at time ``t``."""
        s = self.speed * t
        if s >= self.length:
            i = self._n - 1
            x, y, th, _ = self._table.xytk
            return np.array([x[i], y[i], th[i], 0.0, 0.0])
        f = max(s, 0.0) / self.ds
        i = min(int(f), self._n - 2)
        a = min(f - i, 1.0)
        b = 1.0 - a
        x, y, th, k = self._table.xytk
        return np.array(
            [
                b * x[i] + a * x[i + 1],
                b * y[i] + a * y[i + 1],
                b * th[i] + a * th[i + 1],
                self.speed,
                (b * k[i] + a * k[i + 1]) * self.speed,
            ]
        )

    def step(self, t, dt, inputs):
        return {"reference": self.reference(t)}
