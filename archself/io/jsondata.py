"""Plain JSON data: the one cleaner for everything archself writes as JSON.

Decision records, run summaries and traces, campaign summaries: numpy scalars and
arrays become Python numbers and lists, tuples and sets lists, mapping keys
strings, and non-finite floats ``None`` (JSON has no NaN). It imports nothing
heavy, so ``archself explain`` stays free of numpy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["JsonLimitError", "finite_or_none", "json_kind", "jsonable", "loads"]


class JsonLimitError(ValueError):
    """A JSON text past what archself reads: nested too deeply, or an integer of more
    digits than Python converts (``yaml_nodes.MAX_INT_DIGITS``); ``str`` says which."""


def _int(digits: str) -> int:
    from archself.io.yaml_nodes import MAX_INT_DIGITS

    if len(digits) > MAX_INT_DIGITS:
        raise JsonLimitError(f"an integer of {len(digits.lstrip('-')):,} digits (at most "
                             f"{MAX_INT_DIGITS:,})")
    return int(digits)


def loads(text: str | bytes, **kw: Any) -> Any:
    """:func:`json.loads` with the reading limits of architecture files: an integer of
    more than 4,300 digits or nesting past Python's recursion limit is a
    :class:`JsonLimitError` (a ``ValueError``) that says which, never a bare
    ``ValueError`` or ``RecursionError``. For traces, results and runs files.

    Examples
    --------
    >>> loads('{"a": [1, 2.5]}')
    {'a': [1, 2.5]}
    >>> loads("[" * 100_000 + "]" * 100_000)
    Traceback (most recent call last):
    ...
    archself.io.jsondata.JsonLimitError: nested too deeply
    """
    import json

    try:
        return json.loads(text, parse_int=_int, **kw)
    except RecursionError:
        raise JsonLimitError("nested too deeply") from None


def finite_or_none(v: float) -> float | None:
    """``v`` as a float, or None when it is NaN or infinite (JSON has neither).

    Examples
    --------
    >>> finite_or_none(2), finite_or_none(float("nan"))
    (2.0, None)
    """
    return float(v) if v == v and not math.isinf(v) else None


def json_kind(x: Any) -> str:
    """What a JSON value is, for a message: ``an object``, ``a list``, ``a string``, ``null``.

    Examples
    --------
    >>> json_kind({}), json_kind(None), json_kind(1.5)
    ('an object', 'null', 'float')
    """
    return {dict: "an object", list: "a list", str: "a string", type(None): "null"}.get(
        type(x), type(x).__name__)


def jsonable(x: Any) -> Any:
    """``x`` as plain JSON data (dict, list, str, int, float, bool, None).

    Mappings become dicts with string keys; lists and tuples lists; sets lists
    sorted by their text; numpy arrays and scalars (anything with ``tolist``)
    their Python values; other numbers (``__float__``) floats; non-finite floats
    ``None``; anything else its ``str``.

    Examples
    --------
    >>> import numpy as np
    >>> jsonable({"a": np.float64(1.5), "b": [np.nan, 2], "c": (1, 2), 3: {"y", "x"}})
    {'a': 1.5, 'b': [None, 2], 'c': [1, 2], '3': ['x', 'y']}
    >>> jsonable([np.array([1.0, np.inf]), np.int64(4), np.bool_(True)])
    [[1.0, None], 4, True]
    """
    tp = type(x)
    if tp is float:
        return x if math.isfinite(x) else None
    if x is None or tp is str or tp is int or tp is bool:
        return x
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (set, frozenset)):
        return [jsonable(v) for v in sorted(x, key=str)]
    if isinstance(x, (bool, str)):
        return x
    if hasattr(x, "tolist") and not isinstance(x, (int, float)):
        return jsonable(x.tolist())
    if isinstance(x, int):
        return int(x)
    if isinstance(x, float) or hasattr(x, "__float__"):
        v = float(x)
        return v if math.isfinite(v) else None
    return str(x)
