"""Signal blocks: a reference generator and the static gain, sum and select blocks.

The static blocks take their input under any signal name of the library and
publish their result under every one of them (:data:`PORTS`), so they fit on any
edge: ``sensor --measurement--> gain --measurement--> pid``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from archself.model.ports import Input, Output
from archself.modules.base import LinearModel, Param, RuntimeModule
from archself_blocks.lti import as_matrix, as_vector

__all__ = ["PORTS", "Reference", "Gain", "Sum", "Select"]

#: The signal names of the block library; the static blocks take and give each of them.
PORTS = ("signal", "y", "u", "state", "measurement", "estimate", "reference", "command")


class Reference(RuntimeModule):
    """A reference from a table of times: steps or ramps, optionally rate-limited.

    ``table`` holds ``[t_s, value]`` rows. With ``interpolation: previous`` the
    reference steps to ``value`` at ``t_s`` (the first row gives the start value),
    approached at most at ``max_rate`` per second (0: at once); with ``linear`` it
    ramps linearly between the rows and holds the last value. Output
    ``reference`` = ``[r, dr/dt]``.

    Examples
    --------
    >>> r = Reference("r", {"table": [[0, 1.0], [10, 3.0]], "interpolation": "linear"},
    ...               np.random.default_rng(0))
    >>> [r.step(t, 0.1, {})["reference"].tolist() for t in (5.0, 20.0)]
    [[2.0, 0.2], [3.0, 0.0]]
    """

    state_fields = ()  # an exogenous signal of time

    parameters = {
        "table": Param([[0.0, 0.0]], "[s, units]", "rows [t_s, value]"),
        "interpolation": Param("previous", "", "previous (steps) or linear (ramps)"),
        "max_rate": Param(
            0.0, "1/s", "rate limit of the steps (units per second); 0: none", min=0.0
        ),
    }
    role = "planner"
    ports = (Output("reference", doc="[r, dr/dt]", size=2),)
    lanes = "archself_blocks.lanes_control:ReferenceLanes"

    def __init__(self, name: str, params: dict[str, Any], rng: np.random.Generator) -> None:
        super().__init__(name, params, rng)
        self.r: float | None = None

    def configure(self) -> None:
        rows = sorted((float(t), float(v)) for t, v in self.params["table"])
        if not rows:
            raise ValueError("table needs at least one row")
        self.times = np.array([t for t, _ in rows])
        self.values = np.array([v for _, v in rows])
        mode = self.params["interpolation"]
        if mode not in ("previous", "linear"):
            raise ValueError("interpolation must be previous or linear")
        self.linear = mode == "linear"
        self.rate = float(self.params["max_rate"])

    def target(self, t: float) -> tuple[float, float]:
        """The table's value and slope at ``t`` (before the rate limit)."""
        i = int(np.searchsorted(self.times, t + 1e-9, side="right")) - 1
        if i < 0:
            return float(self.values[0]), 0.0
        if self.linear and i + 1 < len(self.times):
            t0, t1 = self.times[i], self.times[i + 1]
            slope = (self.values[i + 1] - self.values[i]) / (t1 - t0)
            return float(self.values[i] + slope * (t - t0)), float(slope)
        return float(self.values[i]), 0.0

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        value, slope = self.target(t)
        if self.rate > 0 and self.r is not None and not self.linear:
            d = min(max(value - self.r, -self.rate * dt), self.rate * dt)
            slope = d / dt if dt > 0 else 0.0
            value = self.r + d
        self.r = value
        return {"reference": np.array([value, slope])}


class _Static(RuntimeModule):
    """A memoryless block on the library's signal names (:data:`PORTS`)."""

    role = "static"
    ports = (
        *(Input(s, doc="any library signal, several edges", required=False, multi=True)
          for s in PORTS),
        *(Output(s, doc="the result, under every library signal name") for s in PORTS),
    )
    main_output = "signal"

    def _values(self, inputs: dict[str, Any]) -> list[np.ndarray | None]:
        """Every input value: by name in :data:`PORTS` order, then in edge order."""
        out: list[np.ndarray | None] = []
        for name in PORTS:
            for v in inputs.get(name) or ():
                out.append(as_vector(v) if isinstance(v, (int, float, list, np.ndarray)) else None)
        return out

    def _first(self, inputs: Any) -> list[tuple[str, int, int]]:
        """``[(signal, width, edge)]`` of the first wired input in the order of
        :meth:`_values`; empty when there is none or its source has no model."""
        for name in PORTS:
            for k, pt in enumerate(inputs.get(name) or ()):
                return [(name, int(pt.size), k)] if pt.size else []
        return []

    def _static_model(self, dt: float, ports: list[tuple[str, int, int]],
                      D: np.ndarray) -> LinearModel:
        """``y = D u`` on ``ports``, published under every name of :data:`PORTS`."""
        p = D.shape[0]
        Dall = np.vstack([D] * len(PORTS))
        return LinearModel(np.zeros((0, 0)), np.zeros((0, D.shape[1])),
                           np.zeros((Dall.shape[0], 0)), Dall, ports,
                           [(name, p) for name in PORTS], dt)

    def _publish(self, v: np.ndarray | None) -> dict[str, Any]:
        if v is None:
            return dict.fromkeys(PORTS)
        value: Any = float(v[0]) if v.size == 1 and self.scalar else v
        return dict.fromkeys(PORTS, value)

    scalar = True


class Gain(_Static):
    """``out = K·in + offset`` (K a number or a matrix) of the first available input.

    Examples
    --------
    >>> g = Gain("g", {"gain": 2.0, "offset": 1.0}, np.random.default_rng(0))
    >>> g.step(0.0, 0.1, {"measurement": [3.0]})["measurement"]
    7.0
    """

    parameters = {
        "gain": Param(1.0, "", "K: a number or a matrix"),
        "offset": Param(0.0, "", "added after the gain (a number or a vector)"),
    }
    lanes = "archself_blocks.lanes_static:GainLanes"

    def configure(self) -> None:
        self.k = np.asarray(self.params["gain"], dtype=float)
        self.offset = np.asarray(self.params["offset"], dtype=float)

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        x = next((v for v in self._values(inputs) if v is not None), None)
        if x is None:
            return self._publish(None)
        y = self.k * x if self.k.ndim == 0 else as_matrix(self.k) @ x
        return self._publish(np.atleast_1d(y + self.offset))

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        """``K`` on the first wired input (the offset is no part of A)."""
        ports = self._first(inputs)
        if not ports:
            return None
        w = ports[0][1]
        K = self.k * np.eye(w) if self.k.ndim == 0 else as_matrix(self.k)
        if K.shape[1] != w:
            return None
        return self._static_model(dt, ports, K)


class Sum(_Static):
    """``out = Σ w_k·in_k`` over every input (missing ones count as 0).

    ``weights`` (default all 1) follow the inputs in :data:`PORTS` order, then in
    the file order of the edges; ``[1, -1]`` makes a difference.

    Examples
    --------
    >>> s = Sum("s", {"weights": [1.0, -1.0]}, np.random.default_rng(0))
    >>> s.step(0.0, 0.1, {"signal": [5.0, 2.0]})["signal"]
    3.0
    """

    parameters = {"weights": Param(None, "", "one weight per input; None: all 1")}
    lanes = "archself_blocks.lanes_static:SumLanes"

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        values = self._values(inputs)
        w = self.params["weights"]
        weights = [1.0] * len(values) if w is None else [float(x) for x in w]
        if len(weights) < len(values):
            raise ValueError(f"{len(values)} inputs but {len(weights)} weights")
        total: np.ndarray | None = None
        for wk, v in zip(weights, values, strict=False):
            if v is None:
                continue
            total = wk * v if total is None else total + wk * v
        return self._publish(total)

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        """``Σ w_k·in_k`` over the wired inputs (of one width)."""
        w = self.params["weights"]
        order = [(name, k, pt) for name in PORTS for k, pt in enumerate(inputs.get(name) or ())]
        weights = [1.0] * len(order) if w is None else [float(x) for x in w]
        ports, cols = [], []
        for (name, k, pt), wk in zip(order, weights, strict=False):
            if pt.size:
                ports.append((name, int(pt.size), k))
                cols.append(wk * np.eye(int(pt.size)))
        if not ports or len({c.shape[0] for c in cols}) != 1:
            return None
        return self._static_model(dt, ports, np.hstack(cols))


class Select(_Static):
    """Components ``index`` (a number or a list) of the first available input.

    With several inputs it is also a fail-over: the first that has a value this
    step (in :data:`PORTS` order, then edge order) is used.

    Examples
    --------
    >>> s = Select("s", {"index": 1}, np.random.default_rng(0))
    >>> s.step(0.0, 0.1, {"y": [None, [1.0, 2.0, 3.0]]})["measurement"]
    2.0
    """

    parameters = {
        "index": Param(0, "", "component, or list of components, to pass on", min=0, max=100000),
    }
    lanes = "archself_blocks.lanes_static:SelectLanes"

    def configure(self) -> None:
        idx = self.params["index"]
        self.idx = [int(i) for i in np.atleast_1d(idx)]
        self.scalar = np.ndim(idx) == 0

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        x = next((v for v in self._values(inputs) if v is not None), None)
        return self._publish(None if x is None else x[self.idx])

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        """Components ``index`` of the first wired input."""
        ports = self._first(inputs)
        if not ports or max(self.idx) >= ports[0][1]:
            return None
        D = np.zeros((len(self.idx), ports[0][1]))
        D[np.arange(len(self.idx)), self.idx] = 1.0
        return self._static_model(dt, ports, D)
