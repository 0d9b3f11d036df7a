"""``generic.sensor``: a reading with gain, bias, drift, noise, quantization, range, dropout."""

from __future__ import annotations

from typing import Any

import numpy as np

from archself.model.architecture import Input, Output
from archself.modules.base import LinearModel, Param, RuntimeModule
from archself_blocks.lti import as_vector

__all__ = ["Sensor", "SENSOR_FAULTS"]

#: Fault kinds a scenario may inject into a sensor's ``measurement``.
SENSOR_FAULTS = frozenset({"bias_drift", "bias", "noise_increase", "dropout", "stuck", "nan"})


class Sensor(RuntimeModule):
    """Reads component ``index`` of its input and publishes ``measurement``::

        m = quantize(gain·x + bias + drift_per_s·t + noise·n) clipped to [min, max]

    with ``n`` standard normal and ``quantize`` rounding to a multiple of
    ``resolution`` (0: none). With probability ``dropout_probability`` a sample is
    lost (``None``); with ``max_silence_s`` the system counts a sensor that gave no
    reading for longer as unavailable (``silent for … s``: a dropout is detected, from
    ``dropout_probability`` or a scenario's ``dropout`` fault). The input is ``y`` (a
    plant's output) or ``u`` (a plant's applied input: a meter on the input line); the
    first one connected is read.

    The built-in ``bias``/``drift_per_s`` describe a sensor as it is; a scenario's
    faults (``bias_drift``, ``bias``, ``noise_increase``, ``dropout``, ``stuck``, ``nan``)
    act on ``measurement`` on top. An unquantized noisy sensor declares its noise
    (``noise_levels``), so a frozen value is detected as stale.

    Examples
    --------
    >>> s = Sensor("s", {"resolution": 0.5}, np.random.default_rng(0))
    >>> s.step(0.0, 0.1, {"y": np.array([1.2, 3.0])})
    {'measurement': 1.0}
    """

    parameters = {
        "index": Param(0, "", "component of the input vector that is measured", min=0, max=100000),
        "gain": Param(1.0, "", "scale factor"),
        "bias": Param(0.0, "", "constant offset (units of the measurement)"),
        "drift_per_s": Param(0.0, "1/s", "offset growing with time (units per second)"),
        "noise": Param(0.0, "", "standard deviation of the white noise", min=0.0),
        "resolution": Param(0.0, "", "quantization step; 0: none", min=0.0),
        "min": Param(None, "", "lower end of the range; None: none"),
        "max": Param(None, "", "upper end of the range; None: none"),
        "dropout_probability": Param(
            0.0, "", "probability that a sample is lost", min=0.0, max=1.0
        ),
        "max_silence_s": Param(
            None, "s", "no reading for longer makes it unavailable (silent); None: never",
            min=0.0, max=1e7, period=True,
        ),
    }
    role = "sensor"
    ports = (
        Input("y", doc="a plant's output vector (component index is measured)", required=False),
        Input("u", doc="a plant's applied input, for a meter on the input line",
              required=False),
        Output("measurement", doc="gain·x + bias + drift + noise, quantized and clipped"),
    )
    fault_kinds = SENSOR_FAULTS
    main_output = "measurement"
    lanes = "archself_blocks.lanes_plants:SensorLanes"

    def configure(self) -> None:
        p = self.params
        self.index = int(p["index"])
        self.gain, self.bias = float(p["gain"]), float(p["bias"])
        self.drift = float(p["drift_per_s"])
        self.noise = float(p["noise"])
        self.resolution = float(p["resolution"])
        self.lo = -np.inf if p["min"] is None else float(p["min"])
        self.hi = np.inf if p["max"] is None else float(p["max"])
        self.p_drop = float(p["dropout_probability"])
        if not 0.0 <= self.p_drop <= 1.0:
            raise ValueError("dropout_probability must lie in [0, 1]")
        silence = p["max_silence_s"]
        self.max_silence_s = None if silence is None else float(silence)
        self.noise_levels = (
            {"measurement": self.noise} if self.noise > 0 and self.resolution == 0 else None
        )

    def measure(self, t: float, x: float) -> float | None:
        """One reading of the true value ``x`` at ``t`` (None: lost)."""
        v = self.gain * x + self.bias + self.drift * t
        if self.noise:
            v += self.noise * float(self.rng.standard_normal())
        if self.resolution > 0 and not self.smooth:  # a quantizer's slope is 0 almost everywhere
            v = self.resolution * round(v / self.resolution)
        v = min(max(v, self.lo), self.hi)
        if self.p_drop and float(self.rng.random()) < self.p_drop:
            return None
        return float(v)

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        """``measurement = gain·x[index]`` of ``y`` (or of ``u`` when no ``y`` is wired).

        Bias, drift and noise are additive (no part of A), quantization, range and
        dropout are left out: the small-signal model of a sensor is its gain.
        """
        key = "y" if inputs.get("y") else "u"
        width = next((pt.size for pt in inputs.get(key) or () if pt.size), self.index + 1)
        if self.index >= width:
            return None
        D = np.zeros((1, width))
        D[0, self.index] = self.gain
        return LinearModel(np.zeros((0, 0)), np.zeros((0, width)), np.zeros((1, 0)), D,
                           [(key, width)], [("measurement", 1)], dt)

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        x = inputs.get("y")
        if x is None:
            x = inputs.get("u")
        vec = as_vector(x)
        if vec is None:
            return {"measurement": None}
        return {"measurement": self.measure(t, float(vec[self.index]))}
