"""``generic.pid``: PID control with anti-windup, feed-forward and a closed-loop linearization."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.model.architecture import Input, Output
from archself.modules.base import LinearModel, Param, RuntimeModule
from archself_blocks.lti import LtiModel, as_vector

__all__ = ["Pid", "pid_closed_loop"]

_ANTI_WINDUP = ("clamp", "back_calculation", "none")


def pid_closed_loop(
    model: LtiModel,
    kp: float,
    ki: float,
    kd: float,
    n: float,
    input_index: int = 0,
    output_index: int = 0,
) -> np.ndarray:
    """Closed-loop A (Eq. 20) of a continuous LTI model under :class:`Pid`, reference held.

    States ``[x, I, x_f]``: the plant's, the integral term (``İ = ki·e``; left out
    when ``ki = 0``) and the derivative filter (``ẋ_f = N (y − x_f)``, derivative on
    the measurement; left out when ``kd = 0``). With ``c`` the fed-back row of C and
    ``b`` the driven column of B::

        u = −kp c x + I − kd N (c x − x_f)

    Examples
    --------
    >>> m = LtiModel([[-1.0]], [[1.0]])
    >>> pid_closed_loop(m, 2.0, 1.0, 0.0, 10.0).tolist()
    [[-3.0, 1.0], [-1.0, 0.0]]
    """
    A, B, C = model.A, model.B, model.C
    nx = A.shape[0]
    b = B[:, [input_index]]
    c = C[[output_index], :]
    blocks = [A - b @ c * (kp + kd * n)]
    extra = []
    if ki != 0:
        extra.append("i")
    if kd != 0:
        extra.append("f")
    size = nx + len(extra)
    out = np.zeros((size, size))
    out[:nx, :nx] = blocks[0]
    k = nx
    for kind in extra:
        if kind == "i":
            out[:nx, k] = b[:, 0]
            out[k, :nx] = -ki * c[0]
        else:
            out[:nx, k] = b[:, 0] * kd * n
            out[k, :nx] = n * c[0]
            out[k, k] = -n
        k += 1
    return out


class Pid(RuntimeModule):
    """PID controller with anti-windup and feed-forward.

    With ``e = r − y``::

        v = u_ff + kp·e + I − kd·N·(y − y_f),   u = clip(v, u_min, u_max)
        u_ff = ff_offset + ff_gain·r + ff_rate_gain·dr/dt

    ``I`` is the integral term (in output units, ``İ = ki·e``); the derivative acts on
    the measurement (no kick on reference steps) through a first-order filter of
    bandwidth ``N`` (``derivative_filter_rad_s``). Anti-windup: ``clamp`` stops
    integrating while the output saturates in the error's direction;
    ``back_calculation`` adds ``(u − v)/tracking_time_s`` to ``İ``; ``none`` lets it wind up.

    Inputs ``reference`` (a number or ``[r, dr/dt]``) and one of ``estimate``
    (component ``feedback_index`` of an estimator's output) or ``measurement``
    (preferred in that order); optional ``model`` (an LTI model, for
    :meth:`linearization`). Output ``command``. Residual signal
    ``tracking_error`` = |e|.

    Examples
    --------
    >>> c = Pid("c", {"kp": 2.0, "ki": 1.0, "u_max": 1.0}, np.random.default_rng(0))
    >>> c.step(0.0, 0.1, {"reference": 1.0, "measurement": 0.0})["command"]
    1.0
    >>> c.integral  # clamped: saturated high with a positive error
    0.0
    """

    state_fields = ("integral", "y_f")

    parameters = {
        "kp": Param(1.0, "", "proportional gain (command units per feedback unit)"),
        "ki": Param(0.0, "1/s", "integral gain (times kp's unit)"),
        "kd": Param(0.0, "s", "derivative gain (times kp's unit)"),
        "derivative_filter_rad_s": Param(
            10.0, "rad/s", "bandwidth N of the derivative filter", min=1e-3, max=1e6
        ),
        "ff_gain": Param(0.0, "", "feed-forward gain on the reference"),
        "ff_rate_gain": Param(0.0, "s", "feed-forward gain on the reference's rate"),
        "ff_offset": Param(0.0, "", "constant feed-forward (operating-point command)"),
        "u_min": Param(None, "", "lower command limit; None: none"),
        "u_max": Param(None, "", "upper command limit; None: none"),
        "anti_windup": Param("clamp", "", "clamp, back_calculation or none"),
        "tracking_time_s": Param(1.0, "s", "back-calculation time constant", min=1e-6, max=1e7),
        "initial_integral": Param(0.0, "", "I at the start (command units)"),
        "feedback_index": Param(
            0, "", "component of estimate/measurement/y that is fed back", min=0, max=100000
        ),
        "reference_index": Param(
            0, "", "component of the reference vector that is r", min=0, max=100000
        ),
        "input_index": Param(
            0, "", "plant input the command drives (for the linearization)", min=0, max=100000
        ),
    }
    role = "controller"
    ports = (
        Input("reference", doc="[r, dr/dt] (component reference_index is r)"),
        Input("estimate", doc="fed back when connected (component feedback_index)",
              required=False),
        Input("measurement", doc="fed back when no estimate is connected", required=False),
        Input("model", doc="an LtiModel, for its closed-loop linearization", required=False),
        Output("command", doc="clip(feed-forward + kp·e + I − D, u_min, u_max)"),
    )
    residual_signals = ("tracking_error",)
    lanes = "archself_blocks.lanes_control:PidLanes"

    def __init__(self, name: str, params: dict[str, Any], rng: np.random.Generator) -> None:
        super().__init__(name, params, rng)
        self.integral = float(self.params["initial_integral"])
        self.y_f: float | None = None
        self.model: LtiModel | None = None
        self.last: float | None = None
        self.signals = {"tracking_error": math.nan}

    def configure(self) -> None:
        p = self.params
        self.kp, self.ki, self.kd = float(p["kp"]), float(p["ki"]), float(p["kd"])
        self.n = float(p["derivative_filter_rad_s"])
        self.ff_gain, self.ff_rate_gain = float(p["ff_gain"]), float(p["ff_rate_gain"])
        self.ff_offset = float(p["ff_offset"])
        self.u_min = -math.inf if p["u_min"] is None else float(p["u_min"])
        self.u_max = math.inf if p["u_max"] is None else float(p["u_max"])
        if self.u_min > self.u_max:
            raise ValueError("u_min > u_max")
        if p["anti_windup"] not in _ANTI_WINDUP:
            raise ValueError(f"anti_windup must be one of {', '.join(_ANTI_WINDUP)}")
        self.mode = p["anti_windup"]
        self.tt = max(float(p["tracking_time_s"]), 1e-9)
        self.fi, self.ri = int(p["feedback_index"]), int(p["reference_index"])
        self.input_index = int(p["input_index"])

    def _feedback(self, inputs: dict[str, Any]) -> float | None:
        for key in ("estimate", "measurement"):
            v = as_vector(inputs.get(key))
            if v is not None:
                return float(v[self.fi if v.size > self.fi else 0])
        return None

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        m = inputs.get("model")
        if m is not None:
            self.model = m
        ref = as_vector(inputs.get("reference"))
        y = self._feedback(inputs)
        if ref is None or y is None:
            return {"command": self.last}
        r = float(ref[self.ri])
        r_rate = float(ref[self.ri + 1]) if ref.size > self.ri + 1 else 0.0
        e = r - y
        self.signals["tracking_error"] = abs(e)
        if self.y_f is None:
            self.y_f = y
        d_term = -self.kd * self.n * (y - self.y_f) if self.kd else 0.0
        self.y_f += (1.0 - math.exp(-self.n * dt)) * (y - self.y_f)
        ff = self.ff_offset + self.ff_gain * r + self.ff_rate_gain * r_rate
        v = ff + self.kp * e + self.integral + d_term
        u = min(max(v, self.u_min), self.u_max)
        if self.mode == "clamp":
            if not ((v > self.u_max and e > 0) or (v < self.u_min and e < 0)):
                self.integral += self.ki * e * dt
        elif self.mode == "back_calculation":
            self.integral += dt * (self.ki * e + (u - v) / self.tt)
        else:
            self.integral += self.ki * e * dt
        self.last = u
        return {"command": u}

    def linearization(self) -> np.ndarray | None:
        """Closed-loop A of the ``model`` input under this PID (:func:`pid_closed_loop`);
        None without a model or for a discrete one."""
        if self.model is None or self.model.dt != 0:
            return None
        return pid_closed_loop(self.model, self.kp, self.ki, self.kd, self.n,
                               self.input_index, self.fi)

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        """One step of the controller between the limits, in discrete time.

        With ``y`` the fed-back component (of ``estimate`` when that input is wired,
        else of ``measurement``), ``r`` and ``ṙ`` the reference's components and
        ``α = 1 − e^(−N dt)``::

            u   = ff_gain·r + ff_rate_gain·ṙ + kp (r − y) + I − kd N (y − y_f)
            I⁺  = I + ki dt (r − y)              (a state when ki ≠ 0)
            y_f⁺ = y_f + α (y − y_f)              (a state when kd ≠ 0)
        """
        key = "estimate" if inputs.get("estimate") else "measurement"
        w_y = next((pt.size for pt in inputs.get(key) or () if pt.size), self.fi + 1)
        w_r = next((pt.size for pt in inputs.get("reference") or () if pt.size), self.ri + 1)
        if self.fi >= w_y or self.ri >= w_r:
            return None
        r = np.zeros(w_r)
        r[self.ri] = 1.0
        rate = np.zeros(w_r)
        if w_r > self.ri + 1:
            rate[self.ri + 1] = 1.0
        y = np.zeros(w_y)
        y[self.fi] = 1.0
        states = ([("I", 1.0)] if self.ki else []) + ([("y_f", 0.0)] if self.kd else [])
        n = len(states)
        A, B = np.eye(n), np.zeros((n, w_r + w_y))
        C, D = np.zeros((1, n)), np.zeros((1, w_r + w_y))
        D[0, :w_r] = self.ff_gain * r + self.ff_rate_gain * rate + self.kp * r
        D[0, w_r:] = -(self.kp + self.kd * self.n) * y
        alpha = 1.0 - math.exp(-self.n * dt)
        for k, (label, _) in enumerate(states):
            if label == "I":
                C[0, k] = 1.0
                B[k, :w_r] = self.ki * dt * r
                B[k, w_r:] = -self.ki * dt * y
            else:
                C[0, k] = self.kd * self.n
                A[k, k] = 1.0 - alpha
                B[k, w_r:] = alpha * y
        return LinearModel(A, B, C, D, [("reference", w_r), (key, w_y)], [("command", 1)], dt,
                           [label for label, _ in states])

    def export_state(self) -> dict[str, Any]:
        out: dict[str, Any] = {"integral": self.integral}
        if self.model is not None:
            out["model"] = self.model
        return out

    def import_state(self, state: dict[str, Any]) -> None:
        if "integral" in state:
            self.integral = float(state["integral"])
        if state.get("model") is not None:
            self.model = state["model"]
