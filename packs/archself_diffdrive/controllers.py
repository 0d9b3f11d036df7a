"""Controllers: LQR on the tracking-error dynamics, and an asymmetric LQR.

Both regulate ``e = [e_along, e_lateral, e_heading]`` (see
:func:`archself_diffdrive.kinematics.tracking_error`) with the gain of
``control.lqr`` on the linearized error dynamics at the reference speed
(:func:`archself_diffdrive.kinematics.error_dynamics`, straight-line point), plus
feed-forward of the reference speed and yaw rate:

    [v, ω] = [v_ref, ω_ref] − K e,   wheel_cmd = body_to_wheels(v, ω).

python-control designs every gain (:func:`archself.linear.designs.lqr`): once per
process and design inputs, and kept in the user's design cache, so a later process
with the same weights imports neither python-control nor what it pulls in (scipy.signal,
matplotlib: ≈ 0.7 s of a process).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from archself.linear.designs import lqr
from archself.modules.base import Param, RuntimeModule
from archself_diffdrive.kinematics import error_dynamics, tracking_error_floats
from archself_diffdrive.models import Actuation, Dynamics, Kinematics

__all__ = ["lqr_gain", "LqrController", "AsymLqrController"]

_DEFAULT_KIN = Kinematics()
_MIN_DESIGN_SPEED = 0.05


def lqr_gain(v: float, q: tuple[float, float, float], r: tuple[float, float]) -> np.ndarray:
    """LQR gain K (2×3) of the tracking-error dynamics at speed ``v``.

    Designed by :func:`archself.linear.designs.lqr` (python-control), once per process
    and set of design inputs and cached across processes.

    Parameters
    ----------
    v : float
        Reference speed (m/s); floored at 0.05 m/s (the lateral error is not
        controllable at standstill).
    q : (q_along, q_lateral, q_heading)
        Diagonal state weights; floored at 1e-9 (a zero weight on a marginally
        stable error state leaves the Riccati equation without a stabilizing
        solution).
    r : (r_speed, r_turn)
        Diagonal input weights.

    Examples
    --------
    >>> K = lqr_gain(0.5, (4.0, 1.0, 0.0), (1.0, 1.0))
    >>> np.abs(K).round(6)   # K = [[√q_a, 0, 0], [0, √q_l, √(q_h + 2 v √q_l)]]
    array([[2., 0., 0.],
           [0., 1., 1.]])
    """
    v = max(float(v), _MIN_DESIGN_SPEED)
    A, B = error_dynamics(v)
    Q = np.diag([max(float(x), 1e-9) for x in q])
    return lqr(A, B, Q, np.diag([float(x) for x in r])).copy()


class LqrController(RuntimeModule):
    """LQR trajectory-tracking controller assuming symmetric, healthy wheels.

    The weights are those of :func:`lqr_gain` (a small ``q_lateral`` gives a
    deliberately soft lateral loop); ``design_speed_mps`` is the speed used for
    :meth:`linearization` before a reference has been seen.

    Inputs ``reference``, ``pose_estimate``, ``kinematics``; optional
    ``dynamics`` (the wheel-speed lag, used by :meth:`linearization`), ``actuation``
    (wheel-speed limit). Output
    ``wheel_cmd`` ``[l, r]`` (rad/s). Residual signal ``tracking_error``:
    |estimate − reference| position (m).
    """

    finite_outputs = True  # a gain times finite errors, clipped (needs_checks)
    state_fields = ()  # static: v_ref and K are scheduled from the reference

    parameters: ClassVar[dict[str, Param]] = {
        "q_along": Param(1.0, "", "weight of the along-track error", min=0.0, max=1e6),
        "q_lateral": Param(1.0, "", "weight of the lateral error", min=0.0, max=1e6),
        "q_heading": Param(1.0, "", "weight of the heading error", min=0.0, max=1e6),
        "r_speed": Param(
            1.0, "", "weight of δv (> 0: the Riccati equation needs R > 0)", min=1e-6, max=1e6
        ),
        "r_turn": Param(
            1.0, "", "weight of δω (> 0: the Riccati equation needs R > 0)", min=1e-6, max=1e6
        ),
        "design_speed_mps": Param(
            0.5, "m/s", "linearization speed before a reference"
            " (> 0: at rest the error dynamics are uncontrollable)",
            min=0.01, max=50.0,
        ),
    }
    role = "controller"
    inputs: ClassVar[tuple[str, ...]] = ("reference", "pose_estimate", "kinematics")
    optional_inputs = ("dynamics", "actuation")
    outputs = ("wheel_cmd",)
    output_sizes = {"wheel_cmd": 2}
    output_elements = {"wheel_cmd": ("left", "right")}
    residual_signals = ("tracking_error",)
    lanes = "archself_diffdrive.lanes_control:LqrControllerLanes"

    def __init__(self, name, params, rng):
        self._gains: dict[float, np.ndarray] = {}
        self.v_ref = math.nan  # the design speed until a reference is seen (see configure)
        super().__init__(name, params, rng)
        self._k_of: np.ndarray | None = None  # the gain whose rows are in _k
        self._k: list[list[float]] = []
        self.signals = {"tracking_error": math.nan}
        self.last_cmd: np.ndarray | None = None
        self.dynamics: Dynamics | None = None  # the dynamic model, once an edge delivers it

    @classmethod
    def check_params(cls, name: str, params: dict, dt: float) -> str | None:
        """Each weight and the design speed must be one number (a list passes the declared
        ranges, entry by entry); within the ranges every weight has a stabilizing Riccati
        solution (q floored at 1e-9, r > 0, design speed > 0), and not building one keeps
        python-control out of ``archself validate``."""
        for key in ("q_along", "q_lateral", "q_heading", "r_speed", "r_turn",
                    "design_speed_mps"):
            value = params.get(key, 0.0)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                return f"{key}: expected one number, got {type(value).__name__} {value!r}"
        return None

    def configure(self) -> None:
        """New weights: forget the cached gains and recompute the current one."""
        if math.isnan(self.v_ref):
            self.v_ref = float(self.params["design_speed_mps"])
        self._gains.clear()
        self.K = self.gain(self.v_ref)

    # gains -------------------------------------------------------------------
    def _weights(self) -> tuple[tuple[float, float, float], tuple[float, float]]:
        p = self.params
        q = (float(p["q_along"]), float(p["q_lateral"]), float(p["q_heading"]))
        r = (float(p["r_speed"]), float(p["r_turn"]))
        return q, r

    def gain(self, v: float) -> np.ndarray:
        """LQR gain at reference speed ``v`` (cached by speed rounded to 1 cm/s)."""
        key = round(max(float(v), _MIN_DESIGN_SPEED), 2)
        K = self._gains.get(key)
        if K is None:
            K = lqr_gain(key, *self._weights())
            self._gains[key] = K
        return K

    def linearization(self) -> np.ndarray:
        """Closed-loop matrix of the error dynamics at the current reference speed (Eq. 20).

        Without a dynamic model it is ``A − B K`` (3×3). With the ``dynamics`` input
        (the wheel-speed lag τ of :class:`~archself_diffdrive.models.Dynamics`) the
        realised body speeds ``δu_a`` lag the commanded ``−K e`` by a first-order
        lag and the closed loop is the 5×5 matrix::

            [ė  ]   [  A     B  ] [e  ]
            [δu̇_a] = [−K/τ  −I/τ] [δu_a]

        so the eigenvalue test of the stability filter (Eq. 21) sees the actuator
        lag the controller cannot remove.

        Examples
        --------
        >>> import numpy as np
        >>> from archself_diffdrive.models import Dynamics
        >>> c = LqrController("c", {}, np.random.default_rng(0))
        >>> c.linearization().shape
        (3, 3)
        >>> c.dynamics = Dynamics(wheel_time_constant_s=0.1)
        >>> A = c.linearization()
        >>> A.shape, bool(np.linalg.eigvals(A).real.max() < 0)
        ((5, 5), True)
        """
        A, B = error_dynamics(max(self.v_ref, _MIN_DESIGN_SPEED))
        K = self.gain(self.v_ref)
        tau = self.dynamics.wheel_time_constant_s if self.dynamics is not None else 0.0
        if tau <= 0:
            return A - B @ K
        return np.block([[A, B], [-K / tau, -np.eye(2) / tau]])

    # data flow ---------------------------------------------------------------
    def body_command(self, ref, est) -> tuple[float, float]:
        """``(v, ω)`` from the reference and the pose estimate."""
        # floats once (indexing an array costs more)
        ref = ref.tolist() if type(ref) is np.ndarray else [float(v) for v in ref]
        est = est.tolist() if type(est) is np.ndarray else [float(v) for v in est]
        v_ref = ref[3]
        if abs(v_ref - self.v_ref) > 0.005:
            self.v_ref = v_ref
            self.K = self.gain(v_ref)
        e0, e1, e2 = tracking_error_floats(est, ref)
        K = self.K
        if K is not self._k_of:  # the gain changed: refresh its float copy
            self._k_of, self._k = K, K.tolist()
        (k00, k01, k02), (k10, k11, k12) = self._k
        self.signals["tracking_error"] = math.hypot(est[0] - ref[0], est[1] - ref[1])
        return v_ref - (k00 * e0 + k01 * e1 + k02 * e2), ref[4] - (k10 * e0 + k11 * e1 + k12 * e2)

    def wheel_speeds(self, ref, est, inputs, eff: tuple[float, float] = (1.0, 1.0)
                     ) -> tuple[float, float]:
        """Wheel speeds ``(l, r)`` (rad/s) realising :meth:`body_command`'s ``(v, ω)``, each
        divided by its wheel's effectiveness ``eff`` (a division by 1 is exact), both
        scaled together into the actuation limit: clipping each alone would change the
        curvature (a saturated pair turns in circles instead of slowing down on the path)."""
        v, w = self.body_command(ref, est)
        kin = inputs.get("kinematics") or _DEFAULT_KIN
        half = w * kin.wheel_base_m / 2.0
        r = kin.wheel_radius_m
        left, right = (v - half) / r / eff[0], (v + half) / r / eff[1]
        act: Actuation | None = inputs.get("actuation")
        if act is not None:
            lim = act.max_wheel_speed_rad_s
            peak = max(abs(left), abs(right))
            if peak > lim:
                left, right = left * lim / peak, right * lim / peak
        return left, right

    def step(self, t, dt, inputs):
        dyn = inputs.get("dynamics")
        if dyn is not None:
            self.dynamics = dyn
        ref = inputs.get("reference")
        est = inputs.get("pose_estimate")
        if ref is None or est is None:
            return {"wheel_cmd": self.last_cmd}
        cmd = self.last_cmd = np.array(self.wheel_speeds(ref, est, inputs))
        return {"wheel_cmd": cmd}

    def export_state(self):
        return {"v_ref": self.v_ref, "dynamics": self.dynamics}

    def import_state(self, state):
        if "v_ref" in state:
            self.v_ref = float(state["v_ref"])
            self.K = self.gain(self.v_ref)
        if state.get("dynamics") is not None:
            self.dynamics = state["dynamics"]


class AsymLqrController(LqrController):
    """LQR that estimates each wheel's effectiveness online and pre-compensates it.

    The effectiveness ``e_i`` of wheel i is the exponentially weighted
    least-squares ratio of measured (encoder) to commanded speed, with time
    constant ``adaptation_time_s``, clipped to ``[min_effectiveness, 1]``; the
    command sent is the LQR command divided by ``e_i``.

    Parameters: those of :class:`LqrController` and the two above. Inputs as
    :class:`LqrController` plus ``encoder_speeds``.
    """

    # the effectiveness estimate is frozen: adaptation is slow next to the loop, and its sums
    # start at 0 on a hand-over, where the ratio's slope says nothing (docs/stability.md)
    state_fields = ()

    parameters = {
        **LqrController.parameters,
        "adaptation_time_s": Param(
            3.0, "s", "time constant of the effectiveness estimate", min=0.01, max=1e4
        ),
        "min_effectiveness": Param(
            0.3, "", "lower clip of the effectiveness estimate", min=0.01, max=1.0
        ),
    }
    inputs = ("reference", "pose_estimate", "kinematics", "encoder_speeds")
    lanes = "archself_diffdrive.lanes_control:AsymLqrControllerLanes"

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self._eff = [1.0, 1.0]
        self._num = [0.0, 0.0]
        self._den = [0.0, 0.0]
        self._sent: tuple[float, float] | None = None  # the last command sent, as floats
        self._lam = 1.0  # forgetting factor for the step _lam_of (set in _adapt)

    def configure(self) -> None:
        super().configure()
        self._tau = max(float(self.params["adaptation_time_s"]), 1e-6)
        self._emin = float(self.params["min_effectiveness"])
        self._lam_of: float | None = None  # the dt of _lam

    @property
    def effectiveness(self) -> np.ndarray:
        """Estimated effectiveness ``[e_l, e_r]`` of the two wheels."""
        return np.array(self._eff)

    @effectiveness.setter
    def effectiveness(self, value) -> None:
        self._eff = [float(v) for v in np.asarray(value, dtype=float).ravel()[:2]]

    def _adapt(self, dt: float, enc, sent: tuple[float, float]) -> None:
        """One recursive least-squares step of the effectiveness estimate.

        ``enc`` are the measured wheel speeds, ``sent`` the command of the last step.
        """
        if self._lam_of != dt:
            self._lam_of, self._lam = dt, math.exp(-dt / self._tau)
        lam, emin = self._lam, self._emin
        num, den, eff = self._num, self._den, self._eff
        measured = enc.tolist() if type(enc) is np.ndarray else [float(x) for x in enc]
        for i in (0, 1):
            c = sent[i]
            num[i] = lam * num[i] + c * measured[i]
            den[i] = lam * den[i] + c * c
            est = num[i] / den[i] if den[i] > 1e-3 else 1.0
            eff[i] = min(max(est, emin), 1.0)

    def step(self, t, dt, inputs):
        self.dynamics = inputs.get("dynamics") or self.dynamics
        enc = inputs.get("encoder_speeds")
        if enc is not None and self._sent is not None:
            self._adapt(dt, enc, self._sent)
        ref = inputs.get("reference")
        pose = inputs.get("pose_estimate")
        if ref is None or pose is None:
            last = self.last_cmd
            self._sent = None if last is None else (float(last[0]), float(last[1]))
            return {"wheel_cmd": last}
        self._sent = self.wheel_speeds(ref, pose, inputs, self._eff)
        cmd = self.last_cmd = np.array(self._sent)
        return {"wheel_cmd": cmd}

    def export_state(self):
        return {**super().export_state(), "effectiveness": self.effectiveness.copy()}

    def import_state(self, state):
        super().import_state(state)
        if "effectiveness" in state:
            self.effectiveness = np.asarray(state["effectiveness"], dtype=float).copy()
