"""Signal blocks: a reference generator, the static gain, sum and select blocks, and expressions.

The static blocks take their input under any signal name of the library and
publish their result under every one of them (:data:`PORTS`), so they fit on any
edge: ``sensor --measurement--> gain --measurement--> pid``.

``generic.expression`` (:class:`Expression`) is a static non-linear block: its
arithmetic is parsed once (Python's :mod:`ast`) and every node is checked against a
whitelist — numbers, input names (a component as ``name[k]``), ``+ - * / **``, unary
``-``/``+`` and the functions of :data:`FUNCTIONS`. Anything else (attributes, calls of
other names, comparisons, strings, lambdas) is refused with its column, so ``archself
validate`` reports a bad expression at the module's ``expression`` parameter and no text
of the file is ever executed. The names that are not functions are the block's inputs:
an edge delivers each under its port (``to: loss.T``).
"""

from __future__ import annotations

import ast
import functools
import operator
from collections.abc import Callable
from typing import Any

import numpy as np

from archself.model.architecture import Input, Output
from archself.modules.base import LinearModel, Param, RuntimeModule
from archself_blocks.lti import as_matrix, as_vector

__all__ = ["PORTS", "Reference", "Gain", "Sum", "Select", "Expression", "FUNCTIONS",
           "MAX_EXPRESSION_CHARS", "parse_expression"]

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


#: The longest expression text a file may give.
MAX_EXPRESSION_CHARS = 2000


def _clip(x: Any, lo: Any, hi: Any) -> Any:
    return np.minimum(np.maximum(x, lo), hi)


#: Function name → (callable on arrays, least and most arguments).
FUNCTIONS: dict[str, tuple[Callable[..., Any], int, int]] = {
    "min": (lambda *a: functools.reduce(np.minimum, a), 2, 16),
    "max": (lambda *a: functools.reduce(np.maximum, a), 2, 16),
    "abs": (np.abs, 1, 1),
    "exp": (np.exp, 1, 1),
    "log": (np.log, 1, 1),
    "sqrt": (np.sqrt, 1, 1),
    "clip": (_clip, 3, 3),
}
_BINARY: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
    ast.Div: operator.truediv, ast.Pow: operator.pow,
}
_UNARY: dict[type, Callable[[Any], Any]] = {ast.USub: operator.neg, ast.UAdd: operator.pos}
_ALLOWED = "numbers, input names (name[k] for a component), + - * / **, " + ", ".join(FUNCTIONS)

Compiled = Callable[[dict[str, Any]], Any]


def _refuse(node: ast.AST, what: str) -> ValueError:
    return ValueError(f"expression: column {getattr(node, 'col_offset', 0) + 1}: {what}; "
                      f"it may hold {_ALLOWED}")


def _name(node: ast.Name, names: set[str]) -> Compiled:
    if node.id in FUNCTIONS:
        raise _refuse(node, f"'{node.id}' is a function, not an input")
    names.add(node.id)
    key = node.id
    return lambda env: env[key]


def _component(node: ast.Subscript, names: set[str]) -> Compiled:
    k = node.slice
    if not (isinstance(node.value, ast.Name) and isinstance(k, ast.Constant)
            and type(k.value) is int and 0 <= k.value <= 100000):
        raise _refuse(node, "only an input's component name[k], k a whole number ≥ 0, "
                      "is allowed as an index")
    key, i = _name(node.value, names), k.value
    return lambda env: key(env)[..., i:i + 1]  # a 1-wide column, in lanes too


def _call(node: ast.Call, names: set[str]) -> Compiled:
    fn = node.func.id if isinstance(node.func, ast.Name) else None
    if fn not in FUNCTIONS or node.keywords:
        raise _refuse(node, f"'{ast.unparse(node.func)}' is no allowed function call")
    f, lo, hi = FUNCTIONS[fn]
    if not lo <= len(node.args) <= hi:
        count = str(lo) if lo == hi else f"{lo} to {hi}"
        raise _refuse(node, f"{fn}() takes {count} arguments, not {len(node.args)}")
    args = [_compile(a, names) for a in node.args]
    return lambda env: f(*(a(env) for a in args))


def _compile(node: ast.AST, names: set[str]) -> Compiled:
    """A callable of the input values for one checked node (recursively)."""
    if isinstance(node, ast.Constant):
        number = node.value
        if not isinstance(number, (int, float)) or isinstance(number, bool):
            raise _refuse(node, f"{number!r} is not a number")
        value = np.float64(number)
        return lambda env: value
    if isinstance(node, ast.Name):
        return _name(node, names)
    if isinstance(node, ast.Subscript):
        return _component(node, names)
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        op, a, b = _BINARY[type(node.op)], _compile(node.left, names), _compile(node.right, names)
        return lambda env: op(a(env), b(env))
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        op1, x = _UNARY[type(node.op)], _compile(node.operand, names)
        return lambda env: op1(x(env))
    if isinstance(node, ast.Call):
        return _call(node, names)
    raise _refuse(node, f"'{ast.unparse(node)}' ({type(node).__name__}) is not allowed")


def parse_expression(text: Any) -> tuple[Compiled, tuple[str, ...]]:
    """The checked expression as a callable of ``{input name: array}``, and its input names.

    Raises
    ------
    ValueError
        The text is not an expression of the allowed subset (the message names the
        parameter ``expression`` and the column).

    Examples
    --------
    >>> f, names = parse_expression("k * damper[0] * (T - max(T_out, 0))")
    >>> names
    ('T', 'T_out', 'damper', 'k')
    >>> parse_expression("__import__('os')")
    Traceback (most recent call last):
    ...
    ValueError: expression: column 1: '__import__' is no allowed function call; it may hold ...
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError("expression: expected the text of an arithmetic expression")
    if len(text) > MAX_EXPRESSION_CHARS:
        raise ValueError(f"expression: {len(text)} characters, more than the cap of "
                         f"{MAX_EXPRESSION_CHARS}")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except (SyntaxError, RecursionError, MemoryError) as exc:
        col = getattr(exc, "offset", None) or 1
        raise ValueError(f"expression: column {col}: not an arithmetic expression "
                         f"({getattr(exc, 'msg', type(exc).__name__)})") from None
    names: set[str] = set()
    try:
        fn = _compile(tree.body, names)
    except RecursionError:
        raise ValueError("expression: nested too deeply") from None
    if not names:
        raise ValueError("expression: names no input (a constant is a generic.gain's offset)")
    return fn, tuple(sorted(names))


class Expression(_Static):
    """``out = f(inputs)``: a static non-linearity written in the file.

    ``expression`` is arithmetic over named inputs (see :func:`parse_expression`),
    e.g. the ventilation loss ``-120 * damper * (T[0] - T_out[0])`` of a zone. Each
    name is an input port, delivered by an edge ``to: block.name``; a number, a list or
    a vector; ``name[k]`` is its component ``k`` (``T_out[0]``, the value of a
    ``generic.reference``). While an input is absent the output is absent. The result
    is published under every library signal name (as the static blocks), a number
    when it has one component; with ``width`` > 1 a vector of that length, zeros but the
    result at ``channel`` (one input of a multi-input plant, as an actuator's).

    Its linear model is the Jacobian at the inputs of the last step (central
    differences), so the stability filter sees the loop it closes; before a first step
    it has none.

    Examples
    --------
    >>> e = Expression("e", {"expression": "2 * a * (b[1] - 1)"}, np.random.default_rng(0))
    >>> e.step(0.0, 0.1, {"a": 3.0, "b": [0.0, 4.0]})["u"]
    18.0
    """

    state_fields = ()
    parameters = {
        "expression": Param(doc="arithmetic over the input names: numbers, + - * / **, "
                            "name[k], min, max, abs, exp, log, sqrt, clip"),
        "channel": Param(0, "", "component of the output the result is, with width > 1",
                         min=0, max=100000),
        "width": Param(1, "", "length of the output vector (zeros but at channel); 1: the "
                       "result as it is", min=1, max=100000),
    }
    ports = tuple(Output(s, doc="the result, under every library signal name") for s in PORTS)
    lanes = "archself_blocks.lanes_static:ExpressionLanes"

    def configure(self) -> None:
        self.fn, self.names = parse_expression(self.params["expression"])
        self.point: dict[str, np.ndarray] | None = None
        self.channel, self.width = int(self.params["channel"]), int(self.params["width"])
        if self.width > 1 and self.channel >= self.width:
            raise ValueError(f"channel: {self.channel} is outside an output of width {self.width}")

    def evaluate(self, env: dict[str, np.ndarray]) -> np.ndarray:
        """The expression on input vectors, placed at ``channel`` of ``width`` (no warning
        for inf or NaN: health judges them). Rows of lanes ``(L, w)`` give ``(L, width)``."""
        with np.errstate(all="ignore"):
            y = np.atleast_1d(np.asarray(self.fn(env), dtype=float))
        if self.width <= 1:
            return y
        if y.shape[-1] != 1:
            raise ValueError(f"a result of {y.shape[-1]} components for one channel")
        out = np.zeros((*y.shape[:-1], self.width))
        out[..., self.channel] = y[..., 0]
        return out

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        env: dict[str, np.ndarray] = {}
        for name in self.names:
            v = inputs.get(name)
            if not isinstance(v, (int, float, list, np.ndarray, np.floating)):
                return self._publish(None)
            env[name] = np.atleast_1d(np.asarray(v, dtype=float))
        self.point = env
        return self._publish(self.evaluate(env))

    def linear_model(self, dt: float, inputs: Any) -> LinearModel | None:
        """The Jacobian at the last step's inputs on the wired inputs with a model.

        Inputs without a model (a reference, a constant) are held at their values.
        """
        point = self.point
        if point is None:
            return None
        ports = [(n, int(pt.size), k) for n in self.names
                 for k, pt in enumerate(inputs.get(n) or ())
                 if pt.size and pt.size == point[n].size]
        if not ports:
            return None
        cols = []
        for name, width, _ in ports:
            for j in range(width):
                h = 1e-6 * max(1.0, abs(float(point[name][j])))
                hi, lo = dict(point), dict(point)
                hi[name], lo[name] = point[name].copy(), point[name].copy()
                hi[name][j] += h
                lo[name][j] -= h
                cols.append((self.evaluate(hi) - self.evaluate(lo)) / (2 * h))
        D = np.column_stack(cols)
        return self._static_model(dt, ports, D) if np.isfinite(D).all() else None
