"""Benchmarks of archself (pytest-benchmark): not part of the test suite.

Run them with ``pytest bench/ -p no:cacheprovider --benchmark-columns=min,mean,max,rounds``
(``pip install -e '.[bench]'``); results and targets are in docs/benchmarks.md.
"""

from __future__ import annotations

import functools
import re
from pathlib import Path

from archself.resources import single_thread_blas

single_thread_blas()  # as the archself command does, before numpy loads

import numpy as np  # noqa: E402
import pytest  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DIFFDRIVE = ROOT / "architectures" / "diffdrive.yaml"
_EDGE = re.compile(r'\{"from": "(m\d+)", "to": "(m\d+)", "weight": ([0-9.eE+-]+)')


@pytest.fixture(scope="session")
def diffdrive():
    from archself.model.loader import load_architecture

    return load_architecture(DIFFDRIVE).arch


@functools.lru_cache(maxsize=8)
def generated_w(n: int, seed: int = 1):
    """W of a generated n-module DAG, read straight from the generator's edge lines.

    (Loading a 10^5-module YAML file through the loader takes minutes; the graph
    is the same.)
    """
    from archself.model.generate import generate_architecture
    from archself.runtime.influence import weight_matrix

    text = generate_architecture(n, seed=seed)
    edges = [(a, b, float(w)) for a, b, w in _EDGE.findall(text)]
    return weight_matrix([f"m{i}" for i in range(n)], edges)


@pytest.fixture(scope="session")
def rng():
    return np.random.default_rng(0)
