"""Selectors given the array of z values choose exactly what they choose from the mapping."""

from __future__ import annotations

import math

import numpy as np
import pytest

from archself.runtime.candidates import HysteresisSelector, ThresholdSelector, TopKSelector
from archself.runtime.decisions import ValueMap


def _cycles(seed: int, n: int = 40, cycles: int = 30) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(cycles):
        z = rng.normal(0.0, 0.6, n)
        z[rng.random(n) < 0.3] = 0.0
        z[rng.random(n) < 0.1] = 0.75  # ties, ranked by name
        z[rng.random(n) < 0.1] = -0.75
        z[rng.random(n) < 0.02] = math.nan
        out.append(z)
    return out


@pytest.mark.parametrize(
    "make",
    [
        lambda: ThresholdSelector(0.55),
        lambda: TopKSelector(5),
        lambda: HysteresisSelector(on=0.6, off=0.3),
    ],
)
def test_select_with_values_matches_mapping(make) -> None:
    names = [f"m{i}" for i in range(40)]
    index = {n: i for i, n in enumerate(names)}
    plain, fast = make(), make()
    for z in _cycles(4):
        as_dict = dict(zip(names, z.tolist(), strict=True))
        as_map = ValueMap(names, index, z)
        assert repr(list(as_map.items())) == repr(list(as_dict.items()))  # NaN != NaN
        assert as_map.get("x", 1) == 1 and repr(as_map.get("m3")) == repr(as_dict["m3"])
        assert fast.select(as_map, z) == plain.select(as_dict)


def test_value_map_pickles_and_copies() -> None:
    import copy
    import pickle

    m = ValueMap(["a", "b"], {"a": 0, "b": 1}, np.array([0.25, -1.5]))
    for back in (pickle.loads(pickle.dumps(m)), copy.deepcopy(m)):
        assert isinstance(back, ValueMap) and back == {"a": 0.25, "b": -1.5}
        assert list(back.items()) == [("a", 0.25), ("b", -1.5)]
