"""``generic.actuator``: saturation, rate limit, lag, gain; a command-versus-delivered residual."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.model.architecture import Input, Output
from archself.modules.base import LinearModel, Param, RuntimeModule
from archself_blocks.lti import as_vector

__all__ = ["Actuator", "ACTUATOR_FAULTS"]

#: Fault kinds a scenario may inject into an actuator's ``u``.
ACTUATOR_FAULTS = frozenset(
    {"effectiveness_loss", "stuck", "dropout", "bias", "bias_drift", "noise_increase", "nan"}
)


class Actuator(RuntimeModule):
    """Turns a ``command`` into the plant input ``u``::

        target = clip(scale·gain·command, u_min, u_max)
        v ← v + clip(target − v, ±rate_limit·dt)        (rate limit)
        x ← x + (1 − e^(−dt/τ))·(v − x)                (first-order lag, τ = time_constant_s)
        u = x

    ``scale`` converts the command's units into the output's (W per %, N per V; 1 by
    default); ``gain`` is the effectiveness the actuator is driven with (1 when
    healthy; a ``parameter_update`` that raises it compensates a partial loss). A scenario's
    ``effectiveness_loss`` on ``u`` scales what the plant really receives. The
    output is a number, or, with ``width`` > 1, a vector of that length with the
    value at ``channel`` (one input of a multi-input plant).

    Optional input ``measurement``: a meter of what is delivered (a sensor on the
    plant's ``u`` output, in the output's units). Residual signal ``command_error`` =
    |x_prev/gain − measurement|: what the controller asked for in the last step
    (``scale·command`` as far as the limits let it, in output units) against what
    arrived — near the meter's noise when healthy, a fraction of the command when the
    actuator lost effectiveness. A unit conversion given as ``gain`` instead of
    ``scale`` would compare command units with output units (``archself validate`` warns:
    :meth:`param_warnings`).

    Examples
    --------
    >>> a = Actuator("a", {"u_max": 10.0, "rate_limit": 20.0}, np.random.default_rng(0))
    >>> [a.step(0.1 * k, 0.1, {"command": 50.0})["u"] for k in range(3)]
    [2.0, 4.0, 6.0]
    """

    state_fields = ("v", "x")

    parameters = {
        "gain": Param(1.0, "", "effectiveness the command is multiplied by (1: healthy)"),
        "scale": Param(1.0, "", "output units per command unit (W per %); the meter's units "
                       "are the output's"),
        "u_min": Param(None, "", "lower output limit; None: none"),
        "u_max": Param(None, "", "upper output limit; None: none"),
        "rate_limit": Param(
            None, "1/s", "largest change per second (output units); None: none", min=0.0
        ),
        "time_constant_s": Param(0.0, "s", "first-order lag; 0: none", min=0.0, max=1e7),
        "initial": Param(0.0, "", "output at the start"),
        "channel": Param(0, "", "plant input driven, with width > 1", min=0, max=100000),
        "width": Param(1, "", "length of the output vector; 1: a number", min=1, max=100000),
    }
    role = "actuator"
    ports = (
        Input("command", doc="the command (the controller's units)"),
        Input("measurement", doc="a meter of what it delivers (command_error)", required=False),
        Output("u", doc="what it delivers: clip(scale·gain·command), rate-limited, lagged"),
    )
    residual_signals = ("command_error",)
    fault_kinds = ACTUATOR_FAULTS
    main_output = "u"
    lanes = "archself_blocks.lanes_plants:ActuatorLanes"

    @classmethod
    def param_warnings(cls, params: dict[str, Any], residual: str | None) -> list[tuple[str, str]]:
        """A ``gain`` ≠ 1 without ``scale`` beside a ``command_error`` residual: a unit
        conversion given as the effectiveness (the residual would compare the command's
        units with the meter's)."""
        gain, scale = params.get("gain", 1.0), params.get("scale", 1.0)
        if residual != "command_error" or not isinstance(gain, (int, float)) or gain == 1 \
                or scale != 1:
            return []
        return [("gain", f"gain {gain:g} with the residual command_error compares x/gain, the "
                 "command in its own units, with the meter in the output's; a unit "
                 "conversion (W per %) belongs in 'scale', gain is the effectiveness "
                 "(1 when healthy; docs/blocks.md)")]

    def __init__(self, name: str, params: dict[str, Any], rng: np.random.Generator) -> None:
        super().__init__(name, params, rng)
        self.v = self.x = float(self.params["initial"])
        self.prev: float | None = None
        self.signals = {"command_error": math.nan}

    def configure(self) -> None:
        p = self.params
        self.gain = float(p["gain"])
        self.drive = self.gain * float(p["scale"])  # command → output units, with effectiveness
        self.lo = -math.inf if p["u_min"] is None else float(p["u_min"])
        self.hi = math.inf if p["u_max"] is None else float(p["u_max"])
        self.rate = math.inf if p["rate_limit"] is None else float(p["rate_limit"])
        self.tau = float(p["time_constant_s"])
        self.channel, self.width = int(p["channel"]), int(p["width"])

    def _publish(self, x: float) -> Any:
        if self.width <= 1:
            return x
        out = np.zeros(self.width)
        out[self.channel] = x
        return out

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        meas = as_vector(inputs.get("measurement"))
        if meas is not None and self.prev is not None and self.gain:
            self.signals["command_error"] = abs(self.prev / self.gain - float(meas[0]))
        cmd = as_vector(inputs.get("command"))
        if cmd is None:
            self.prev = None
            return {"u": None}
        target = min(max(self.drive * float(cmd[0]), self.lo), self.hi)
        step = self.rate * dt
        self.v += min(max(target - self.v, -step), step)
        if self.tau > 0:
            self.x += (1.0 - math.exp(-dt / self.tau)) * (self.v - self.x)
        else:
            self.x = self.v
        self.prev = self.x
        return {"u": self._publish(self.x)}

    def state_space(self) -> tuple[np.ndarray, ...] | None:
        """(A, B, C, D) of the lag from command to u, linear between the limits."""
        if self.tau <= 0:
            return None
        return (np.array([[-1.0 / self.tau]]), np.array([[self.drive / self.tau]]),
                np.array([[1.0]]), np.array([[0.0]]))

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        """Command to ``u`` between the limits, as one step runs it (rate limit inactive).

        ``u_k = (1 − a)·u_{k−1} + a·scale·gain·command_k`` with ``a = 1 − e^(−dt/τ)`` (``a = 1``
        without a lag): the state is the output of the step before.
        """
        ports = inputs.get("command") or ()
        w_in = next((pt.size for pt in ports if pt.size), 1)
        a = 1.0 - math.exp(-dt / self.tau) if self.tau > 0 else 1.0
        width = max(self.width, 1)
        row = np.zeros((width, 1))
        row[self.channel if width > 1 else 0, 0] = 1.0
        b = np.zeros((1, w_in))
        b[0, 0] = a * self.drive
        if a >= 1.0:  # no lag: a static gain
            return LinearModel(np.zeros((0, 0)), np.zeros((0, w_in)), np.zeros((width, 0)),
                               row @ b, [("command", w_in)], [("u", width)], dt)
        return LinearModel([[1.0 - a]], b, row * (1.0 - a), row @ b, [("command", w_in)],
                           [("u", width)], dt, ["lag"])

    def export_state(self) -> dict[str, Any]:
        return {"output": self.x}

    def import_state(self, state: dict[str, Any]) -> None:
        if "output" in state:  # a backup takes over where the other one stood
            self.v = self.x = float(state["output"])
