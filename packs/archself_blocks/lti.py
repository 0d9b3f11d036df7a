"""Linear time-invariant blocks: state-space and transfer-function plants, the LTI model node.

The model is written once as matrices (or a numerator/denominator) in the file;
python-control converts and discretizes it (``control.ss``, ``control.tf``,
``control.c2d`` with a zero-order hold) when the block first runs, never at
import time, so ``archself validate`` stays light; both go through the design cache
(:mod:`archself.linear.designs`), so a warm run imports neither python-control nor scipy.

Signal vocabulary of the block library (edges name signals by ``carries``):

===============  ================================================================
``u``            a plant's input (what actuators deliver); a plant also publishes
                 the input it applied during the last step under ``u``
``y``            a plant's output ``C x + D u`` (always a vector)
``state``        a plant's state ``x`` or an estimator's ``x̂`` (vector)
``measurement``  a sensor's reading (scalar)
``estimate``     an estimator's output estimate ``C x̂`` (vector)
``reference``    a reference generator's ``[r, dr/dt]``
``command``      a controller's output (scalar)
``model``        an :class:`LtiModel` published by ``generic.lti_model``
===============  ================================================================

Examples
--------
>>> import numpy as np
>>> p = StateSpacePlant("p", {"A": [[-1.0]], "B": [[1.0]]}, np.random.default_rng(0))
>>> for k in range(100):
...     _ = p.step(0.01 * k, 0.01, {"u": [1.0]})
>>> round(float(p.output(1.0)["y"][0]), 6)  # 1 − e^(−1)
0.632121
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.linear import designs
from archself.model.architecture import Input, Output
from archself.modules.base import LinearModel, Param, RuntimeModule

__all__ = [
    "LtiModel",
    "StateSpacePlant",
    "TransferFunctionPlant",
    "LtiModelNode",
    "as_matrix",
    "as_vector",
    "vector",
    "continuous_equivalent",
    "matvec",
]


def as_vector(x: Any) -> np.ndarray | None:
    """A float vector from a number, a list or an array; None stays None.

    Examples
    --------
    >>> as_vector(2), as_vector([1, 2]), as_vector(None)
    (array([2.]), array([1., 2.]), None)
    """
    if x is None:
        return None
    return vector(x)


def vector(x: Any) -> np.ndarray:
    """A float vector from a number, a list or an array (not None)."""
    return np.atleast_1d(np.asarray(x, dtype=float)).ravel()


def as_matrix(x: Any, rows: int | None = None, cols: int | None = None) -> np.ndarray:
    """A 2-D float matrix from a number, a list of lists or a flat list.

    A number is a 1×1 matrix, or ``x·I`` when ``rows`` is given and ``cols`` is not;
    a flat list is a row, or the diagonal when ``rows == cols == len(x)``
    and ``cols`` is given.

    Examples
    --------
    >>> as_matrix(2.0).tolist(), as_matrix(0.5, rows=2).tolist()
    ([[2.0]], [[0.5, 0.0], [0.0, 0.5]])
    >>> as_matrix([1, 2], rows=2, cols=2).tolist()
    [[1.0, 0.0], [0.0, 2.0]]
    """
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        if rows is not None and cols is None:
            return float(a) * np.eye(rows)
        return a.reshape(1, 1)
    if a.ndim == 1:
        if rows is not None and cols is not None and rows == cols == a.size and rows > 1:
            return np.diag(a)
        return a.reshape(1, -1)
    return a


def continuous_equivalent(Ad: np.ndarray, dt: float) -> np.ndarray:
    """A real matrix whose eigenvalues' real parts are ``ln|λ_i(Ad)| / dt``.

    The stability filter tests max Re λ(A) ≤ −ε of a continuous-time A (Eq. 21); a
    discrete-time block hands it this equivalent of its own dynamics (a pole on
    the unit circle maps to 0, one inside to a negative number).

    Examples
    --------
    >>> continuous_equivalent(np.array([[0.5]]), 0.1).round(4).tolist()
    [[-6.9315]]
    """
    lam = np.linalg.eigvals(np.atleast_2d(Ad))
    with np.errstate(divide="ignore"):
        re = np.log(np.maximum(np.abs(lam), 1e-300)) / dt
    return np.diag(re)


def matvec(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``A[i] @ x[i]`` for every lane: ``(L, p, n)`` by ``(L, n)`` gives ``(L, p)``
    (and ``(p, n)`` by ``(n,)`` gives ``(p,)``).

    Examples
    --------
    >>> matvec(np.array([[[1.0, 2.0]], [[0.0, 1.0]]]), np.array([[1.0, 1.0], [3.0, 4.0]]))
    array([[3.],
           [4.]])
    """
    return np.matmul(A, x[..., None])[..., 0]


class LtiModel:
    """``ẋ = A x + B u, y = C x + D u`` (``dt = 0``) or ``x⁺ = A x + B u`` (period ``dt``).

    Parameters
    ----------
    A, B, C, D : array_like
        The matrices; C defaults to the identity, D to zeros.
    dt : float
        0 for continuous time, else the sample time (s).

    Examples
    --------
    >>> m = LtiModel([[-1.0]], [[1.0]])
    >>> Ad, Bd = m.discrete(0.1)
    >>> round(float(Ad[0, 0]), 6), round(float(Bd[0, 0]), 6)
    (0.904837, 0.095163)
    """

    def __init__(self, A: Any, B: Any, C: Any = None, D: Any = None, dt: float = 0.0) -> None:
        A = as_matrix(A)
        n = A.shape[0]
        if A.shape != (n, n):
            raise ValueError(f"A must be square, got {A.shape}")
        B = as_matrix(B)
        if B.shape[0] != n and B.size == n:
            B = B.reshape(n, 1)
        C = np.eye(n) if C is None else as_matrix(C)
        # the culprit first: validate locates the finding at the parameter named first
        if B.shape[0] != n:
            raise ValueError(f"B has {B.shape[0]} rows, expected {n} (the states of A "
                             f"{n}×{n}); shapes: A {A.shape}, B {B.shape}, C {C.shape}")
        if C.shape[1] != n:
            raise ValueError(f"C has {C.shape[1]} columns, expected {n} (the states of A "
                             f"{n}×{n}); shapes: A {A.shape}, B {B.shape}, C {C.shape}")
        D = np.zeros((C.shape[0], B.shape[1])) if D is None else as_matrix(D)
        if D.shape != (C.shape[0], B.shape[1]):
            raise ValueError(f"D must be {C.shape[0]}×{B.shape[1]}, got {D.shape}")
        self.A, self.B, self.C, self.D = A, B, C, D
        self.dt = float(dt)
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def n(self) -> int:
        """Number of states."""
        return self.A.shape[0]

    @property
    def m(self) -> int:
        """Number of inputs."""
        return self.B.shape[1]

    @property
    def p(self) -> int:
        """Number of outputs."""
        return self.C.shape[0]

    @classmethod
    def from_tf(cls, num: Any, den: Any, dt: float = 0.0) -> LtiModel:
        """A SISO model from a transfer function (``control.tf`` → ``control.ss``).

        Examples
        --------
        >>> m = LtiModel.from_tf([2.0], [1.0, 1.0])
        >>> m.n, round(float((m.C @ np.linalg.solve(-m.A, m.B) + m.D)[0, 0]), 6)  # DC gain
        (1, 2.0)
        """
        m = designs.tf2ss(num, den, dt or 0.0)
        return cls(np.array(m["A"]), np.array(m["B"]), np.array(m["C"]), np.array(m["D"]), dt)

    def discrete(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(Ad, Bd)`` for a step ``dt``: zero-order hold (``control.c2d``) of a
        continuous model; a discrete model's own matrices (its period must be ``dt``)."""
        if self.dt > 0:
            return self.A, self.B
        hit = self._cache.get(dt)
        if hit is None:
            hit = self._cache[dt] = designs.zoh(self.A, self.B, self.C, self.D, dt)
        return hit

    def continuous_a(self) -> np.ndarray:
        """A of a continuous model; for a discrete one :func:`continuous_equivalent`."""
        return self.A if self.dt == 0 else continuous_equivalent(self.A, self.dt)

    def __repr__(self) -> str:
        kind = "continuous" if self.dt == 0 else f"dt={self.dt:g}"
        return f"LtiModel(n={self.n}, m={self.m}, p={self.p}, {kind})"


def _model_params(tf: bool) -> dict[str, Param]:
    if tf:
        return {
            "num": Param(doc="numerator coefficients, highest power first", unit=""),
            "den": Param(doc="denominator coefficients, highest power first", unit=""),
            "sample_time_s": Param(
                0.0, "s", "0: continuous (ZOH at the step); else the period", min=0.0, max=3600.0,
                period=True,
            ),
        }
    return {
        "A": Param(doc="state matrix (n×n)", unit=""),
        "B": Param(doc="input matrix (n×m)", unit=""),
        "C": Param(None, "", "output matrix (p×n); None: the identity"),
        "D": Param(None, "", "feedthrough matrix (p×m); None: zeros"),
        "sample_time_s": Param(
            0.0, "s", "0: continuous (ZOH at the step); else the period", min=0.0, max=3600.0,
            period=True,
        ),
    }


def _build_model(params: dict[str, Any]) -> LtiModel:
    dt = float(params.get("sample_time_s") or 0.0)
    if dt < 0:
        raise ValueError("sample_time_s must be ≥ 0")
    if "num" in params:
        return LtiModel.from_tf(params["num"], params["den"], dt)
    return LtiModel(params["A"], params["B"], params.get("C"), params.get("D"), dt)


class StateSpacePlant(RuntimeModule):
    """An LTI plant ``ẋ = A x + B u + w``, ``y = C x + D u`` (or its discrete form).

    A continuous model is discretized exactly (zero-order hold) at the run's step; a
    discrete one (``sample_time_s`` > 0) samples ``u`` at the start of each period,
    updates at its end and holds its output in between. ``u`` may arrive over
    several edges (two heaters heating one zone): the values are summed; each is
    a number (for a plant with one input) or an m-vector. No ``u`` at all this step means ``u = 0``.
    ``process_noise`` adds white noise to the state (standard deviation per √s for
    a continuous model, per period for a discrete one; one number or one per state).

    Outputs ``y`` (C x + D u with the last applied u; a vector), ``state`` (x) and
    ``u`` (the input applied during the last step, as a meter on the input line
    sees it). No direct feedthrough: it breaks feedback loops.

    Its ``linearization()`` is None: the plant enters the closed-loop A of a
    configuration through :meth:`linear_model`, wired to the actuators, sensors,
    estimators and controllers around it; :meth:`state_space` gives (A, B, C, D).
    """

    state_fields = ("x", "u")  # u: the held input its output publishes

    parameters = {
        **_model_params(False),
        "x0": Param(None, "", "initial state; None: zeros"),
        "process_noise": Param(
            0.0, "", "state noise std (per √s continuous, per period discrete)", min=0.0
        ),
    }
    role = "plant"
    ports = (
        Input("u", doc="the input; several edges are summed", required=False, multi=True),
        Output("y", doc="C x + D u, always a vector"),
        Output("state", doc="x"),
        Output("u", doc="the input it applied during the last step"),
    )
    direct_feedthrough = False
    lanes = "archself_blocks.lanes_plants:StateSpacePlantLanes"

    def __init__(self, name: str, params: dict[str, Any], rng: np.random.Generator) -> None:
        super().__init__(name, params, rng)
        x0 = self.params["x0"]
        self.x = np.zeros(self.model.n) if x0 is None else vector(x0)
        if self.x.size != self.model.n:
            raise ValueError(f"x0 has {self.x.size} entries, the model {self.model.n} states")
        self.u = np.zeros(self.model.m)
        self._u_sample = self.u
        self._acc = 0.0

    def configure(self) -> None:
        self.model = _build_model(self.params)
        noise = self.params["process_noise"]
        self.noise = np.broadcast_to(vector(noise or 0.0), (self.model.n,)).copy()

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C, D) of the model (continuous, or discrete with its period)."""
        m = self.model
        return m.A, m.B, m.C, m.D

    def output(self, t: float) -> dict[str, Any]:
        m = self.model
        return {"y": m.C @ self.x + m.D @ self.u, "state": self.x.copy(), "u": self.u.copy()}

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        """The plant as the executor runs it, with the state ``[x; u_prev]``.

        ``x⁺ = Ad x + Bd u`` and ``u_prev⁺ = u``;
        ``y = C x + D u_prev``, ``state = x`` and ``u = u_prev`` (the input of the step
        that ended); a continuous model is held over the step (zero-order hold). None
        for a discrete model whose period is not the step.
        """
        m = self.model
        if m.dt > 0 and abs(m.dt - dt) > 1e-9 * max(1.0, dt):
            return None
        Ad, Bd = m.discrete(dt)
        n, k, p = m.n, m.m, m.p
        A = np.zeros((n + k, n + k))
        A[:n, :n] = Ad
        B = np.vstack([Bd, np.eye(k)])
        C = np.zeros((p + n + k, n + k))
        C[:p, :n], C[:p, n:] = m.C, m.D
        C[p : p + n, :n] = np.eye(n)
        C[p + n :, n:] = np.eye(k)
        states = [f"x{i}" for i in range(n)] + [f"u_prev{i}" for i in range(k)]
        return LinearModel(A, B, C, np.zeros((p + n + k, k)), [("u", k)],
                           [("y", p), ("state", n), ("u", k)], dt, states)

    def _input(self, inputs: dict[str, Any]) -> np.ndarray:
        total = np.zeros(self.model.m)
        for v in inputs.get("u") or ():
            vec = as_vector(v)
            if vec is None or not np.all(np.isfinite(vec)):
                continue
            if vec.size != total.size:
                raise ValueError(f"u has {vec.size} entries, the model {total.size} inputs")
            total += vec
        return total

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        u = self._input(inputs)
        m = self.model
        if m.dt > 0:  # discrete: u sampled at the start of a period, x updated at its end
            if self._acc < 1e-9:
                self._u_sample = u
            self._acc += dt
            while self._acc >= m.dt - 1e-9:
                self._acc -= m.dt
                self.x = m.A @ self.x + m.B @ self._u_sample
                if self.noise.any():
                    self.x = self.x + self.noise * self.rng.standard_normal(m.n)
            self.u = u
            return {}
        Ad, Bd = m.discrete(dt)
        self.x = Ad @ self.x + Bd @ u
        if self.noise.any():
            self.x = self.x + self.noise * math.sqrt(dt) * self.rng.standard_normal(m.n)
        self.u = u
        return {}

    def export_state(self) -> dict[str, Any]:
        return {"state": self.x.copy()}

    def import_state(self, state: dict[str, Any]) -> None:
        x = state.get("state")
        if x is not None and np.size(x) == self.model.n:
            self.x = vector(x)


class TransferFunctionPlant(StateSpacePlant):
    """A SISO plant given as a transfer function ``num(s)/den(s)`` (or in z).

    Converted once to a state-space realization (``control.tf`` → ``control.ss``)
    and run as :class:`StateSpacePlant`; ``y`` is a 1-vector.
    """

    parameters = {
        **_model_params(True),
        "x0": Param(None, "", "initial state of the realization; None: zeros"),
        "process_noise": Param(
            0.0, "", "state noise std (per √s continuous, per period discrete)", min=0.0
        ),
    }


class LtiModelNode(RuntimeModule):
    """A model node: publishes an :class:`LtiModel` as ``model``.

    Estimators (``generic.kalman``, ``generic.luenberger``) predict with it, and
    ``generic.pid`` closes its linearization (Eq. 20) over it.
    """

    parameters = _model_params(False)
    role = "model"
    ports = (Output("model", doc="the LtiModel (a model object, not a signal)"),)
    direct_feedthrough = False
    lanes = "archself_blocks.lanes_plants:LtiModelNodeLanes"

    def configure(self) -> None:
        self._out = {"model": _build_model(self.params)}

    def output(self, t: float) -> dict[str, Any]:
        return self._out
