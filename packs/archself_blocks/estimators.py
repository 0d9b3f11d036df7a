"""Estimators on an LTI model: Kalman filters and the Luenberger observer.

Both take the model from a ``generic.lti_model`` node (input ``model``), the plant's
applied input (``u``, optional: zeros without it) and a measurement of some of the
model's outputs (``measurement``). They publish ``estimate`` (``C x̂``, a vector) and
``state`` (``x̂``), and two residual signals for the Monitor (Eq. 12), taken over a
sliding window of ``innovation_window_s``:

* ``innovation`` — the norm of the window mean of the innovation ν = y − C x̂⁻:
  zero-mean sensor noise averages out, a bias or drift does not;
* ``nis`` — the window mean of the normalized innovation squared νᵀ S⁻¹ ν (Kalman
  filter only; about the number of measured outputs when the filter is consistent).

For ``settle_s`` seconds after the start and after a hand-over the monitor is
paused: a converging estimate says nothing about the sensor.

The Kalman filters' maths (:func:`predict`, :func:`update`, :func:`nis`) is written
once, for one filter or a stack of L: the per-run filters and their lane classes run
the same functions; filterpy is the tests' oracle, never imported by a run.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from archself.linear import designs
from archself.model.architecture import Input, Output
from archself.modules.base import LinearModel, Param, RuntimeModule
from archself_blocks.lti import (
    LtiModel,
    as_matrix,
    as_vector,
    continuous_equivalent,
    matvec,
    vector,
)

__all__ = ["MeanWindow", "KalmanFilter", "AugmentedEkf", "Luenberger", "nis", "observer_gain",
           "predict", "update"]

#: the identity of each state size (read only)
_EYE: dict[int, np.ndarray] = {}


class MeanWindow:
    """Sliding-window mean of vectors over ``window_s`` seconds (NaN until half full).

    Examples
    --------
    >>> w = MeanWindow(4.0)
    >>> for t, v in [(0.0, 1.0), (1.0, -1.0), (2.0, 3.0)]:
    ...     w.add(t, np.array([v]))
    >>> w.value().tolist()
    [1.0]
    """

    def __init__(self, window_s: float) -> None:
        self.window_s = float(window_s)
        self.items: deque[tuple[float, np.ndarray]] = deque()
        self.total: np.ndarray | None = None
        self.start: float | None = None
        self.last = 0.0

    def add(self, t: float, v: np.ndarray) -> None:
        if self.start is None:
            self.start = t
        self.last = t
        self.items.append((t, v))
        self.total = v.copy() if self.total is None else self.total + v
        while self.items and self.items[0][0] <= t - self.window_s:
            self.total = self.total - self.items.popleft()[1]

    def value(self) -> np.ndarray | None:
        if self.total is None or self.start is None or self.last - self.start < 0.5 * self.window_s:
            return None
        return np.asarray(self.total / len(self.items))

    def clear(self) -> None:
        self.items.clear()
        self.total = None
        self.start = None


_COMMON = {
    "measured_outputs": Param(
        None, "", "rows of C the measurement holds; None: all", min=0, max=100000
    ),
    "x0": Param(None, "", "initial estimate; None: least squares from the first measurement"),
    "innovation_window_s": Param(10.0, "s", "window of the innovation monitor", min=0.001, max=1e7),
    "settle_s": Param(
        5.0, "s", "monitor paused this long after a start or hand-over", min=0.0, max=1e7
    ),
}


class _ModelEstimator(RuntimeModule):
    """What the Kalman filter and the observer share: inputs, monitor, hand-over."""

    role = "estimator"
    ports: ClassVar[tuple[Input | Output, ...]] = (
        Input("measurement", doc="the measured outputs (rows measured_outputs of C)"),
        Input("model", doc="the LtiModel it predicts with (generic.lti_model)"),
        Input("u", doc="the plant's applied input, to predict with", required=False),
        Output("estimate", doc="C x̂"),
        Output("state", doc="x̂"),
    )
    residual_signals: ClassVar[tuple[str, ...]] = ("innovation",)

    def __init__(self, name: str, params: dict[str, Any], rng: np.random.Generator) -> None:
        self.window = MeanWindow(10.0)
        super().__init__(name, params, rng)
        self.model: Any = None  # LtiModel once the model input has arrived
        self.x: np.ndarray | None = None
        self.u: np.ndarray | None = None
        self.quiet_until = -math.inf
        self._pending_settle = False
        self._dt: float | None = None
        self.signals = {k: math.nan for k in self.residual_signals}

    def configure(self) -> None:
        p = self.params
        self.window.window_s = float(p["innovation_window_s"])
        self.settle_s = float(p["settle_s"])
        rows = p["measured_outputs"]
        self.rows = None if rows is None else [int(r) for r in np.atleast_1d(rows)]
        self._dt = None  # rebuild the discrete matrices

    def _h(self) -> np.ndarray:
        C = self.model.C
        return C if self.rows is None else C[self.rows, :]

    def _begin(self, t: float, z: np.ndarray) -> None:
        x0 = self.params["x0"]
        self.x = vector(x0) if x0 is not None else np.linalg.pinv(self._h()) @ z
        self.quiet_until = t + self.settle_s

    def _monitor(self, t: float, nu: np.ndarray, nis: float | None = None) -> None:
        if t < self.quiet_until:
            return
        self.window.add(t, nu if nis is None else np.append(nu, nis))
        mean = self.window.value()
        if mean is None:
            return
        k = nu.size
        self.signals["innovation"] = float(np.linalg.norm(mean[:k]))
        if nis is not None:
            self.signals["nis"] = float(mean[k])

    def _inputs(self, t: float, dt: float, inputs: dict[str, Any]) -> np.ndarray | None:
        """The measurement, after taking the model and u; None when nothing can be done."""
        m = inputs.get("model")
        if m is not None and m is not self.model:
            self.model = m
            self._dt = None
        u = as_vector(inputs.get("u"))
        if u is not None:
            self.u = u
        elif self.u is None and self.model is not None:
            self.u = np.zeros(self.model.m)
        if self._pending_settle:
            self.quiet_until = t + self.settle_s
            self._pending_settle = False
        return as_vector(inputs.get("measurement"))

    def _out(self) -> dict[str, Any]:
        if self.x is None or self.model is None:
            return {"estimate": None, "state": None}
        return {"estimate": self.model.C @ self.x, "state": self.x.copy()}

    def export_state(self) -> dict[str, Any]:
        return {} if self.x is None else {"state": self.x.copy()}

    def import_state(self, state: dict[str, Any]) -> None:
        x = state.get("state")
        if x is not None:
            self.x = vector(x)
            self._reset_covariance()
        self.window.clear()
        self._pending_settle = True
        for k in self.signals:
            self.signals[k] = math.nan

    def _reset_covariance(self) -> None:
        """A hand-over restarts the uncertainty (Kalman filter)."""

    def _linear_model_of(self, inputs: Any) -> LtiModel | None:
        """The model the filter runs on: its own, else the one its ``model`` input carries."""
        if self.model is not None:
            return self.model
        for pt in inputs.get("model") or ():
            if isinstance(pt.value, LtiModel):
                return pt.value
        return None

    def _filter_model(self, dt: float, model: LtiModel, G: np.ndarray, Bu: np.ndarray,
                      K: np.ndarray, extra: int = 0) -> LinearModel:
        """``x̂_k = G s + Bu u_k + K z_k`` with the state ``s = x̂_{k−1}``.

        Outputs ``estimate = C x̂_k`` and ``state = x̂_k``.

        ``extra`` trailing states hold the previous measurement (the observer's).
        """
        n, k, m, p = model.n, K.shape[1], model.m, model.C.shape[0]
        size = n + extra
        A = np.zeros((size, size))
        A[:n, :] = G
        B = np.zeros((size, m + k))
        B[:n, :m], B[:n, m:] = Bu, K
        if extra:
            B[n:, m:] = np.eye(k)
        Cx, Dx = A[:n, :], B[:n, :]  # x̂_k as a function of (s, u, z)
        C = np.vstack([model.C @ Cx, Cx])
        D = np.vstack([model.C @ Dx, Dx])
        states = [f"x_hat{i}" for i in range(n)] + [f"z_prev{i}" for i in range(extra)]
        return LinearModel(A, B, C, D, [("u", m), ("measurement", k)],
                           [("estimate", p), ("state", n)], dt, states)


def _cov(x: Any, n: int) -> np.ndarray:
    """A covariance from a number (times I), a flat list (the diagonal) or a matrix."""
    return as_matrix(x, rows=n, cols=None if np.ndim(x) == 0 else n)


# ----------------------------------------------------------------- the Kalman maths, once
# filterpy's predict and Joseph-form update (KalmanFilter; ExtendedKalmanFilter with the
# linear h of the augmented filter) on one filter's vector and matrices (the per-run
# classes below) or on stacks of L (their lane classes in lanes_estimators and
# lanes_observers): the same numpy calls, so a lane is its run; filterpy stays the
# tests' oracle (tests/test_blocks.py) and a run imports none of it.


def _t(a: np.ndarray) -> np.ndarray:
    """The (stacked) transposes."""
    return a.swapaxes(-1, -2)


def predict(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray,
            Bu: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """``x⁺ = F x + B u`` and ``P⁺ = F P Fᵀ + Q`` (filterpy's ``predict``).

    Parameters
    ----------
    x : (n,) or (L, n) array
    P, F, Q : (n, n) or (L, n, n) arrays
    Bu : array shaped as x, or 0
        The input's part ``B u`` (0: filterpy's ``B = 0``, which adds an exact 0).

    Examples
    --------
    >>> x, P = predict(np.array([[1.0]]), np.array([[[2.0]]]), np.array([[[0.5]]]),
    ...                np.array([[[0.1]]]), np.array([[3.0]]))
    >>> x.tolist(), P.tolist()
    ([[3.5]], [[[0.6]]])
    """
    return matvec(F, x) + Bu, (F @ P) @ _t(F) + Q


def update(x: np.ndarray, P: np.ndarray, nu: np.ndarray, H: np.ndarray, R: np.ndarray,
           inv: Callable[[np.ndarray], Any]
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[int, Exception]]:
    """filterpy's ``update`` in Joseph form, with innovation ``nu = z − H x``.

    ``K = P Hᵀ S⁻¹`` with ``S = H P Hᵀ + R``, ``x + K ν`` and
    ``(I − K H) P (I − K H)ᵀ + K R Kᵀ``. ``inv`` is the filter's inverse (filterpy's
    ``KalmanFilter``: ``numpy.linalg.inv``; its ``ExtendedKalmanFilter``:
    ``scipy.linalg.inv``), batched where it can be, else matrix by matrix. Shapes
    as :func:`predict`'s: one filter, or a stack of L.

    Returns
    -------
    x, P : arrays
        Updated (a stack's row whose ``S`` could not be inverted: ``x`` as given).
    S : (k, k) or (L, k, k) array
        The innovation covariance(s).
    errors : dict
        Stack row -> the exception ``inv`` raised for it (one filter: it is raised).

    Examples
    --------
    >>> x, P, S, errors = update(np.array([[0.0]]), np.array([[[1.0]]]), np.array([[2.0]]),
    ...                          np.array([[[1.0]]]), np.array([[[1.0]]]), np.linalg.inv)
    >>> x.tolist(), P.tolist(), S.tolist(), errors
    ([[1.0]], [[[0.5]]], [[[2.0]]], {})
    """
    PHT = P @ _t(H)
    S = H @ PHT + R
    errors: dict[int, Exception] = {}
    try:
        SI = inv(S)
        if SI.shape != S.shape:
            raise ValueError("not batched")
    except (ValueError, np.linalg.LinAlgError):  # one by one
        if S.ndim == 2:
            raise
        SI = np.zeros_like(S)
        for j in range(len(S)):
            try:
                SI[j] = inv(S[j])
            except (ValueError, np.linalg.LinAlgError) as exc:
                errors[j] = exc
    K = PHT @ SI
    n = P.shape[-1]
    eye = _EYE.get(n)
    if eye is None:
        eye = _EYE[n] = np.eye(n)
    I_KH = eye - K @ H
    return (x + matvec(K, nu), (I_KH @ P) @ _t(I_KH) + (K @ R) @ _t(K), S, errors)


def nis(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """The normalized innovation squared ``νᵀ S⁻¹ ν`` (a number, or ``(L,)`` for a stack).

    Examples
    --------
    >>> nis(np.array([[2.0]]), np.array([[[4.0]]])).tolist()
    [1.0]
    >>> float(nis(np.array([2.0]), np.array([[4.0]])))
    1.0
    """
    return (nu[..., None, :] @ np.linalg.solve(S, nu[..., None]))[..., 0, 0]


class KalmanFilter(_ModelEstimator):
    """Linear Kalman filter on an LTI model (filterpy's ``KalmanFilter``'s formulas,
    the Kalman maths above, shared with its lane class).

    A continuous model is discretized at the run's step (zero-order hold) and the
    process noise intensity ``Q`` becomes ``Q·dt`` per step; a discrete model's
    period must be the run's step and ``Q`` is per step. Each step predicts with the
    applied input ``u`` (the plant's ``u`` output: the input of the step that just
    ended), then updates with the measurement (rows ``measured_outputs`` of C; ``R``
    its covariance). A number for ``Q``, ``R`` or ``P0`` means that times the
    identity, a flat list the diagonal.

    Residual signals ``innovation`` and ``nis`` (see the module's docstring). The
    filter's matrices ``F``, ``B``, ``H``, ``Q``, ``R`` and covariance ``P`` are
    attributes (``P`` None until the first model arrived).
    """

    # P follows its own Riccati map; quiet_until is a timer
    state_fields: ClassVar[tuple[str, ...] | None] = ("x",)

    parameters = {
        "Q": Param(1.0, "", "process noise intensity (per s continuous, per step discrete)"),
        "R": Param(1.0, "", "measurement noise covariance"),
        "P0": Param(1.0, "", "initial covariance"),
        **_COMMON,
    }
    residual_signals: ClassVar[tuple[str, ...]] = ("innovation", "nis")
    lanes = "archself_blocks.lanes_estimators:KalmanFilterLanes"

    def __init__(self, name: str, params: dict[str, Any], rng: np.random.Generator) -> None:
        self.P: np.ndarray | None = None
        super().__init__(name, params, rng)

    def _matrices(self, dt: float) -> None:
        m = self.model
        n, k = m.n, self._h().shape[0]
        self.F, self.B = m.discrete(dt)
        q = _cov(self.params["Q"], n)
        self.Q = q * dt if m.dt == 0 else q
        self.H = self._h()
        self.R = _cov(self.params["R"], k)
        if self.P is None or self.P.shape != (n, n):
            self.P = self._p0()
        self._dt = dt

    def _p0(self) -> np.ndarray:
        return _cov(self.params["P0"], self.model.n)

    def _reset_covariance(self) -> None:
        if self.P is not None and self.model is not None:
            self.P = self._p0()

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        z = self._inputs(t, dt, inputs)
        if self.model is None:
            return self._out()
        if self._dt != dt:
            self._matrices(dt)
        if self.x is None:
            if z is not None:
                self._begin(t, z)
            return self._out()
        assert self.P is not None and self.u is not None  # (_matrices, _inputs: a model came)
        x, P = predict(self.x, self.P, self.F, self.Q, matvec(self.B, self.u))
        self._correct(t, z, x, P, self.H, np.linalg.inv)
        return self._out()

    def _correct(self, t: float, z: np.ndarray | None, x: np.ndarray, P: np.ndarray,
                 H: np.ndarray, inv: Any) -> np.ndarray:
        """Update the predicted ``x``, ``P`` with ``z`` (if any) and keep the result; the
        full state. An ``S`` that ``inv`` cannot invert raises, the estimate kept and
        the covariance predicted (as filterpy's filter)."""
        self.P = P
        if z is not None:
            nu = z - matvec(H, x)
            x, self.P, S, _ = update(x, P, nu, H, self.R, inv)
            self._monitor(t, nu, float(nis(nu, S)))
        self.x = x[: self.model.n]
        return x

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        """One predict-update step with the current gain.

        ``x̂_k = (I − K H)(F x̂_{k−1} + B u_k) + K z_k`` with
        ``K = P⁻ Hᵀ (H P⁻ Hᵀ + R)⁻¹`` and ``P⁻ = F P Fᵀ + Q`` from the filter's
        covariance now (``P0`` before its first step). None without a model, or for a
        discrete model whose period is not the step.
        """
        model = self._linear_model_of(inputs)
        if model is None or (model.dt > 0 and abs(model.dt - dt) > 1e-9 * max(1.0, dt)):
            return None
        saved = self.model
        self.model = model
        try:
            H = self._h()
            F, Bd = model.discrete(dt)
            n = model.n
            q = _cov(self.params["Q"], n) * (dt if model.dt == 0 else 1.0)
            P = self.P if self.P is not None and self.P.shape == (n, n) else self._p0()
            R = _cov(self.params["R"], H.shape[0])
        finally:
            self.model = saved
        Pm = F @ P @ F.T + q
        K = Pm @ H.T @ np.linalg.inv(H @ Pm @ H.T + R)
        IKH = np.eye(n) - K @ H
        return self._filter_model(dt, model, IKH @ F, IKH @ Bd, K)

    def linearization(self) -> np.ndarray | None:
        """Error dynamics ``(I − K H) F`` of the filter as a continuous equivalent."""
        if self.P is None or self._dt is None:
            return None
        k = self.P @ self.H.T @ np.linalg.inv(self.H @ self.P @ self.H.T + self.R)
        err = (np.eye(self.F.shape[0]) - k @ self.H) @ self.F
        return continuous_equivalent(err, self._dt)


class AugmentedEkf(KalmanFilter):
    """Extended Kalman filter (filterpy's ``ExtendedKalmanFilter``'s formulas,
    the Kalman maths above) that also estimates the effectiveness of each plant
    input and the bias of each measured output.

    The state is augmented with η (one effectiveness per input, start 1, random walk of
    intensity ``effectiveness_noise``) and b (one bias per measured output, start 0,
    ``bias_noise``), each part switched on by ``estimate_effectiveness`` /
    ``estimate_bias``::

        x⁺ = Ad x + Bd (η ∘ u),   η⁺ = η,   b⁺ = b,   z = H x + b

    The product η ∘ u makes the model nonlinear in the augmented state; its Jacobian
    ``[[Ad, Bd diag(u), 0], [0, I, 0], [0, 0, I]]`` is exact for the given u. With
    varying inputs η and b are distinguishable; at a constant input they trade off
    against each other, so switch on only the one the application needs.

    ``Q``, ``R``, ``P0`` are those of the plant states (as :class:`KalmanFilter`).
    Outputs ``estimate`` and ``state`` (the plant's part) and ``parameters`` (η then b).
    Residual signals ``innovation``, ``nis``, ``effectiveness_loss`` = max_j (1 − η̂_j)⁺
    (an actuator that lost effectiveness, seen from the estimator) and ``bias`` = max |b̂|.
    """

    state_fields = ("x", "aug")

    parameters = {
        **KalmanFilter.parameters,
        "estimate_effectiveness": Param(True, "", "augment the state with η per input"),
        "effectiveness_noise": Param(1e-3, "1/s", "random-walk intensity of η", min=0.0),
        "effectiveness_p0": Param(0.01, "", "initial variance of η", min=0.0),
        "estimate_bias": Param(False, "", "augment the state with a bias per measured output"),
        "bias_noise": Param(1e-4, "", "random-walk intensity of b (units²/s)", min=0.0),
        "bias_p0": Param(1.0, "", "initial variance of b (units²)", min=0.0),
    }
    ports = (*_ModelEstimator.ports, Output("parameters", doc="η̂ per input, then b̂"))
    residual_signals: ClassVar[tuple[str, ...]] = (
        "innovation", "nis", "effectiveness_loss", "bias",
    )
    lanes = "archself_blocks.lanes_observers:AugmentedEkfLanes"

    def __init__(self, name: str, params: dict[str, Any], rng: np.random.Generator) -> None:
        super().__init__(name, params, rng)
        self.aug: np.ndarray | None = None  # [η, b]

    def _sizes(self) -> tuple[int, int, int]:
        m = self.model
        ne = m.m if self.params["estimate_effectiveness"] else 0
        nb = self._h().shape[0] if self.params["estimate_bias"] else 0
        return m.n, ne, nb

    def _p0(self) -> np.ndarray:
        n, ne, nb = self._sizes()
        p = np.zeros((n + ne + nb,) * 2)
        p[:n, :n] = _cov(self.params["P0"], n)
        p[n:n + ne, n:n + ne] = float(self.params["effectiveness_p0"]) * np.eye(ne)
        p[n + ne:, n + ne:] = float(self.params["bias_p0"]) * np.eye(nb)
        return p

    def _matrices(self, dt: float) -> None:
        import scipy.linalg  # filterpy's EKF inverse (it raises on a non-finite S)

        self._inv = scipy.linalg.inv
        m = self.model
        n, ne, nb = self._sizes()
        k = self._h().shape[0]
        self._ad, self._bd = m.discrete(dt)
        scale = dt if m.dt == 0 else 1.0
        q = np.zeros((n + ne + nb,) * 2)
        q[:n, :n] = _cov(self.params["Q"], n) * scale
        q[n:n + ne, n:n + ne] = float(self.params["effectiveness_noise"]) * scale * np.eye(ne)
        q[n + ne:, n + ne:] = float(self.params["bias_noise"]) * scale * np.eye(nb)
        h = np.zeros((k, n + ne + nb))
        h[:, :n] = self._h()
        h[:, n + ne:] = np.eye(k)[:, :nb] if nb else 0.0
        self.Q, self.R = q, _cov(self.params["R"], k)
        if self.P is None or self.P.shape != q.shape:
            self.P = self._p0()
        self._haug, self._dt = h, dt
        if self.aug is None or self.aug.size != ne + nb:
            self.aug = np.concatenate([np.ones(ne), np.zeros(nb)])

    def _jacobian(self, u: np.ndarray) -> np.ndarray:
        n, ne, nb = self._sizes()
        f = np.eye(n + ne + nb)
        f[:n, :n] = self._ad
        if ne:
            f[:n, n:n + ne] = self._bd * u  # Bd diag(u)
        return f

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        z = self._inputs(t, dt, inputs)
        if self.model is None:
            return self._out()
        if self._dt != dt:
            self._matrices(dt)
        n, ne, nb = self._sizes()
        if self.x is None:
            if z is not None:
                self._begin(t, z)
            return self._out()
        u = self.u if self.u is not None else np.zeros(self.model.m)
        assert self.P is not None  # (_matrices)
        xa = np.concatenate([self.x, self.aug])
        f = self._jacobian(u)
        if not ne:  # η ≡ 1 is not a state: the input enters as in the linear filter
            B = np.vstack([self._bd, np.zeros((nb, self.model.m))])
            xa, P = predict(xa, self.P, f, self.Q, matvec(B, u))
        else:  # exact: f(x, η) = F·[x, η, b] for this u (B = 0)
            xa, P = predict(xa, self.P, f, self.Q, 0)
        self.aug = self._correct(t, z, xa, P, self._haug, self._inv)[n:]
        if t >= self.quiet_until:
            eta, b = self.aug[:ne], self.aug[ne:]
            self.signals["effectiveness_loss"] = float(max(0.0, *(1.0 - eta))) if ne else 0.0
            self.signals["bias"] = float(np.abs(b).max()) if nb else 0.0
        return self._out()

    def _out(self) -> dict[str, Any]:
        out = super()._out()
        out["parameters"] = None if self.aug is None else self.aug.copy()
        return out

    def linearization(self) -> np.ndarray | None:
        """None: with η in the state the error dynamics depend on the input u."""
        return None

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        """None: the augmented filter is not linear in its state (η multiplies u)."""
        return None

    def export_state(self) -> dict[str, Any]:
        out = super().export_state()
        if self.aug is not None:
            out["parameters"] = self.aug.copy()
        return out


def observer_gain(model: LtiModel, poles: Any, rows: list[int] | None = None) -> np.ndarray:
    """Luenberger gain L with eig(A − L C) at ``poles`` (``control.place`` on the dual).

    Poles are numbers, or ``[re, im]`` pairs for a complex pair (give each once).

    Examples
    --------
    >>> m = LtiModel([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], [[1.0, 0.0]])
    >>> observer_gain(m, [-2.0, -3.0]).round(6).tolist()
    [[5.0], [6.0]]
    """
    C = model.C if rows is None else model.C[rows, :]
    wanted: list[complex] = []
    for p in poles:
        if isinstance(p, (list, tuple)):
            re, im = float(p[0]), float(p[1])
            wanted += [complex(re, im), complex(re, -im)]
        else:
            wanted.append(float(p))
    return np.array(designs.place(model.A.T, C.T, wanted)).T


class Luenberger(_ModelEstimator):
    """Luenberger observer ``dx̂/dt = A x̂ + B u + L (y − C x̂)`` on an LTI model.

    ``L`` is given (``gain``, n × measured outputs) or placed (``poles``: eig(A − L C),
    ``control.place``). A continuous observer is integrated exactly over each step
    (zero-order hold of u and y, ``control.c2d``); on a discrete model it is
    ``x̂⁺ = A x̂ + B u + L (y − C x̂)``. ``linearization()`` gives the error dynamics
    ``A − L C`` (the separation principle: the closed loop's poles are the
    controller's and these). Residual signal ``innovation``.
    """

    state_fields = ("x", "_y")  # _y: the last measurement, used over the next step

    parameters = {
        "gain": Param(None, "", "L (n × measured outputs); None: from poles"),
        "poles": Param(None, "1/s", "observer poles (numbers, or [re, im] pairs)"),
        **_COMMON,
    }
    lanes = "archself_blocks.lanes_observers:LuenbergerLanes"

    def configure(self) -> None:
        super().configure()
        if (self.params["gain"] is None) == (self.params["poles"] is None):
            raise ValueError("give exactly one of gain and poles")
        self._y: np.ndarray | None = None
        self._L: np.ndarray | None = None

    def gain(self) -> np.ndarray:
        """L (computed once per model)."""
        if self._L is None:
            g = self.params["gain"]
            if g is not None:
                L = as_matrix(g)
                if L.shape[0] != self.model.n and L.size == self.model.n:
                    L = L.reshape(self.model.n, -1)
                self._L = L
            else:
                self._L = observer_gain(self.model, self.params["poles"], self.rows)
        return self._L

    def _matrices(self, dt: float) -> None:
        m = self.model
        L = self.gain()
        H = self._h()
        ao, bo = m.A - L @ H, np.hstack([m.B, L])
        if m.dt == 0:
            self._ad, self._bd = designs.zoh(ao, bo, np.eye(m.n),
                                             np.zeros((m.n, bo.shape[1])), dt)
        else:
            self._ad, self._bd = ao, bo
        self._dt = dt

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        z = self._inputs(t, dt, inputs)
        if self.model is None:
            return self._out()
        if self._dt != dt:
            self._L = None if self.params["gain"] is None else self._L
            self._matrices(dt)
        if self.x is None:
            if z is None:
                return self._out()
            self._begin(t, z)
            self._y = z
            return self._out()
        if self._y is not None:  # propagate over the step that ended, with its u and y
            self.x = self._ad @ self.x + self._bd @ np.concatenate([self.u, self._y])
        if z is not None:
            nu = z - self._h() @ self.x
            self._monitor(t, nu)
            self._y = z
        return self._out()

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        """One step: ``x̂_k = Ad x̂_{k−1} + Bd_u u_k + Bd_y z_{k−1}`` (the measurement of
        the step before is a state), with the observer's ``(Ad, Bd)`` at the step."""
        model = self._linear_model_of(inputs)
        if model is None or (model.dt > 0 and abs(model.dt - dt) > 1e-9 * max(1.0, dt)):
            return None
        probe = copy.copy(self)  # the matrices are a cache; compute them on a copy
        probe.model = model
        if probe._dt != dt or self.model is not model:
            probe._L = None if self.params["gain"] is None else self._L
            probe._matrices(dt)
        n, m = model.n, model.m
        ad, bd = probe._ad, probe._bd
        k = bd.shape[1] - m
        G = np.hstack([ad, bd[:, m:]])
        return self._filter_model(dt, model, G, bd[:, :m], np.zeros((n, k)), extra=k)

    def linearization(self) -> np.ndarray | None:
        if self.model is None:
            return None
        err = self.model.A - self.gain() @ self._h()
        return err if self.model.dt == 0 else continuous_equivalent(err, self.model.dt)
