"""Generic module types for synthetic and large architectures.

``generic.relay`` passes the mean of its inputs on with a little noise; it lets
generated graphs of any size validate, compile and run (see
:mod:`archself.generate`).
"""

from __future__ import annotations

from typing import Any

from archself.modules.base import RuntimeModule
from archself.registry import register


@register("generic.relay")
class Relay(RuntimeModule):
    """Forward the mean of the incoming ``signal`` values, plus Gaussian noise.

    Parameters (``params``): ``gain`` (default 1.0), ``noise`` (default 0.0).
    Local signal ``deviation``: |output − gain·mean input|, the injected disturbance.
    """

    role = "relay"
    optional_inputs = ("signal",)
    outputs = ("signal",)
    residual_signals = ("deviation",)
    fault_kinds = frozenset({"bias", "bias_drift", "effectiveness_loss", "noise_increase",
                             "dropout", "stuck"})

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        x = inputs.get("signal")
        base = float(self.params.get("gain", 1.0)) * (float(x) if x is not None else 0.0)
        noise = float(self.params.get("noise", 0.0))
        y = base + (noise * float(self.rng.standard_normal()) if noise else 0.0)
        self.signals["deviation"] = abs(y - base)
        return {"signal": y}
