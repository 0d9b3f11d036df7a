"""Generic module types for synthetic and large architectures.

``generic.relay`` passes the mean of its inputs on with a little noise; it lets
generated graphs of any size validate, compile and run (see
:mod:`archself.model.generate`).
"""

from __future__ import annotations

from typing import Any

from archself.model.architecture import Input, Output
from archself.modules.base import Param, RuntimeModule


class Relay(RuntimeModule):
    """A unit delay: publish ``gain`` times the mean of last step's ``signal`` inputs, plus noise.

    ``signal`` may arrive over any number of edges (``multi_inputs``); sources
    with nothing this step are left out of the mean (none: the input is 0), and
    a value that is not a number makes the relay hold its state. Local signal
    ``deviation``: |output − gain·input|, the injected disturbance.
    Having no direct feedthrough, relays can form feedback loops.
    """

    state_fields = ("value",)

    parameters = {
        "gain": Param(1.0, "", "factor on last step's input"),
        "noise": Param(0.0, "", "standard deviation of the added white noise", min=0.0),
    }
    role = "relay"
    ports = (
        Input("signal", doc="upstream values, one per edge", required=False, multi=True),
        Output("signal", doc="gain times the mean of last step's inputs, plus noise"),
    )
    residual_signals = ("deviation",)
    fault_kinds = frozenset(
        {"bias", "bias_drift", "effectiveness_loss", "noise_increase", "dropout", "stuck"}
    )

    direct_feedthrough = False
    lanes = "archself_blocks.lanes_static:RelayLanes"

    def __init__(self, name: str, params: dict[str, Any], rng: Any) -> None:
        super().__init__(name, params, rng)
        self.value = 0.0

    def output(self, t: float) -> dict[str, Any]:
        return {"signal": self.value}

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        values = [x for x in inputs.get("signal") or () if x is not None]
        try:
            mean = sum(float(x) for x in values) / len(values) if values else 0.0
            base = float(self.params["gain"]) * mean
        except (TypeError, ValueError):  # a vector or junk on the wire: hold the state
            base = self.value
        noise = float(self.params["noise"])
        self.value = base + (noise * float(self.rng.standard_normal()) if noise else 0.0)
        self.signals["deviation"] = abs(self.value - base)
        return {}
