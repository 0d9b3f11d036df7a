"""The Luenberger observer and the augmented EKF in N lanes.

:class:`LuenbergerLanes` and :class:`AugmentedEkfLanes` are the batched classes of
:class:`~archself_blocks.estimators.Luenberger` and
:class:`~archself_blocks.estimators.AugmentedEkf`, on the base the Kalman filter
uses (:class:`~archself_blocks.lanes_estimators.ModelEstimatorLanes`: model input,
start, paused monitor, windows, the per-run bridge). The observer's matrices (its
gain L, by ``control.place`` or given, and the zero-order hold of ``A − L C``) come
from the per-run code run on a copy of the lane's instance, once for the lanes
whose model and parameters agree; the propagation ``Ad x̂ + Bd [u; y]`` is a stacked
product. The EKF runs the predict and update of :mod:`~archself_blocks.estimators` on the
augmented state ``[x, η, b]``, as its per-run instance does on one row, its ``S⁻¹`` by
``scipy.linalg.inv`` (filterpy's EKF's: batched from scipy 1.16, else matrix by matrix).
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import scipy.linalg as linalg

from archself.errors import SimulationError
from archself_blocks.estimators import _cov, predict
from archself_blocks.lanes_base import zoh
from archself_blocks.lanes_estimators import ModelEstimatorLanes
from archself_blocks.lti import matvec

__all__ = ["AugmentedEkfLanes", "LuenbergerLanes"]


class LuenbergerLanes(ModelEstimatorLanes):
    """:class:`~archself_blocks.estimators.Luenberger` in N lanes.

    State per lane: x̂ and the measurement of the step before (``y_prev``, the
    observer's input over the step that ended; ``has_y`` where there is one).
    """

    extra_width = 0

    def __init__(self, modules) -> None:
        self.has_y = np.zeros(len(modules), dtype=bool)
        super().__init__(modules)

    def _alloc(self) -> None:
        N, (n, k, m, _) = self.n, self.sizes
        self.y_prev = np.zeros((N, k))
        self.L, self.Ad, self.Bd = np.zeros((N, n, k)), np.zeros((N, n, n)), np.zeros((N, n, m + k))

    def _load_lane(self, i: int, m: Any) -> None:
        self.has_y[i] = m._y is not None
        if m._y is not None:
            self.y_prev[i] = m._y

    def _store_lane(self, i: int, m: Any) -> None:
        m._y = self.y_prev[i].copy() if self.has_y[i] else None
        if not math.isnan(self.dt_of[i]):  # the lane's matrices (else rebuilt per run)
            m._L, m._ad, m._bd = self.L[i].copy(), self.Ad[i].copy(), self.Bd[i].copy()

    def _build(self, idx: np.ndarray, dt: float) -> None:
        """``Luenberger._matrices(dt)`` (L recomputed) of lanes ``idx``, per distinct lane."""
        for i in idx.tolist():
            mod, model = self.modules[i], self.models[i]
            key = (model.A.tobytes(), model.B.tobytes(), model.C.tobytes(), model.A.shape,
                   model.B.shape, model.C.shape, model.dt, dt, repr(mod.params["gain"]),
                   repr(mod.params["poles"]))
            got = self._shared.get(key)
            if got is None:
                probe = copy.copy(mod)  # the per-run code, on a copy: the instance is untouched
                probe.model, probe._L = model, None
                probe._matrices(dt)
                got = self._shared[key] = (probe._L, probe._ad, probe._bd)
            self.L[i], self.Ad[i], self.Bd[i] = got

    def _begin(self, t: float, idx: np.ndarray, z: np.ndarray) -> None:
        super()._begin(t, idx, z)
        self.y_prev[idx] = z
        self.has_y[idx] = True

    def _advance(self, t: float, sel, z: np.ndarray | None, zhas: np.ndarray) -> None:
        x = self.x[sel]
        has_y = self.has_y[sel]
        if has_y.any():  # over the step that ended, with its u and y
            v = np.concatenate([self.u[sel], self.y_prev[sel]], axis=1)
            new = matvec(self.Ad[sel], x) + matvec(self.Bd[sel], v)
            x = new if has_y.all() else np.where(has_y[:, None], new, x)
        self.x[sel] = x
        if z is not None and zhas.any():
            idx = self.indices(sel)[zhas]
            nu = z[zhas] - matvec(self.H[idx], x[zhas])
            self._monitor(t, idx, nu, None)
            self.y_prev[idx] = z[zhas]
            self.has_y[idx] = True


class AugmentedEkfLanes(ModelEstimatorLanes):
    """:class:`~archself_blocks.estimators.AugmentedEkf` in N lanes.

    State per lane: x̂, the augmented part ``aug`` = [η̂, b̂] (``has_aug`` once made)
    and the covariance of ``[x, η, b]``. The lanes must agree on which parts are
    estimated (the sizes).
    """

    def __init__(self, modules) -> None:
        N = len(modules)
        flags = {(bool(m.params["estimate_effectiveness"]), bool(m.params["estimate_bias"]))
                 for m in modules}
        if len(flags) > 1:
            raise SimulationError(f"{modules[0].name}: the lanes estimate different parameters")
        self.flags = flags.pop()
        self.has_aug = np.zeros(N, dtype=bool)
        self.has_P = np.zeros(N, dtype=bool)
        self.dt_last = np.full(N, math.nan)
        super().__init__(modules)

    def _alloc(self) -> None:
        N, (n, k, m, _) = self.n, self.sizes
        self.ne, self.nb = m if self.flags[0] else 0, k if self.flags[1] else 0
        na = n + self.ne + self.nb
        self.aug = np.zeros((N, self.ne + self.nb))
        self.P, self.Q = np.zeros((N, na, na)), np.zeros((N, na, na))
        self.h, self.R = np.zeros((N, k, na)), np.zeros((N, k, k))
        self.ad, self.bd = np.zeros((N, n, n)), np.zeros((N, n, m))
        self.eye = np.eye(na)

    def _load_lane(self, i: int, m: Any) -> None:
        self.has_aug[i] = m.aug is not None
        if m.aug is not None:
            self.aug[i] = m.aug
        self._load_cov(i, m)

    def _store_lane(self, i: int, m: Any) -> None:
        m.aug = self.aug[i].copy() if self.has_aug[i] else None
        self._store_cov(i, m)

    def _build(self, idx: np.ndarray, dt: float) -> None:
        """``AugmentedEkf._matrices(dt)`` of lanes ``idx``: Q, h, R; P kept or P0; η = 1, b = 0."""
        (n, k, _, _), ne, nb = self.sizes, self.ne, self.nb
        for i in idx.tolist():
            p, model = self.modules[i].params, self.models[i]
            self.ad[i], self.bd[i] = zoh(model, dt, self._shared)
            scale = dt if model.dt == 0 else 1.0
            q = self.Q[i]
            q[:] = 0.0
            q[:n, :n] = _cov(p["Q"], n) * scale
            q[n:n + ne, n:n + ne] = float(p["effectiveness_noise"]) * scale * np.eye(ne)
            q[n + ne:, n + ne:] = float(p["bias_noise"]) * scale * np.eye(nb)
            self.h[i, :, :n] = self.H[i]
            self.h[i, :, n + ne:] = np.eye(k)[:, :nb] if nb else 0.0
            self.R[i] = _cov(p["R"], k)
            if not self.has_P[i]:
                P0 = self.P[i]
                P0[:] = 0.0
                P0[:n, :n] = _cov(p["P0"], n)
                P0[n:n + ne, n:n + ne] = float(p["effectiveness_p0"]) * np.eye(ne)
                P0[n + ne:, n + ne:] = float(p["bias_p0"]) * np.eye(nb)
                self.has_P[i] = True
            if not self.has_aug[i]:
                self.aug[i] = np.concatenate([np.ones(ne), np.zeros(nb)])
                self.has_aug[i] = True
            self.dt_last[i] = dt

    def _publish(self, lanes, modeled: np.ndarray) -> dict[str, Any]:
        out = super()._publish(lanes, modeled)
        has = self.has_aug[lanes]
        if not has.any():
            return {**out, "parameters": None}
        aug = self.aug[lanes].copy()
        aug[~has] = math.nan
        return {**out, "parameters": aug}

    def _advance(self, t: float, sel, z: np.ndarray | None, zhas: np.ndarray) -> None:
        n, ne = self.sizes[0], self.ne
        u, bd = self.u[sel], self.bd[sel]
        xa = np.concatenate([self.x[sel], self.aug[sel]], axis=1)
        f = np.repeat(self.eye[None], len(xa), axis=0)
        f[:, :n, :n] = self.ad[sel]
        if ne:  # exact: f(x, η) = F·[x, η, b] for this u (B = 0)
            f[:, :n, n:n + ne] = bd * u[:, None, :]
            xa, P = predict(xa, self.P[sel], f, self.Q[sel], 0)
        else:
            B = np.concatenate([bd, np.zeros((len(xa), self.nb, bd.shape[2]))], axis=1)
            xa, P = predict(xa, self.P[sel], f, self.Q[sel], matvec(B, u))
        keep = np.ones(len(xa), dtype=bool)
        if z is not None and zhas.any():
            rows = np.flatnonzero(zhas)
            xa[rows], P[rows], keep[rows] = self._update(t, self.indices(sel)[rows], xa[rows],
                                                         P[rows], z[rows])
        x, aug = xa[:, :n], xa[:, n:]
        if not keep.all():  # a lane whose update raised keeps x̂ and the parameters
            x = np.where(keep[:, None], x, self.x[sel])
            aug = np.where(keep[:, None], aug, self.aug[sel])
        self.x[sel], self.aug[sel], self.P[sel] = x, aug, P
        idx = self.indices(sel)
        on = ~(t < self.quiet_until[idx]) & keep
        if on.any():
            eta, b = aug[on, :ne], aug[on, ne:]
            loss = np.maximum(0.0, (1.0 - eta).max(axis=1)) if ne else np.zeros(on.sum())
            self.signals["effectiveness_loss"][idx[on]] = loss
            self.signals["bias"][idx[on]] = np.abs(b).max(axis=1) if self.nb else 0.0

    def _update(self, t, idx, xa, P, z) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``ExtendedKalmanFilter.update`` with H = h (Joseph form); which lanes did not raise."""
        H = self.h[idx]
        return self._joseph(t, idx, xa, P, z - matvec(H, xa), H, self.R[idx], linalg.inv)
