"""Property tests: loading and checking raise nothing but archself's own errors."""

from __future__ import annotations

import copy
import json
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from archself.check import check
from archself.errors import ArchselfError
from archself.model.loader import load_data, load_text

from conftest import DIFFDRIVE

BASE, _ = load_data(DIFFDRIVE.read_text(encoding="utf-8"))

junk = st.recursive(
    st.none() | st.booleans() | st.integers(-10**6, 10**6)
    | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner,
                                                                 max_size=3),
    max_leaves=6,
)


def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


ALL_PATHS = [p for p in _paths(BASE) if p]


def _load_and_check(text: str) -> None:
    try:
        check(load_text(text, "fuzz.yaml"))
    except ArchselfError as exc:
        assert str(exc).startswith("fuzz.yaml"), str(exc)
        assert "\n" not in str(exc)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(max_size=300))
def test_arbitrary_text(text: str) -> None:
    _load_and_check(text)


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.tuples(st.sampled_from(ALL_PATHS), st.sampled_from(["delete", "replace", "rename"]),
                  junk),
        min_size=1, max_size=3,
    )
)
def test_mutated_valid_file(mutations: list[tuple[tuple, str, Any]]) -> None:
    data = copy.deepcopy(BASE)
    for path, op, value in mutations:
        parent: Any = data
        try:
            for p in path[:-1]:
                parent = parent[p]
            last = path[-1]
            if op == "delete":
                del parent[last]
            elif op == "replace":
                parent[last] = value
            elif isinstance(parent, dict) and last in parent:
                parent[f"{last}x"] = parent.pop(last)
        except (KeyError, IndexError, TypeError):
            continue  # an earlier mutation removed the path
    text = json.dumps(data, allow_nan=True)  # JSON is YAML 1.2
    _load_and_check(text)


@settings(max_examples=30, deadline=None)
@given(st.sampled_from(ALL_PATHS), st.floats(min_value=-5, max_value=5, allow_nan=False))
def test_numeric_perturbations_of_valid_file(path: tuple, value: float) -> None:
    data = copy.deepcopy(BASE)
    parent: Any = data
    for p in path[:-1]:
        parent = parent[p]
    if isinstance(parent[path[-1]], (int, float)) and not isinstance(parent[path[-1]], bool):
        parent[path[-1]] = value
    _load_and_check(json.dumps(data))
