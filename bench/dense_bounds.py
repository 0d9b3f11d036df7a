"""Where numpy beats scipy on a small system (issue 38.4): the size bounds of the run path.

CPU per call (``time.process_time``, best of 3 batches, imports not counted) of

- the influence solve: ``InfluenceSolver`` dense (``P = (I − Wᵀ)⁻¹``, one product per
  solve) against sparse (SuperLU) on random W with ~3 edges per module: factor once,
  then 1,000 solves (a run's MAPE-K cycles);
- strong components: :func:`archself.linear.closed_loop.strong_components` on a dense
  pattern (numpy) against ``scipy.sparse.csgraph.connected_components``;
- NNLS: :func:`archself.runtime.influence.nnls` (Lawson–Hanson in numpy) against
  ``scipy.optimize.nnls`` on random 2k × k problems.

Usage::

    python bench/dense_bounds.py [--sizes 10 50 100 200 400 800]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import scipy.optimize
import scipy.sparse
from scipy.sparse.csgraph import connected_components

from archself.linear.closed_loop import strong_components
from archself.runtime.influence import InfluenceSolver, nnls, weight_matrix


def cpu(fn: Callable[[], object], repeat: int) -> float:
    """Best CPU seconds per call of ``fn`` over 3 batches of ``repeat`` calls."""
    best = np.inf
    for _ in range(3):
        t = time.process_time()
        for _ in range(repeat):
            fn()
        best = min(best, (time.process_time() - t) / repeat)
    return best


def influence_row(n: int, rng: np.random.Generator) -> str:
    names = [f"m{i}" for i in range(n)]
    src, dst = rng.integers(0, n, 3 * n), rng.integers(0, n, 3 * n)
    edges = [(names[a], names[b], 0.1) for a, b in zip(src, dst, strict=True) if a != b]
    dense = weight_matrix(names, edges, dense_max=n)
    sparse = weight_matrix(names, edges)
    r = rng.uniform(0.0, 1.0, n)
    out = []
    for W, dense_max in ((dense, n), (sparse, 0)):
        def run(W=W, dense_max=dense_max) -> None:
            s = InfluenceSolver(dense_max)
            s.set_matrix(W, key=0)
            for _ in range(1000):
                s.solve(r)
        out.append(cpu(run, 1))
    return f"influence n={n:5d}: dense {out[0] * 1e3:8.2f} ms, sparse {out[1] * 1e3:8.2f} ms"


def components_row(n: int, rng: np.random.Generator) -> str:
    A = (rng.random((n, n)) < 3.0 / n).astype(float)
    S = scipy.sparse.csr_matrix(A)
    dense = cpu(lambda: strong_components(A), 20)
    sparse = cpu(lambda: connected_components(scipy.sparse.csr_matrix(A), directed=True,
                                              connection="strong"), 20)
    sparse_only = cpu(lambda: connected_components(S, directed=True, connection="strong"), 20)
    return (f"components n={n:5d}: numpy {dense * 1e6:9.1f} µs, scipy from dense "
            f"{sparse * 1e6:9.1f} µs, scipy on CSR {sparse_only * 1e6:9.1f} µs")


def nnls_row(k: int, rng: np.random.Generator) -> str:
    A, b = rng.standard_normal((2 * k, k)), rng.standard_normal(2 * k)
    ours = cpu(lambda: nnls(A, b), 20)
    theirs = cpu(lambda: scipy.optimize.nnls(A, b), 20)
    return f"nnls k={k:4d}: numpy {ours * 1e6:9.1f} µs, scipy {theirs * 1e6:9.1f} µs"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 50, 100, 200, 400, 800])
    ap.add_argument("--nnls", type=int, nargs="+", default=[1, 3, 8, 16, 32, 64, 128])
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    for n in args.sizes:
        print(influence_row(n, rng), flush=True)
    for n in args.sizes:
        print(components_row(n, rng), flush=True)
    for k in args.nnls:
        print(nnls_row(k, rng), flush=True)


if __name__ == "__main__":
    main()
