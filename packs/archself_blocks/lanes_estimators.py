"""The linear Kalman filter in N lanes: :class:`~archself_blocks.estimators.KalmanFilter`, batched.

:class:`KalmanFilterLanes` keeps every lane's estimate ``(N, n)``, covariance
``(N, n, n)`` and filter matrices (from the lane's own model object and
parameters: ``model.discrete(dt)``, ``Q·dt``, the measured rows of C, ``R``, ``P0``)
and runs filterpy's ``predict`` and ``update`` (Joseph form) as stacked products
(``numpy.matmul``: each lane's ``dot`` of the per-run filter bit for bit on the
platforms tested; ``numpy.linalg.inv``/``solve`` per stacked matrix, LAPACK's as
per run). Lanes start (the first measurement: ``x0`` or the least-squares
estimate), take a new model object, keep their last ``u`` and pause their monitor
after a hand-over exactly as the per-run filter does; the innovation windows are
:class:`~archself_blocks.lanes_windows.LaneMeanWindows`. The per-run bridge stores a
lane's state into its instance's filterpy object (built with the instance's own
``_matrices``), so ``export_state``, ``linear_model`` and ``linearization`` see it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.errors import SimulationError
from archself_blocks.estimators import _cov
from archself_blocks.lanes_base import BlockLanes, as_rows, matvec, present, zoh
from archself_blocks.lanes_windows import LaneMeanWindows
from archself_blocks.lti import vector

__all__ = ["KalmanFilterLanes"]


def _t(a: np.ndarray) -> np.ndarray:
    """The stacked transposes."""
    return a.transpose(0, 2, 1)


class KalmanFilterLanes(BlockLanes):
    """:class:`~archself_blocks.estimators.KalmanFilter` in N lanes (see the module doc).

    The arrays of the filter are made when the first model (or estimate, or input)
    arrives, empty until then: the lanes' models must share their sizes.
    """

    settle_s: np.ndarray
    window_s: np.ndarray

    def __init__(self, modules) -> None:
        N = len(modules)
        self.sizes = (0, 0, 0, 0)  # n, k (measured rows), m, p; (0, …): no model yet
        self.models: list[Any] = [None] * N
        self.x = np.zeros((N, 0))
        self.started = np.zeros(N, dtype=bool)  # x̂ known (not None)
        self.u = np.zeros((N, 0))
        self.has_u = np.zeros(N, dtype=bool)
        self.dt_of = np.full(N, math.nan)  # the step of the lane's matrices (NaN: to build)
        self.dt_last = np.full(N, math.nan)  # the step its covariance was last built for
        self.has_P = np.zeros(N, dtype=bool)
        self.quiet_until = np.full(N, -math.inf)
        self.pending = np.zeros(N, dtype=bool)  # _pending_settle
        self.innovation = np.full(N, math.nan)
        self.nis = np.full(N, math.nan)
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

    def _size_model(self, model: Any, rows: list[int] | None) -> None:
        k = model.p if rows is None else len(rows)
        sizes = (model.n, k, model.m, model.p)
        if self.sizes[0]:
            if sizes != self.sizes:
                raise SimulationError(f"{self.name}: the lanes' models differ in size")
            return
        self.sizes = sizes
        N, (n, k, m, p) = self.n, sizes
        self._size_x(n)
        self._size_u(m)
        self.F, self.B, self.Q = np.zeros((N, n, n)), np.zeros((N, n, m)), np.zeros((N, n, n))
        self.H, self.R, self.C = np.zeros((N, k, n)), np.zeros((N, k, k)), np.zeros((N, p, n))
        self.P = np.zeros((N, n, n))
        self.eye = np.eye(n)
        self.window = LaneMeanWindows(N, k + 1)
        self.window.window_s[:] = self.window_s

    # ------------------------------------------------------------------ the per-run bridge
    def load(self, lanes):
        mods = self._mods(lanes)
        idx = self.indices(lanes).tolist()
        self._read(lanes, "settle_s", [m.settle_s for m in mods])
        self._read(lanes, "window_s", [m.window.window_s for m in mods])
        self.rows = self.modules[0].rows
        for m in mods:  # the sizes first: a lane may have its model, another none yet
            if m.model is not None:
                self._size_model(m.model, m.rows)
            if m.x is not None:
                self._size_x(m.x.size)
            if m.u is not None:
                self._size_u(m.u.size)
        for i, m in zip(idx, mods, strict=True):
            self.models[i] = m.model
            self.started[i] = m.x is not None
            if m.x is not None:
                self.x[i] = m.x
            self.has_u[i] = m.u is not None
            if m.u is not None:
                self.u[i] = m.u
            kf = getattr(m, "kf", None)
            self.has_P[i] = kf is not None
            if kf is not None:
                self.P[i] = kf.P
            self.dt_of[i] = self.dt_last[i] = math.nan  # rebuilt: the same matrices, P kept
            self.quiet_until[i], self.pending[i] = m.quiet_until, m._pending_settle
            self.innovation[i], self.nis[i] = m.signals["innovation"], m.signals["nis"]
            self.window.load(i, m.window)

    def store(self, lanes):
        for i, m in zip(self.indices(lanes), self._mods(lanes), strict=True):
            m.model = self.models[i]
            m.x = self.x[i].copy() if self.started[i] else None
            m.u = self.u[i].copy() if self.has_u[i] else None
            m.quiet_until, m._pending_settle = float(self.quiet_until[i]), bool(self.pending[i])
            m.signals["innovation"] = float(self.innovation[i])
            m.signals["nis"] = float(self.nis[i])
            self.window.store(i, m.window)
            if self.has_P[i]:
                if not math.isnan(self.dt_last[i]):  # its filterpy object, with the lane's model
                    m._matrices(float(self.dt_last[i]))
                m.kf.P = self.P[i].copy()  # (else the instance's own object, loaded from)
                if m.x is not None:
                    m.kf.x = m.x.copy()
            m._dt = None if math.isnan(self.dt_of[i]) else float(self.dt_of[i])

    def local_signals(self, lanes):
        return {"innovation": self.innovation[lanes].copy(), "nis": self.nis[lanes].copy()}

    # ------------------------------------------------------------------ a step
    def _build(self, idx: np.ndarray, dt: float) -> None:
        """``KalmanFilter._matrices(dt)`` of lanes ``idx``: F, B, H, Q, R, C; P kept or P0."""
        n, k = self.sizes[0], self.sizes[1]
        for i in idx.tolist():
            mod, model = self.modules[i], self.models[i]
            self.F[i], self.B[i] = zoh(model, dt, self._shared)
            q = _cov(mod.params["Q"], n)
            self.Q[i] = q * dt if model.dt == 0 else q
            self.H[i] = model.C if self.rows is None else model.C[self.rows, :]
            self.R[i] = _cov(mod.params["R"], k)
            self.C[i] = model.C
            if not self.has_P[i]:
                self.P[i] = _cov(mod.params["P0"], n)
                self.has_P[i] = True
            self.dt_of[i] = self.dt_last[i] = dt

    def _take_models(self, objs: list[Any] | None, idx: np.ndarray) -> np.ndarray:
        """Lanes ``idx`` take a new model object (its matrices rebuilt); which have one."""
        if objs is not None:
            for i, obj in zip(idx.tolist(), objs, strict=True):
                if obj is not None and obj is not self.models[i]:
                    self._size_model(obj, self.rows)
                    self.models[i] = obj
                    self.dt_of[i] = math.nan
        return np.array([self.models[i] is not None for i in idx.tolist()], dtype=bool)

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
            return {"estimate": None, "state": None}
        z = as_rows(inputs.get("measurement"))
        zhas = np.zeros(len(idx), dtype=bool) if z is None else present(z)
        build = modeled & ~(self.dt_of[idx] == dt)
        if build.any():
            self._build(idx[build], dt)
        run = modeled & self.started[idx]
        fresh = modeled & ~self.started[idx] & zhas
        if fresh.any():
            self._begin(t, idx[fresh], z[fresh])
        if run.any():
            every = bool(run.all())
            sel = lanes if every else idx[run]
            self._advance(t, sel, None if z is None else (z if every else z[run]),
                          zhas if every else zhas[run])
        out = modeled & self.started[idx]
        x = self.x[idx]
        est = matvec(self.C[idx], x)
        if not out.all():
            x[~out] = math.nan
            est[~out] = math.nan
        self._screen(lanes, out, est, x)
        return {"estimate": est, "state": x}

    def _begin(self, t: float, idx: np.ndarray, z: np.ndarray) -> None:
        """``_begin``: ``x0`` or the least-squares estimate ``pinv(H) z``; the monitor pauses."""
        for j, i in enumerate(idx.tolist()):
            x0 = self.modules[i].params["x0"]
            self.x[i] = vector(x0) if x0 is not None else np.linalg.pinv(self.H[i]) @ z[j]
            self.quiet_until[i] = t + self.settle_s[i]
            self.started[i] = True

    def _advance(self, t: float, sel, z: np.ndarray | None, zhas: np.ndarray) -> None:
        """Predict the lanes ``sel`` (started, with a model); update those with a measurement.

        A lane whose update raised keeps its estimate and the predicted covariance
        (the per-run filter's state after the exception).
        """
        F = self.F[sel]
        x = matvec(F, self.x[sel]) + matvec(self.B[sel], self.u[sel])
        P = (F @ self.P[sel]) @ _t(F) + self.Q[sel]
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
        """filterpy's ``update`` (Joseph form) of lanes ``idx``; which lanes did not raise.

        A lane whose ``S`` is singular raises per run (``numpy.linalg.inv``): its rows
        come back as given.
        """
        H, R = self.H[idx], self.R[idx]
        nu = z - matvec(H, x)
        PHT = P @ _t(H)
        S = H @ PHT + R
        keep = np.ones(len(idx), dtype=bool)
        try:
            SI = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            SI = np.zeros_like(S)
            for j in range(len(S)):
                try:
                    SI[j] = np.linalg.inv(S[j])
                except np.linalg.LinAlgError:
                    keep[j] = False
                    self.failed[int(idx[j])] = "raised LinAlgError"
        K = PHT @ SI
        x1 = x + matvec(K, nu)
        I_KH = self.eye - K @ H
        P1 = (I_KH @ P) @ _t(I_KH) + (K @ R) @ _t(K)
        if not keep.all():
            x1 = np.where(keep[:, None], x1, x)
            P1 = np.where(keep[:, None, None], P1, P)
            idx, nu, S = idx[keep], nu[keep], S[keep]
        if len(idx):
            sol = np.linalg.solve(S, nu[..., None])
            self._monitor(t, idx, nu, (nu[:, None, :] @ sol)[:, 0, 0])
        return x1, P1, keep

    def _monitor(self, t: float, idx: np.ndarray, nu: np.ndarray, nis: np.ndarray) -> None:
        """``_monitor``: the windows of the lanes past their quiet time, and their signals."""
        on = ~(t < self.quiet_until[idx])
        if not on.any():
            return
        idx, nu, nis = idx[on], nu[on], nis[on]
        self.window.add(t, idx, np.column_stack([nu, nis]))
        mean = self.window.value(idx)
        ready = ~np.isnan(mean[:, 0])
        if ready.any():
            k = nu.shape[1]
            m = mean[ready, :k]
            self.innovation[idx[ready]] = np.sqrt((m[:, None, :] @ m[:, :, None])[:, 0, 0])
            self.nis[idx[ready]] = mean[ready, k]
