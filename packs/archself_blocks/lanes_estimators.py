"""The linear Kalman filter in N lanes: :class:`~archself_blocks.estimators.KalmanFilter`, batched.

:class:`ModelEstimatorLanes` is what the batched estimators share (the model input,
the last ``u``, the start, the paused monitor, the innovation windows, the per-run
bridge of :class:`~archself_blocks.estimators._ModelEstimator`);
:class:`KalmanFilterLanes` keeps every lane's estimate ``(N, n)``, covariance
``(N, n, n)`` and filter matrices (from the lane's own model object and
parameters: ``model.discrete(dt)``, ``Q·dt``, the measured rows of C, ``R``, ``P0``)
and runs the filter's predict and Joseph-form update of
:mod:`~archself_blocks.estimators` on its rows, the functions the per-run filter runs on
one row. Lanes start (the first measurement: ``x0`` or the least-squares
estimate), take a new model object, keep their last ``u`` and pause their monitor
after a hand-over exactly as the per-run filter does; the innovation windows are
:class:`~archself_blocks.lanes_windows.LaneMeanWindows`. The per-run bridge stores a
lane's state into its instance (its covariance ``P`` and the matrices of the
instance's own ``_matrices``), so ``export_state``, ``linear_model`` and
``linearization`` see it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.errors import SimulationError
from archself_blocks.estimators import _cov, nis, predict, update
from archself_blocks.lanes_base import BlockLanes, as_rows, present, zoh
from archself_blocks.lanes_windows import LaneMeanWindows
from archself_blocks.lti import matvec, vector

__all__ = ["KalmanFilterLanes", "ModelEstimatorLanes"]


class ModelEstimatorLanes(BlockLanes):
    """An estimator on an LTI model input in N lanes: what the batched estimators share.

    The arrays are made when the first model (or estimate, or input) arrives, empty
    until then: the lanes' models must share their sizes. Subclasses build their
    matrices (:meth:`_build`), advance the started lanes (:meth:`_advance`) and carry
    their own state over the per-run bridge (:meth:`_load_lane`, :meth:`_store_lane`).
    """

    settle_s: np.ndarray
    window_s: np.ndarray
    eye: np.ndarray  # the identity of the filtered state (the EKF's)
    has_P: np.ndarray
    P: np.ndarray
    dt_last: np.ndarray
    #: Entries after ν in a window item: the NIS of the Kalman filters, none for an observer.
    extra_width = 1

    def __init__(self, modules) -> None:
        N = len(modules)
        self.sizes = (0, 0, 0, 0)  # n, k (measured rows), m, p; (0, …): no model yet
        self.models: list[Any] = [None] * N
        self.x = np.zeros((N, 0))
        self.started = np.zeros(N, dtype=bool)  # x̂ known (not None)
        self.u = np.zeros((N, 0))
        self.has_u = np.zeros(N, dtype=bool)
        self.dt_of = np.full(N, math.nan)  # the step of the lane's matrices (NaN: to build)
        self.quiet_until = np.full(N, -math.inf)
        self.pending = np.zeros(N, dtype=bool)  # _pending_settle
        self.signals = {k: np.full(N, math.nan) for k in type(modules[0]).residual_signals}
        self.window = LaneMeanWindows(N, 0)  # no items before a model
        self._shared: dict[Any, Any] = {}
        super().__init__(modules)

    # ------------------------------------------------------------------ sizes
    def _size_x(self, n: int) -> None:
        if not self.x.shape[1]:
            self.x = np.zeros((self.n, n))
        elif self.x.shape[1] != n:
            raise SimulationError(f"{self.name}: the lanes' estimates differ in size")

    def _size_u(self, m: int) -> None:
        if not self.u.shape[1]:
            self.u = np.zeros((self.n, m))

    def _size_model(self, model: Any) -> None:
        k = model.p if self.rows is None else len(self.rows)
        sizes = (model.n, k, model.m, model.p)
        if self.sizes[0]:
            if sizes != self.sizes:
                raise SimulationError(f"{self.name}: the lanes' models differ in size")
            return
        self.sizes = sizes
        N, (n, k, m, p) = self.n, sizes
        self._size_x(n)
        self._size_u(m)
        self.H, self.C = np.zeros((N, k, n)), np.zeros((N, p, n))
        self.window = LaneMeanWindows(N, k + self.extra_width)
        self.window.window[:] = self.window_s
        self._alloc()

    def _alloc(self) -> None:
        """Make the subclass's arrays (``self.sizes`` is known)."""

    # ------------------------------------------------------------------ the per-run bridge
    def load(self, lanes):
        mods = self._mods(lanes)
        self._read(lanes, "settle_s", [m.settle_s for m in mods])
        self._read(lanes, "window_s", [m.window.window_s for m in mods])
        self.rows = self.modules[0].rows
        for m in mods:  # the sizes first: a lane may have its model, another none yet
            if m.model is not None:
                self._size_model(m.model)
            if m.x is not None:
                self._size_x(m.x.size)
            if m.u is not None:
                self._size_u(m.u.size)
        for i, m in zip(self.indices(lanes).tolist(), mods, strict=True):
            self.models[i] = m.model
            self.started[i] = m.x is not None
            if m.x is not None:
                self.x[i] = m.x
            self.has_u[i] = m.u is not None
            if m.u is not None:
                self.u[i] = m.u
            self.dt_of[i] = math.nan  # rebuilt at the next step: the same matrices
            self.quiet_until[i], self.pending[i] = m.quiet_until, m._pending_settle
            for key, arr in self.signals.items():
                arr[i] = m.signals.get(key, math.nan)
            self.window.load(i, m.window)
            self._load_lane(i, m)

    def _load_lane(self, i: int, m: Any) -> None:
        """Read the subclass's state of lane ``i`` from its instance ``m``."""

    def store(self, lanes):
        for i, m in zip(self.indices(lanes).tolist(), self._mods(lanes), strict=True):
            m.model = self.models[i]
            m.x = self.x[i].copy() if self.started[i] else None
            m.u = self.u[i].copy() if self.has_u[i] else None
            m.quiet_until, m._pending_settle = float(self.quiet_until[i]), bool(self.pending[i])
            for key, arr in self.signals.items():
                m.signals[key] = float(arr[i])
            self.window.store(i, m.window)
            self._store_lane(i, m)
            m._dt = None if math.isnan(self.dt_of[i]) else float(self.dt_of[i])

    def _store_lane(self, i: int, m: Any) -> None:
        """Write the subclass's state of lane ``i`` into its instance ``m``."""

    def local_signals(self, lanes):
        return {k: v[lanes].copy() for k, v in self.signals.items()}

    # ------------------------------------------------------------------ a step
    def _take_models(self, objs: list[Any] | None, idx: np.ndarray) -> np.ndarray:
        """Lanes ``idx`` take a new model object (its matrices rebuilt); which have one."""
        if objs is not None:
            for i, obj in zip(idx.tolist(), objs, strict=True):
                if obj is not None and obj is not self.models[i]:
                    self._size_model(obj)
                    self.models[i] = obj
                    self.dt_of[i] = math.nan
        return np.array([self.models[i] is not None for i in idx.tolist()], dtype=bool)

    def _measured(self, idx: np.ndarray) -> None:
        """H (the measured rows of C) and C of lanes ``idx`` from their models."""
        for i in idx.tolist():
            C = self.models[i].C
            self.C[i] = C
            self.H[i] = C if self.rows is None else C[self.rows, :]

    def step(self, t, dt, inputs, lanes):
        idx = self.indices(lanes)
        modeled = self._take_models(inputs.get("model"), idx)
        u = as_rows(inputs.get("u"))
        if u is not None:
            has = present(u)
            if has.any():
                self._size_u(u.shape[1])
                self.u[idx[has]] = u[has]
                self.has_u[idx[has]] = True
        zero = modeled & ~self.has_u[idx]
        if zero.any():
            self.u[idx[zero]] = 0.0
            self.has_u[idx[zero]] = True
        wait = self.pending[idx]
        if wait.any():
            self.quiet_until[idx[wait]] = t + self.settle_s[idx[wait]]
            self.pending[idx[wait]] = False
        if not modeled.any():
            return self._publish(lanes, modeled)
        z = as_rows(inputs.get("measurement"))
        zhas = np.zeros(len(idx), dtype=bool) if z is None else present(z)
        build = modeled & ~(self.dt_of[idx] == dt)
        if build.any():
            self._measured(idx[build])
            self._build(idx[build], dt)
            self.dt_of[idx[build]] = dt
        run = modeled & self.started[idx]
        fresh = modeled & ~self.started[idx] & zhas
        if fresh.any():
            self._begin(t, idx[fresh], z[fresh])
        if run.any():
            every = bool(run.all())
            self._advance(t, lanes if every else idx[run],
                          None if z is None else (z if every else z[run]),
                          zhas if every else zhas[run])
        return self._publish(lanes, modeled)

    def _build(self, idx: np.ndarray, dt: float) -> None:
        """The subclass's matrices of lanes ``idx`` at ``dt`` (per-run ``_matrices``)."""

    def _advance(self, t: float, sel, z: np.ndarray | None, zhas: np.ndarray) -> None:
        """Advance the started lanes ``sel`` with their measurements ``z`` (rows ``zhas``)."""

    def _begin(self, t: float, idx: np.ndarray, z: np.ndarray) -> None:
        """``_begin``: ``x0`` or the least-squares estimate ``pinv(H) z``; the monitor pauses."""
        for j, i in enumerate(idx.tolist()):
            x0 = self.modules[i].params["x0"]
            self.x[i] = vector(x0) if x0 is not None else np.linalg.pinv(self.H[i]) @ z[j]
            self.quiet_until[i] = t + self.settle_s[i]
            self.started[i] = True

    def _publish(self, lanes, modeled: np.ndarray) -> dict[str, Any]:
        """``estimate`` (C x̂) and ``state`` (x̂) of the lanes with a model and an estimate."""
        if not modeled.any():
            return {"estimate": None, "state": None}
        out = modeled & self.started[lanes]
        x = self.x[lanes].copy()  # a view for ALL: published, it must not change with the state
        est = matvec(self.C[lanes], x)
        if not out.all():
            x[~out] = math.nan
            est[~out] = math.nan
        self._screen(lanes, out, est, x)
        return {"estimate": est, "state": x}

    # the Kalman filters' covariance: ``has_P``, ``P``, ``dt_last``
    def _load_cov(self, i: int, m: Any) -> None:
        """Lane ``i``'s covariance from its instance (if it has one)."""
        self.has_P[i] = m.P is not None
        if m.P is not None:
            self.P[i] = m.P
        self.dt_last[i] = math.nan

    def _store_cov(self, i: int, m: Any) -> None:
        """Lane ``i``'s covariance into its instance, whose matrices are built with the
        lane's model for the step it was last built for."""
        if not self.has_P[i]:
            return
        if not math.isnan(self.dt_last[i]):
            m._matrices(float(self.dt_last[i]))
        m.P = self.P[i].copy()  # (else the instance's own matrices, loaded from)

    def _joseph(self, t, idx, x, P, nu, H, R, inv) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`~archself_blocks.estimators.update` of lanes ``idx`` with innovation ``nu``,
        and the innovation monitor; which lanes did not raise.

        ``inv`` is the per-run filter's inverse; a lane whose ``S`` it cannot invert
        fails (where its run raises) and keeps its rows.
        """
        x1, P1, S, errors = update(x, P, nu, H, R, inv)
        keep = np.ones(len(idx), dtype=bool)
        for j, exc in errors.items():
            keep[j] = False
            self.failed[int(idx[j])] = f"raised {type(exc).__name__}"
        if not keep.all():
            x1 = np.where(keep[:, None], x1, x)
            P1 = np.where(keep[:, None, None], P1, P)
            idx, nu, S = idx[keep], nu[keep], S[keep]
        if len(idx):
            self._monitor(t, idx, nu, nis(nu, S))
        return x1, P1, keep

    def _monitor(self, t: float, idx: np.ndarray, nu: np.ndarray,
                 nis: np.ndarray | None) -> None:
        """``_monitor``: the windows of the lanes past their quiet time, and their signals."""
        on = ~(t < self.quiet_until[idx])
        if not on.any():
            return
        idx, nu = idx[on], nu[on]
        self.window.add(t, idx, nu if nis is None else np.column_stack([nu, nis[on]]))
        mean = self.window.value(idx)
        ready = ~np.isnan(mean[:, 0])
        if ready.any():
            k = nu.shape[1]
            m = mean[ready, :k]
            norm = np.sqrt((m[:, None, :] @ m[:, :, None])[:, 0, 0])
            self.signals["innovation"][idx[ready]] = norm
            if nis is not None:
                self.signals["nis"][idx[ready]] = mean[ready, k]


class KalmanFilterLanes(ModelEstimatorLanes):
    """:class:`~archself_blocks.estimators.KalmanFilter` in N lanes (see the module doc)."""

    def __init__(self, modules) -> None:
        N = len(modules)
        self.dt_last = np.full(N, math.nan)  # the step the lane's matrices were built for
        self.has_P = np.zeros(N, dtype=bool)
        super().__init__(modules)

    def _alloc(self) -> None:
        N, (n, k, m, _) = self.n, self.sizes
        self.F, self.B, self.Q = np.zeros((N, n, n)), np.zeros((N, n, m)), np.zeros((N, n, n))
        self.R, self.P = np.zeros((N, k, k)), np.zeros((N, n, n))

    def _load_lane(self, i: int, m: Any) -> None:
        self._load_cov(i, m)

    def _store_lane(self, i: int, m: Any) -> None:
        self._store_cov(i, m)

    def _build(self, idx: np.ndarray, dt: float) -> None:
        """``KalmanFilter._matrices(dt)`` of lanes ``idx``: F, B, Q, R; P kept or P0."""
        n, k = self.sizes[0], self.sizes[1]
        for i in idx.tolist():
            mod, model = self.modules[i], self.models[i]
            self.F[i], self.B[i] = zoh(model, dt, self._shared)
            q = _cov(mod.params["Q"], n)
            self.Q[i] = q * dt if model.dt == 0 else q
            self.R[i] = _cov(mod.params["R"], k)
            if not self.has_P[i]:
                self.P[i] = _cov(mod.params["P0"], n)
                self.has_P[i] = True
            self.dt_last[i] = dt

    def _advance(self, t: float, sel, z: np.ndarray | None, zhas: np.ndarray) -> None:
        """Predict the lanes ``sel`` (started, with a model); update those with a measurement.

        A lane whose update raised keeps its estimate and the predicted covariance
        (the per-run filter's state after the exception).
        """
        x, P = predict(self.x[sel], self.P[sel], self.F[sel], self.Q[sel],
                       matvec(self.B[sel], self.u[sel]))
        if z is not None and zhas.any():
            idx = self.indices(sel)
            if zhas.all():
                x, P, keep = self._update(t, idx, x, P, z)
            else:
                rows = np.flatnonzero(zhas)
                x[rows], P[rows], ok = self._update(t, idx[rows], x[rows], P[rows], z[rows])
                keep = np.ones(len(idx), dtype=bool)
                keep[rows] = ok
            if not keep.all():
                x = np.where(keep[:, None], x, self.x[sel])
        self.x[sel], self.P[sel] = x, P

    def _update(self, t, idx, x, P, z) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The filter's update (Joseph form) of lanes ``idx``; which lanes did not raise.

        A lane whose ``S`` is singular raises per run (``numpy.linalg.inv``): its rows
        come back as given.
        """
        H = self.H[idx]
        return self._joseph(t, idx, x, P, z - matvec(H, x), H, self.R[idx], np.linalg.inv)
