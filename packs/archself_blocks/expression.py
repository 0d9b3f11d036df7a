"""``generic.expression``: a static non-linear block, an arithmetic expression over named inputs.

The expression is parsed once (Python's :mod:`ast`) and every node is checked against
a whitelist: numbers, input names (a component as ``name[k]``), ``+ - * / **``, unary
``-``/``+`` and the functions of :data:`FUNCTIONS`. Anything else — attributes, calls of
other names, comparisons, strings, lambdas — is refused with its column, so ``archself
validate`` reports a bad expression at the module's ``expression`` parameter and no
text of the file is ever executed. The names that are not functions are the block's
inputs: an edge delivers each under its port (``to: loss.T``).
"""

from __future__ import annotations

import ast
import functools
import operator
from collections.abc import Callable
from typing import Any

import numpy as np

from archself.model.ports import Output
from archself.modules.base import LinearModel, Param
from archself_blocks.signals import PORTS, _Static

__all__ = ["Expression", "FUNCTIONS", "MAX_EXPRESSION_CHARS", "parse_expression"]

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
        if type(node.value) not in (int, float):
            raise _refuse(node, f"{node.value!r} is not a number")
        value = np.float64(node.value)
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
        ports = [(n, int(pt.size), k) for n in self.names for k, pt in enumerate(inputs.get(n) or ())
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
