"""Selectors given the array of z values choose exactly what they choose from the mapping."""

from __future__ import annotations

import math

import numpy as np
import pytest

from archself.runtime.knowledge import ValueMap
from archself.runtime.planner import HysteresisSelector, ThresholdSelector, TopKSelector


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
@pytest.mark.parametrize("n", [12, 40, 120])
def test_select_with_values_matches_mapping(make, n: int) -> None:
    names = [f"m{i}" for i in range(n)]
    index = {n: i for i, n in enumerate(names)}
    plain, fast = make(), make()
    for z in _cycles(4, n):
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


def _ranked_by_rounded_key(z: dict[str, float], tau: float) -> list[str]:
    """The ranking rule written plainly: |z| to 12 digits, descending, then the name."""
    hits = [n for n, v in z.items() if abs(v) >= tau]
    return sorted(hits, key=lambda n: (-float(f"{abs(z[n]):.12g}"), n))


@pytest.mark.parametrize("seed", range(20))
def test_ranking_ties_to_twelve_digits_by_name(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 30
    base = rng.choice([0.7, 1.3, 2.832840213394304, 5.5], n)
    # exact ties, ties in the last bits (a different BLAS), and clearly distinct values
    noise = rng.choice([0.0, 1.0, -1.0, 1e3], n) * np.spacing(base) * rng.integers(1, 8, n)
    names = [f"m{i:02d}" for i in rng.permutation(n)]
    z = dict(zip(names, (base + noise) * rng.choice([1, -1], n), strict=True))
    values = np.array(list(z.values()))
    expected = _ranked_by_rounded_key(z, 0.55)
    assert ThresholdSelector(0.55).select(z) == expected
    assert ThresholdSelector(0.55).select(z, values) == expected
    z2 = {k: v * (1 + 1e-15) for k, v in z.items()}  # the last bits of another build
    assert ThresholdSelector(0.55).select(z2) == _ranked_by_rounded_key(z2, 0.55)


def test_ranking_by_hand() -> None:
    # b and a differ in the last bit only (a tie, by name); d is 1e-9 smaller (not a tie)
    z = {"b": 1.0, "a": 1.0 + 2**-52, "c": -2.0, "d": 1.0 - 1e-9, "e": 0.1}
    expected = ["c", "a", "b", "d"]
    assert ThresholdSelector(0.5).select(z) == expected
    assert ThresholdSelector(0.5).select(z, np.array(list(z.values()))) == expected
    assert TopKSelector(4).select(z, np.array(list(z.values()))) == expected
