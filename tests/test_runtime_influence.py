"""Influence propagation z = (I − Wᵀ)⁻¹ r (Eq. 13–15) and the candidate selectors."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from archself.runtime.influence import (
    InfluenceSolver,
    influence,
    spectral_radius,
    weight_matrix,
)
from archself.runtime.planner import (
    HysteresisSelector,
    ThresholdSelector,
    TopKSelector,
    threshold_candidates,
    top_k_candidates,
)


def neumann_influence(W, r, terms: int = 200) -> np.ndarray:
    """Truncated Neumann series ``Σ_k (Wᵀ)^k r`` of Eq. 15 (the oracle).

    Converges to :func:`influence` when ρ(W) < 1.
    """
    Wt = W.T if scipy.sparse.issparse(W) else np.asarray(W, dtype=float).T
    term = np.asarray(r, dtype=float).ravel().copy()
    total = term.copy()
    for _ in range(terms):
        term = Wt @ term
        total += term
        if not np.any(term):
            break
    return np.asarray(total).ravel()


def test_weight_matrix_orientation_and_parallel_edges():
    W = weight_matrix(["a", "b", "c"], [("a", "b", 0.5), ("a", "b", 0.1), ("x", "c", 0.3)])
    assert scipy.sparse.isspmatrix_csr(W) or isinstance(W, scipy.sparse.csr_array)
    dense = W.toarray()
    assert dense[0, 1] == pytest.approx(0.6)  # W[j, i] = weight of j -> i, parallel edges add
    assert dense.sum() == pytest.approx(0.6)  # the edge from an unknown module is ignored


def test_weight_matrix_rejects_negative():
    with pytest.raises(ValueError):
        weight_matrix(["a", "b"], [("a", "b", -0.1)])


def test_chain_multi_hop():
    """a → b → c, residual only at a: z_c = ω_ab·ω_bc·r_a (upstream aggregation)."""
    w_ab, w_bc, r_a = 0.7, 0.4, 2.0
    W = weight_matrix(["a", "b", "c"], [("a", "b", w_ab), ("b", "c", w_bc)])
    r = np.array([r_a, 0.0, 0.0])
    z = influence(W, r)
    assert_allclose(z, [r_a, w_ab * r_a, w_ab * w_bc * r_a])
    assert_allclose(z, neumann_influence(W, r))
    # a residual at the end of the chain does not flow upstream
    assert_allclose(influence(W, [0.0, 0.0, 1.0]), [0.0, 0.0, 1.0])


def test_cycle_matches_neumann_series():
    W = weight_matrix(["a", "b", "c"], [("a", "b", 0.5), ("b", "c", 0.5), ("c", "a", 0.5)])
    assert spectral_radius(W) == pytest.approx(0.5)
    r = np.array([1.0, 0.0, 0.0])
    assert_allclose(influence(W, r), neumann_influence(W, r), rtol=1e-12)
    # geometric sum around the loop: z_a = 1 / (1 − 0.125)
    assert influence(W, r)[0] == pytest.approx(1 / (1 - 0.125))


def test_solver_reuses_factorization():
    W = weight_matrix(["a", "b"], [("a", "b", 0.5)])
    solver = InfluenceSolver()
    assert solver.set_matrix(W, key="k1") is True
    assert solver.set_matrix(W, key="k1") is False
    for r in ([1.0, 0.0], [0.0, 1.0], [2.0, 3.0]):
        z = solver.solve(r)
        assert_allclose((np.eye(2) - W.toarray().T) @ z, r)
    assert solver.factorizations == 1
    W2 = weight_matrix(["a", "b"], [("a", "b", 0.2)])
    assert solver.set_matrix(W2, key="k2") is True
    assert solver.factorizations == 2
    # without an explicit key the matrix fingerprint is used
    s2 = InfluenceSolver()
    s2.set_matrix(W2)
    s2.set_matrix(weight_matrix(["a", "b"], [("a", "b", 0.2)]))
    assert s2.factorizations == 1


def test_solver_singular_raises():
    W = np.array([[0.0, 1.0], [1.0, 0.0]])  # ρ = 1: I − Wᵀ singular
    with pytest.raises(np.linalg.LinAlgError):
        InfluenceSolver().set_matrix(W)
    with pytest.raises(np.linalg.LinAlgError):
        InfluenceSolver(dense_max=0).set_matrix(scipy.sparse.csr_matrix(W))


def test_solver_errors():
    s = InfluenceSolver()
    with pytest.raises(RuntimeError):
        s.solve([1.0])
    s.set_matrix(np.zeros((2, 2)))
    with pytest.raises(ValueError):
        s.solve([1.0, 2.0, 3.0])


def test_spectral_radius_small():
    assert spectral_radius(np.zeros((3, 3))) == 0.0
    assert spectral_radius(np.zeros((0, 0))) == 0.0
    assert spectral_radius([[0.0, 0.9], [0.0, 0.0]]) == pytest.approx(0.0)  # nilpotent


@st.composite
def dag_weights(draw):
    n = draw(st.integers(min_value=1, max_value=12))
    density = draw(st.floats(min_value=0.0, max_value=1.0))
    seed = draw(st.integers(min_value=0, max_value=2**31 - 1))
    rng = np.random.default_rng(seed)
    W = np.triu(rng.uniform(0.0, 1.0, (n, n)), k=1) * (rng.uniform(size=(n, n)) < density)
    # optional back edges, scaled so that ρ(W) < 1
    if draw(st.booleans()):
        W = W + np.tril(rng.uniform(0.0, 0.5, (n, n)), k=-1) * (rng.uniform(size=(n, n)) < 0.2)
    rho = spectral_radius(W)
    if rho >= 0.9:
        W = W * (0.9 / rho)
    perm = rng.permutation(n)
    W = W[np.ix_(perm, perm)]
    r = rng.normal(size=n)
    return W, r


@settings(max_examples=60, deadline=None)
@given(dag_weights())
def test_property_solves_linear_system(case):
    W, r = case
    # dense LU and sparse LU
    for dense_max in (400, 0):
        solver = InfluenceSolver(dense_max=dense_max)
        solver.set_matrix(scipy.sparse.csr_matrix(W))
        z = solver.solve(r)
        assert_allclose((np.eye(len(r)) - W.T) @ z, r, atol=1e-9)
        assert_allclose(z, neumann_influence(W, r, terms=2000), atol=1e-7)


@settings(max_examples=30, deadline=None)
@given(dag_weights())
def test_property_nonnegative_residuals_give_nonnegative_influence(case):
    W, r = case
    z = influence(W, np.abs(r))
    assert np.all(z >= np.abs(r) - 1e-12)  # z_i = r_i + Σ_j W_ji z_j ≥ r_i


def test_large_sparse_dag_correctness():
    """A 50 000-node random sparse DAG: sparse LU solves (I − Wᵀ) z = r exactly."""
    rng = np.random.default_rng(7)
    n, m = 50_000, 150_000
    src = rng.integers(0, n - 1, size=m)
    dst = src + 1 + (rng.integers(0, 50, size=m) % (n - 1 - src))  # forward edges only: a DAG
    w = rng.uniform(0.0, 0.3, size=m)
    names = [f"m{i}" for i in range(n)]
    W = weight_matrix(names, zip((names[i] for i in src), (names[j] for j in dst), w, strict=True))
    r = np.zeros(n)
    r[rng.integers(0, n, size=100)] = rng.uniform(0, 1, size=100)
    solver = InfluenceSolver()
    solver.set_matrix(W)
    z = solver.solve(r)
    resid = z - W.T @ z - r
    assert np.max(np.abs(resid)) < 1e-9
    assert np.all(z >= r - 1e-12)
    assert spectral_radius(W) < 1e-6  # nilpotent: every eigenvalue of a DAG is 0


def test_large_sparse_spectral_radius_by_components():
    """Many 3-cycles plus one large strongly connected block, checked against dense."""
    rng = np.random.default_rng(3)
    edges = []
    for k in range(300):  # 900 nodes in 3-cycles of weight 0.5: ρ = 0.5
        a, b, c = 3 * k, 3 * k + 1, 3 * k + 2
        edges += [(a, b, 0.5), (b, c, 0.5), (c, a, 0.5)]
    base, size = 900, 300  # a ring with random chords: irreducible, dominant Perron root
    for i in range(size):
        edges.append((base + i, base + (i + 1) % size, 0.3))
    for _ in range(900):
        i, j = rng.integers(0, size, 2)
        edges.append((base + int(i), base + int(j), float(rng.uniform(0, 0.3))))
    names = [f"m{i}" for i in range(base + size)]
    W = weight_matrix(names, [(names[a], names[b], w) for a, b, w in edges])
    block = W[base:, base:].toarray()
    expected = max(0.5, float(np.max(np.abs(np.linalg.eigvals(block)))))
    assert expected > 0.5
    assert spectral_radius(W, dense_max=100) == pytest.approx(expected, rel=1e-6)
    assert spectral_radius(W[:base, :base]) == pytest.approx(0.5)


# --------------------------------------------------------------------------- candidates
def test_threshold_and_top_k():
    z = {"a": 0.1, "b": 0.9, "c": -0.6, "d": 0.0}
    assert threshold_candidates(z, 0.55) == ["b", "c"]
    assert ThresholdSelector(0.55).select(z) == ["b", "c"]
    assert top_k_candidates(z, 3) == ["b", "c", "a"]
    assert TopKSelector(10).select(z) == ["b", "c", "a"]  # zero is never a candidate


def test_hysteresis():
    sel = HysteresisSelector(on=0.6, off=0.3)
    seq = [0.2, 0.5, 0.65, 0.5, 0.35, 0.29, 0.5, 0.61]
    members = [bool(sel.select({"a": v})) for v in seq]
    assert members == [False, False, True, True, True, False, False, True]
    sel.reset()
    assert sel.select({"a": 0.5}) == []
    with pytest.raises(ValueError):
        HysteresisSelector(on=0.3, off=0.3)
