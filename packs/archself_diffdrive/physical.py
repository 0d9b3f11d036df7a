"""Physical modules (M_P): the differential-drive plant, wheel actuators and sensors.

The plant holds the true state; sensors read it (plus noise) and actuators pass
the controller's commands to it. Faults of a scenario are injected by the
system executor on these modules' outputs (:mod:`archself.system.live`), so the
classes here model only the healthy hardware.
"""

from __future__ import annotations

import math

import numpy as np

from archself.modules.base import Param, RuntimeModule
from archself_diffdrive.kinematics import arc_step
from archself_diffdrive.models import Dynamics, Kinematics, parameters_of

__all__ = ["DiffDrivePlant", "WheelActuator", "WheelEncoders", "Imu", "Gps"]

_SENSOR_FAULTS = frozenset({"bias_drift", "bias", "noise_increase", "dropout", "stuck", "nan"})


class DiffDrivePlant(RuntimeModule):
    """Differential-drive chassis with first-order wheel-speed lag, speed limits and disturbances.

    Parameters (``params``): see :attr:`parameters`. The wheel speeds are clipped
    to ±``max_wheel_speed_rad_s`` and lag the actuators' speeds with
    ``wheel_time_constant_s`` (0: no lag); ``effectiveness`` is the built-in
    per-wheel effectiveness (scenario faults act on the actuators instead).

    Disturbances (the module's own random stream, so a seed gives one world):

    - **wheel slip** — the ground travel of each wheel over a step is
      ``r·ω·dt + sqrt(k·|r·ω·dt|)·N(0, 1)`` with ``k = slip_variance_m``: the
      non-systematic odometry error model of Chong & Kleeman (1997), whose
      variance grows with the distance a wheel rolls. Encoders measure the wheel's
      rotation, not its travel, so slip is what dead reckoning cannot see;
    - **process noise** — ground unevenness and side slip as white noise on the
      pose: lateral ``lateral_noise_m_sqrt_s`` (m/√s, across the heading) and yaw
      ``yaw_noise_rad_sqrt_s`` (rad/√s).

    docs/disturbances.md gives the defaults and where they come from; 0 turns a
    disturbance off.

    Inputs ``wheel_speed_left``, ``wheel_speed_right`` (rad/s; None = motor off);
    outputs the true ``pose`` ``[x, y, θ]`` and ``wheel_speeds`` ``[l, r]``.

    Examples
    --------
    >>> p = DiffDrivePlant("c", {"wheel_base_m": 0.5, "wheel_radius_m": 0.1,
    ...     "max_wheel_speed_rad_s": 12.0, "wheel_time_constant_s": 0.0},
    ...     np.random.default_rng(0))
    >>> _ = p.step(0.0, 1.0, {"wheel_speed_left": 5.0, "wheel_speed_right": 5.0})
    >>> p.output(1.0)["pose"].round(3)
    array([0.5, 0. , 0. ])
    """

    finite_outputs = True  # wheel speeds clipped: a bounded move a step (needs_checks)

    state_fields = ("pose", "wl", "wr")

    parameters = {
        **parameters_of(Kinematics),  # the true geometry
        "max_wheel_speed_rad_s": Param(
            math.inf, "rad/s", "per-wheel speed limit"
            " (≤ 10⁴ rad/s ≈ 95,000 rpm; the default inf: none)",
            min=0.01, max=1e4,
        ),
        "initial_pose": Param(
            [0.0, 0.0, 0.0], "m, m, rad", "[x, y, θ] at t = 0", min=-1e6, max=1e6
        ),
        "wheel_time_constant_s": parameters_of(Dynamics)["wheel_time_constant_s"],
        "effectiveness": Param(
            [1.0, 1.0], "", "built-in per-wheel effectiveness [l, r]"
            " (0: dead; above 1 over-delivers, 2 at most)",
            min=0.0, max=2.0,
        ),
        "slip_variance_m": Param(
            0.0, "m", "wheel-travel variance per metre rolled (slip)"
            " (1 m² per metre rolled: no traction)",
            min=0.0, max=1.0,
        ),
        "lateral_noise_m_sqrt_s": Param(
            0.0, "m/sqrt(s)", "side-slip noise across the heading", min=0.0, max=10.0
        ),
        "yaw_noise_rad_sqrt_s": Param(
            0.0, "rad/sqrt(s)", "heading noise (ground unevenness)", min=0.0, max=10.0
        ),
    }
    role = "plant"
    lanes = "archself_diffdrive.lanes_physical:DiffDrivePlantLanes"
    inputs = ("wheel_speed_left", "wheel_speed_right")
    outputs = ("pose", "wheel_speeds")
    output_sizes = {"pose": 3, "wheel_speeds": 2}
    output_elements = {"pose": ("x", "y", "theta"), "wheel_speeds": ("left", "right")}
    direct_feedthrough = False

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self.pose = self.params["initial_pose"]  # held as the floats px, py, th
        self.wl = 0.0
        self.wr = 0.0

    @property
    def pose(self) -> np.ndarray:
        """The true pose ``[x, y, θ]`` (a new array; the plant steps on floats)."""
        return np.array([self.px, self.py, self.th])

    @pose.setter
    def pose(self, value) -> None:
        self.px, self.py, self.th = np.asarray(value, dtype=float)[:3].tolist()

    def configure(self) -> None:
        p = self.params
        self.tau = float(p["wheel_time_constant_s"])
        self.limit = float(p["max_wheel_speed_rad_s"])
        self._kp = {  # (read by the lanes)
            "wheel_radius_m": float(p["wheel_radius_m"]),
            "wheel_base_m": float(p["wheel_base_m"]),
            "effectiveness": [float(e) for e in p["effectiveness"]],
        }
        self.radius = float(p["wheel_radius_m"])
        self._base = float(p["wheel_base_m"])
        self._eff = (float(p["effectiveness"][0]), float(p["effectiveness"][1]))
        self.slip = float(p["slip_variance_m"])
        self.lateral = float(p["lateral_noise_m_sqrt_s"])
        self.yaw = float(p["yaw_noise_rad_sqrt_s"])
        self._lag_of = math.nan  # the dt of _lag: the wheels' lag factor 1 − exp(−dt/τ)
        self._lag = 1.0

    def output(self, t):
        return {"pose": np.array([self.px, self.py, self.th]),
                "wheel_speeds": np.array([self.wl, self.wr])}

    def step(self, t, dt, inputs):
        lim = self.limit
        tl = inputs.get("wheel_speed_left")
        tr = inputs.get("wheel_speed_right")
        tl = 0.0 if tl is None else min(max(float(tl), -lim), lim)
        tr = 0.0 if tr is None else min(max(float(tr), -lim), lim)
        if dt != self._lag_of:
            self._lag_of, self._lag = dt, 1.0 - math.exp(-dt / self.tau) if self.tau > 0 else 1.0
        a = self._lag
        wl0, wr0 = self.wl, self.wr
        wl = self.wl = wl0 + a * (tl - wl0)
        wr = self.wr = wr0 + a * (tr - wr0)
        if self.tau > 0:  # trapezoidal wheel speeds over the step
            wl, wr = 0.5 * (wl0 + wl), 0.5 * (wr0 + wr)
        self._move(wl, wr, dt)
        return {}

    def _move(self, wl: float, wr: float, dt: float) -> None:
        """The pose after ``dt`` at wheel speeds ``wl``, ``wr`` with the disturbances
        (:func:`arc_step`): the wheels' ground travel carries the
        slip (σ² = k·|r·ω·dt| per wheel), the pose the lateral and yaw noise. The step's
        normals are drawn at once, in the stream's order: slip's two, then the pose
        noise's two."""
        slip = self.slip > 0 and dt > 0
        noisy = (self.lateral > 0 or self.yaw > 0) and dt > 0
        r = self.radius
        if slip or noisy:
            z: list[float] = self.rng.standard_normal(2 * slip + 2 * noisy).tolist()
            if slip:
                rdt = r * dt
                wl = wl + math.sqrt(self.slip * abs(r * wl * dt)) * z[0] / rdt
                wr = wr + math.sqrt(self.slip * abs(r * wr * dt)) * z[1] / rdt
        px, py, th = arc_step(self.px, self.py, self.th, r, self._base, wl * self._eff[0],
                              wr * self._eff[1], dt)
        if noisy:
            sq = math.sqrt(dt)
            lat = self.lateral * (z[-2] * sq)
            px, py, th = px + -math.sin(th) * lat, py + math.cos(th) * lat, th + self.yaw * (
                z[-1] * sq)
        self.px, self.py, self.th = px, py, th

    def export_state(self):
        return self.output(0.0)

    def import_state(self, state):
        if "pose" in state:
            self.pose = state["pose"]
        if "wheel_speeds" in state:
            self.wl, self.wr = (float(w) for w in state["wheel_speeds"])


class WheelActuator(RuntimeModule):
    """One wheel's motor and driver: drives its side of the controller's ``wheel_cmd``.

    Parameter ``side`` (``"left"`` or ``"right"``): which entry of ``wheel_cmd``
    ``[l, r]`` this wheel takes. Inputs ``wheel_cmd`` (rad/s, from a controller) and optionally
    ``encoder_speeds``; output ``wheel_speed_<side>``: the speed it drives.
    Residual signal ``command_error`` = (previous command − measured encoder
    speed)·sign(previous command) (rad/s): the wheel's shortfall, positive when it
    turns slower than commanded. Signed, so that the Monitor's low-pass filter
    averages the encoder noise out (a filtered magnitude would keep its mean,
    ≈ 0.8σ): near 0 when healthy, a steady fraction of the command when the wheel
    loses effectiveness. ``error_smoothing_s`` > 0 averages it at every step (the
    Monitor samples it only once per MAPE-K period, so without it the encoder noise
    of the other steps is not averaged at all). ``response_time_s`` > 0 compares the
    measurement with the command passed through the healthy wheel's first-order lag
    (a model-based residual): a commanded acceleration, the start from rest
    included, then leaves no shortfall.

    Examples
    --------
    >>> w = WheelActuator("wl", {"side": "left"}, np.random.default_rng(0))
    >>> w.step(0.0, 0.05, {"wheel_cmd": np.array([4.0, 6.0])})
    {'wheel_speed_left': 4.0}
    >>> _ = w.step(0.05, 0.05, {"wheel_cmd": np.array([4.0, 6.0]),
    ...                         "encoder_speeds": np.array([3.2, 6.0])})
    >>> round(w.local_signals()["command_error"], 3)
    0.8
    >>> _ = w.step(0.1, 0.05, {"wheel_cmd": np.array([4.0, 6.0]),
    ...                        "encoder_speeds": np.array([4.3, 6.0])})
    >>> round(w.local_signals()["command_error"], 3)   # faster than commanded
    -0.3
    """

    finite_outputs = True  # a finite command times a finite effectiveness (needs_checks)

    state_fields = ("prev_cmd", "expected")

    parameters = {
        "side": Param("left", "", "'left' or 'right': the entry of wheel_cmd taken"),
        "error_smoothing_s": Param(
            0.0, "s", "time constant of the command_error average kept at every step (0: raw)",
            min=0.0, max=3600.0,
        ),
        "response_time_s": Param(
            0.0, "s", "first-order lag the healthy wheel follows its command with (0: none)",
            min=0.0, max=100.0,
        ),
    }
    role = "actuator"
    lanes = "archself_diffdrive.lanes_physical:WheelActuatorLanes"
    inputs = ("wheel_cmd",)
    optional_inputs = ("encoder_speeds",)
    outputs = ("wheel_speed_left", "wheel_speed_right")
    residual_signals = ("command_error",)
    fault_kinds = frozenset(
        {"effectiveness_loss", "stuck", "dropout", "bias", "bias_drift", "noise_increase"}
    )
    direct_feedthrough = True

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self.prev_cmd: float | None = None
        self.expected = 0.0  # the healthy wheel's speed (from rest)
        self.signals = {"command_error": math.nan}

    def configure(self) -> None:
        side = self.params["side"]
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', not {side!r}")
        self.index = 0 if side == "left" else 1
        self.main_output = f"wheel_speed_{side}"
        self.smoothing = float(self.params["error_smoothing_s"])
        self.response = float(self.params["response_time_s"])

    def step(self, t, dt, inputs):
        enc = inputs.get("encoder_speeds")
        if enc is not None and self.prev_cmd is not None:
            c, m = self.prev_cmd, float(enc[self.index])
            if self.response > 0:  # what a healthy wheel would turn at now: the lagged command
                c = self.expected = self.expected + (1.0 - math.exp(-dt / self.response)) * (
                    c - self.expected
                )
            e = c - m if c >= 0 else m - c
            last = self.signals["command_error"]
            if self.smoothing > 0 and last == last:  # average at the step rate
                e = last + (1.0 - math.exp(-dt / self.smoothing)) * (e - last)
            self.signals["command_error"] = e
        cmd = inputs.get("wheel_cmd")
        if cmd is None:
            self.prev_cmd = None
            return {self.main_output: None}
        c = float(cmd[self.index])
        self.prev_cmd = c
        return {self.main_output: c}


class WheelEncoders(RuntimeModule):
    """Wheel encoders: the real wheel speeds plus Gaussian noise.

    Input ``wheel_speeds`` (true, from the plant); output ``encoder_speeds`` ``[l, r]``.
    """

    finite_outputs = True  # finite speeds plus noise: no NaN scan (stale still checked)

    parameters = {
        "noise_rad_s": Param(
            0.05, "rad/s", "standard deviation of the speed noise"
            " (above 100 rad/s the reading is all noise)",
            min=0.0, max=100.0,
        ),
    }
    role = "sensor"
    inputs = ("wheel_speeds",)
    outputs = ("encoder_speeds",)
    lanes = "archself_diffdrive.lanes_physical:WheelEncodersLanes"
    output_sizes = {"encoder_speeds": 2}
    fault_kinds = _SENSOR_FAULTS | {"effectiveness_loss"}

    def configure(self) -> None:
        self.noise = float(self.params["noise_rad_s"])
        self.noise_levels = {"encoder_speeds": self.noise}

    def step(self, t, dt, inputs):
        ws = inputs.get("wheel_speeds")
        if ws is None:
            return {"encoder_speeds": None}
        # on floats: the same operations as ``ws + noise · N(0, 1)`` (an array's arithmetic
        # costs 1.7 µs a step, these 0.9)
        n0, n1 = self.rng.standard_normal(2).tolist()
        wl, wr = ws.tolist() if type(ws) is np.ndarray else (float(ws[0]), float(ws[1]))
        return {"encoder_speeds": np.array([wl + self.noise * n0, wr + self.noise * n1])}


class Imu(RuntimeModule):
    """IMU heading (integrated gyro): true heading + bias + Gaussian noise, wrapped to [-π, π).

    ``bias_rad`` is a constant built-in bias; a drifting bias comes from a
    ``bias_drift`` fault of the scenario. Input ``pose`` (true); output
    ``heading`` (rad).
    """

    finite_outputs = True  # a finite heading plus noise: no NaN scan (stale still checked)

    parameters = {
        "noise_rad": Param(
            0.005, "rad", "standard deviation of the heading noise (beyond π a heading is uniform)",
            min=0.0, max=math.pi,
        ),
        "bias_rad": Param(0.0, "rad", "constant built-in bias", min=-math.pi, max=math.pi),
    }
    role = "sensor"
    inputs = ("pose",)
    outputs = ("heading",)
    lanes = "archself_diffdrive.lanes_physical:ImuLanes"
    fault_kinds = _SENSOR_FAULTS

    def configure(self) -> None:
        self.noise = float(self.params["noise_rad"])
        self.bias = float(self.params["bias_rad"])
        self.noise_levels = {"heading": self.noise}

    def step(self, t, dt, inputs):
        pose = inputs.get("pose")
        if pose is None:
            return {"heading": None}
        h = float(pose[2]) + self.bias + self.noise * float(self.rng.standard_normal())
        return {"heading": (h + math.pi) % (2.0 * math.pi) - math.pi}


class Gps(RuntimeModule):
    """GNSS receiver: position fixes ``[x, y]`` at ``rate_hz``, None between fixes.

    The first fix is at t = 0. Input ``pose`` (true); output ``position``.
    ``max_silence_s`` (2.5 fix periods) tells the system when a receiver without
    fixes is in dropout.
    """

    finite_outputs = True  # a position plus noise: no NaN scan (stale, silence checked)

    state_fields = ()  # the fix timer is the clock, not the loop

    parameters = {
        "rate_hz": Param(1.0, "Hz", "fix rate", min=0.001, max=1000.0, period=True),
        "noise_m": Param(
            0.3, "m", "standard deviation of each coordinate"
            " (≤ 1 km: a receiver worse than that gives no fix)",
            min=0.0, max=1000.0,
        ),
    }
    role = "sensor"
    inputs = ("pose",)
    outputs = ("position",)
    lanes = "archself_diffdrive.lanes_physical:GpsLanes"
    output_sizes = {"position": 2}
    fault_kinds = _SENSOR_FAULTS

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self.next_fix = 0.0

    def configure(self) -> None:
        self.period = 1.0 / float(self.params["rate_hz"])
        self.noise = float(self.params["noise_m"])
        self.noise_levels = {"position": self.noise}
        self.max_silence_s = 2.5 * self.period

    def step(self, t, dt, inputs):
        pose = inputs.get("pose")
        if pose is None or t < self.next_fix - 1e-9:
            return {"position": None}
        self.next_fix += self.period * max(1.0, math.floor((t - self.next_fix) / self.period) + 1)
        return {"position": pose[:2] + self.noise * self.rng.standard_normal(2)}
