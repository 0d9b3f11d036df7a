"""A small system's run path in numpy (issue 38.4): scipy is the oracle, and stays unimported.

W, the influence solve, ρ(W), the singularity test, strong components and the NNLS of the
source fit use numpy up to their size bounds; each is checked here against the scipy
routine it stands in for, and a warm diff-drive run is checked to import no scipy at all;
so are warm runs of the blocks pack's files (their observer gains and discretizations
come from the design cache).
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.optimize
import scipy.sparse
from numpy.testing import assert_allclose
from scipy.sparse.csgraph import connected_components

from archself.linear.closed_loop import WholeLoop, strong_components
from archself.runtime.influence import (
    InfluenceSolver,
    SourceEstimator,
    SourceFit,
    is_singular,
    nnls,
    weight_matrix,
)

ROOT = Path(__file__).resolve().parent.parent
DIFFDRIVE = ROOT / "architectures" / "diffdrive.yaml"
inf = importlib.import_module("archself.runtime.influence")  # the attribute is a function


def _random_problems(seed: int, count: int):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        m, k = int(rng.integers(1, 25)), int(rng.integers(1, 12))
        yield rng.standard_normal((m, k)), rng.standard_normal(m)


def test_nnls_equals_scipy_on_random_full_rank_problems() -> None:
    """Unique solutions (tall, full column rank): x and ‖Ax − b‖ to 1e-10 of scipy's."""
    checked = 0
    for A, b in _random_problems(seed=11, count=400):
        if A.shape[0] < A.shape[1] or np.linalg.matrix_rank(A) < A.shape[1]:
            continue
        x, rnorm = nnls(A, b)
        x0, r0 = scipy.optimize.nnls(A, b)
        assert_allclose(x, x0, rtol=0, atol=1e-10)
        assert_allclose(rnorm, r0, rtol=0, atol=1e-10)
        assert np.all(x >= 0.0)
        checked += 1
    assert checked > 150


@pytest.mark.parametrize("case", ["zero column", "duplicate columns", "wide", "zero b",
                                  "b against every column", "zero A", "exact fit",
                                  "one row"])
def test_nnls_equals_scipy_on_degenerate_problems(case: str) -> None:
    """Where x is not unique (dependent columns, wide A) the fit A x and the residual are:
    both to 1e-10 of scipy's; x ≥ 0 always."""
    rng = np.random.default_rng(5)
    A, b = rng.standard_normal((8, 4)), rng.standard_normal(8)
    if case == "zero column":
        A[:, 2] = 0.0
    elif case == "duplicate columns":
        A[:, 1] = A[:, 0]
        A[:, 3] = 2.0 * A[:, 2]
    elif case == "wide":
        A, b = rng.standard_normal((3, 7)), rng.standard_normal(3)
    elif case == "zero b":
        b[:] = 0.0
    elif case == "b against every column":
        A, b = np.abs(A), -np.abs(b)
    elif case == "zero A":
        A[:] = 0.0
    elif case == "exact fit":
        b = A @ np.array([0.5, 0.0, 2.0, 0.1])
    else:
        A, b = A[:1], b[:1]
    x, rnorm = nnls(A, b)
    x0, r0 = scipy.optimize.nnls(A, b)
    assert np.all(x >= 0.0)
    assert_allclose(A @ x, A @ x0, rtol=0, atol=1e-10)
    assert_allclose(rnorm, r0, rtol=0, atol=1e-10)
    if case in ("zero b", "b against every column", "zero A"):
        assert not x.any()
    if case == "exact fit":
        assert_allclose(x, [0.5, 0.0, 2.0, 0.1], rtol=0, atol=1e-10)


def test_nnls_above_its_bound_is_scipys(monkeypatch) -> None:
    A, b = next(_random_problems(seed=3, count=1))
    monkeypatch.setattr(inf, "NNLS_NUMPY_MAX", 0)
    x, rnorm = nnls(A, b)
    x0, r0 = scipy.optimize.nnls(A, b)
    assert x.tobytes() == x0.tobytes() and rnorm == r0
    with pytest.raises(ValueError, match="shape"):
        nnls(A, b[:-1])


def _random_weights(seed: int, n: int, density: float = 0.2) -> list[tuple[str, str, float]]:
    rng = np.random.default_rng(seed)
    src, dst = np.nonzero(rng.random((n, n)) < density)
    return [(f"m{a}", f"m{b}", float(rng.uniform(0.0, 0.4))) for a, b in zip(src, dst,
                                                                           strict=True)]


def test_dense_weight_matrix_and_solver_agree_with_the_sparse_ones() -> None:
    """Dense W (parallel edges added) equals the CSR one; P r equals scipy's sparse LU
    solve; SourceEstimator and SourceFit give the same estimates from either W."""
    names = [f"m{i}" for i in range(12)]
    edges = _random_weights(seed=2, n=12) + [("m0", "m1", 0.1), ("m0", "m1", 0.05)]
    W = weight_matrix(names, edges, scale=0.5, dense_max=inf.DENSE_MAX)
    S = weight_matrix(names, edges, scale=0.5)
    assert isinstance(W, np.ndarray) and scipy.sparse.issparse(S)
    assert_allclose(W, S.toarray(), rtol=0, atol=1e-15)
    dense, sparse = InfluenceSolver(), InfluenceSolver(dense_max=0)
    dense.set_matrix(W), sparse.set_matrix(S)
    r = np.random.default_rng(4).uniform(0.0, 2.0, 12)
    assert_allclose(dense.solve(r), sparse.solve(r), rtol=1e-12, atol=1e-12)
    observed = np.arange(12) % 3 != 0
    assert_allclose(SourceEstimator(W, observed).estimate(r),
                    SourceEstimator(S, observed).estimate(r), rtol=1e-12, atol=1e-12)
    assert_allclose(SourceFit(W, observed).estimate(r), SourceFit(S, observed).estimate(r),
                    rtol=1e-10, atol=1e-10)


def test_the_dense_solver_refuses_what_the_sparse_one_refuses() -> None:
    """A singular I − Wᵀ (a unit cycle) and a non-finite W raise on both paths."""
    cycle = np.array([[0.0, 1.0], [1.0, 0.0]])
    for dense_max in (inf.DENSE_MAX, 0):
        with pytest.raises(np.linalg.LinAlgError):
            InfluenceSolver(dense_max).set_matrix(scipy.sparse.csr_matrix(cycle))
    assert is_singular(cycle) and not is_singular(0.5 * cycle)
    with pytest.raises(ValueError, match="infs or NaNs"):
        InfluenceSolver().set_matrix(np.array([[0.0, np.nan], [0.0, 0.0]]))


def _same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.array_equal(a[:, None] == a[None, :], b[:, None] == b[None, :]))


@pytest.mark.parametrize("n, density", [(1, 0.5), (7, 0.0), (30, 0.05), (60, 0.03),
                                        (200, 0.006)])
def test_strong_components_match_scipy(n: int, density: float) -> None:
    rng = np.random.default_rng(n)
    A = (rng.random((n, n)) < density) * rng.uniform(-1.0, 1.0, (n, n))
    labels = strong_components(A)
    _, oracle = connected_components(scipy.sparse.csr_matrix(A), directed=True,
                                     connection="strong")
    assert _same_partition(labels, oracle)
    assert _same_partition(strong_components(scipy.sparse.csr_matrix(A)), oracle)
    assert labels.max(initial=-1) + 1 == len(set(oracle.tolist()))


def test_whole_loop_modes_the_same_for_a_dense_and_a_sparse_a() -> None:
    """A dense A (numpy components) and the same A sparse (scipy's) give the same modes."""
    A = np.zeros((5, 5))
    A[0, 1], A[1, 0], A[0, 0] = 0.6, -0.7, 0.5  # a decaying oscillation
    A[2, 2], A[3, 4], A[4, 3], A[1, 2] = 1.00005, 1.2, 0.9, 0.3  # marginal; ±1.039: unstable
    owners = ["a", "a", "b", "c", "c"]
    labels = [f"x[{i}]" for i in range(5)]
    dense = WholeLoop(A, 0.1, 1, owners, labels, ["a", "b", "c"]).modes()
    sparse = WholeLoop(scipy.sparse.csr_matrix(A), 0.1, 1, owners, labels,
                       ["a", "b", "c"]).modes()
    assert dense[0] == pytest.approx(sparse[0], rel=1e-12)
    assert dense[0] == pytest.approx(np.sqrt(1.2 * 0.9), rel=1e-12)
    for d, s in zip(dense[1:], sparse[1:], strict=True):
        assert [m.magnitude for m in d] == pytest.approx([m.magnitude for m in s], rel=1e-12)
        assert [m.shares for m in d] == [m.shares for m in s]
    assert len(dense[1]) == 1 and len(dense[2]) == 2


def _cold_then_warm(tmp_path: Path, path: Path, scenario: str, libraries: tuple[str, ...]
                    ) -> tuple[list[str], list[str], list[subprocess.CompletedProcess]]:
    """``archself simulate PATH --scenario S`` in two fresh processes sharing one empty
    design cache; each prints, last, the modules of ``libraries`` it imported. The two
    outputs (lines) and the processes."""
    code = (
        "import runpy, sys\n"
        f"sys.argv = ['archself', 'simulate', {str(path)!r}, '--scenario', {scenario!r}]\n"
        "try:\n"
        "    runpy.run_module('archself', run_name='__main__')\n"
        "except SystemExit as exc:\n"
        "    assert not exc.code, exc.code\n"
        f"print(sorted(m for m in sys.modules if m.split('.')[0] in {libraries!r}))\n"
    )
    env = {**os.environ, "ARCHSELF_CACHE_DIR": str(tmp_path)}
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           env=env, cwd=ROOT) for _ in range(2)]
    cold, warm = (r.stdout.split("\n") for r in runs)
    return cold, warm, runs


@pytest.mark.parametrize("name", ["thermal_zone", "heated_chain", "motor_drive"])
def test_a_warm_blocks_simulate_imports_no_control_or_scipy(tmp_path, name) -> None:
    """The blocks pack's designs (Luenberger poles, zero-order holds) come from the design
    cache on a warm run: neither python-control nor scipy is imported; the cold, first
    process designs with python-control, and both print the same result."""
    cold, warm, runs = _cold_then_warm(tmp_path, ROOT / "architectures" / f"{name}.yaml",
                                       "nominal", ("scipy", "control"))
    assert "'control'" in cold[-2], runs[0].stderr[-2000:]
    assert warm[-2] == "[]", runs[1].stderr[-2000:]
    assert cold[:-2] == warm[:-2] and any("switches (adaptive)" in line for line in warm)


def test_a_warm_diffdrive_simulate_imports_no_scipy(tmp_path) -> None:
    """``archself simulate diffdrive --scenario imu_drift`` (adaptive), design cache warm:
    W, ρ(W), the solves, the source fit and the stability check of a 10-module system
    need numpy only; the first, cold process designs with python-control (scipy)."""
    cold, warm, runs = _cold_then_warm(tmp_path, DIFFDRIVE, "imu_drift", ("scipy",))
    assert "scipy" in cold[-2], runs[0].stderr[-2000:]
    assert warm[-2] == "[]", runs[1].stderr[-2000:]
    assert "switches (adaptive): t = " in runs[1].stdout
