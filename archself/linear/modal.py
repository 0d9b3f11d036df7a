"""Eigenvalues of the closed loop, dense or sparse, and the modal form ln(λ)/dt (pure maths).

:func:`eigenvalues` splits a sparse matrix into the strong components of its
pattern (block triangular: the eigenvalues are those of the diagonal blocks);
:func:`modal_form` maps the discrete eigenvalues λ of a loop to a real matrix with
the continuous-equivalent eigenvalues ``ln(λ)/dt`` that Eq. 21 tests.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.sparse

__all__ = ["LAMBDA_FLOOR", "block_diag", "eigenvalues", "modal_form"]

#: Floor of |λ| when mapping a discrete eigenvalue to ln|λ|/dt (a pure delay has λ = 0).
LAMBDA_FLOOR = 1e-12


def eigenvalues(A: np.ndarray | scipy.sparse.spmatrix) -> np.ndarray:
    """The eigenvalues of a dense or ``scipy.sparse`` square matrix (complex).

    A sparse matrix is split into the strong components of its pattern: in their
    topological order it is block triangular, so its eigenvalues are those of the
    diagonal blocks (a 1×1 block's is its entry).

    Examples
    --------
    >>> import scipy.sparse
    >>> A = scipy.sparse.csr_matrix([[0.5, 0.0, 0.0], [1.0, 0.0, 2.0], [0.0, -2.0, 0.0]])
    >>> sorted(eigenvalues(A).round(6).tolist(), key=lambda z: (z.real, z.imag))
    [-2j, 2j, (0.5+0j)]
    """
    if not scipy.sparse.issparse(A):
        A = np.atleast_2d(np.asarray(A, dtype=float))
        return np.linalg.eigvals(A) if A.size else np.zeros(0, dtype=complex)
    from scipy.sparse.csgraph import connected_components

    A = scipy.sparse.csr_matrix(A)
    if A.shape[0] == 0:
        return np.zeros(0, dtype=complex)
    count, labels = connected_components(A, directed=True, connection="strong")
    size = np.bincount(labels, minlength=count)
    single = size[labels] == 1
    out = [A.diagonal()[single].astype(complex)]
    order = np.argsort(labels, kind="stable")
    starts = np.concatenate([[0], np.cumsum(size)])
    for c in np.flatnonzero(size > 1).tolist():
        idx = order[starts[c] : starts[c + 1]]
        out.append(np.linalg.eigvals(A[idx][:, idx].toarray()))
    return np.concatenate(out)


def modal_form(Ad: np.ndarray, dt: float) -> np.ndarray:
    """A real matrix whose eigenvalues are ``ln(λ_i)/dt`` for the eigenvalues λ_i of ``Ad``.

    Real λ give 1×1 blocks ``ln|λ|/dt``; a complex pair gives the 2×2 block
    ``[[a, ω], [−ω, a]]`` with ``a = ln|λ|/dt`` and ``ω = arg(λ)/dt``. Only the real
    parts matter for Eq. 21; |λ| is floored at 1e-12 (a pure delay).

    Examples
    --------
    >>> modal_form(np.array([[0.5]]), 0.1).round(4).tolist()
    [[-6.9315]]
    """
    if scipy.sparse.issparse(Ad):
        return _modal_sparse(eigenvalues(Ad), dt)
    lam = np.linalg.eigvals(np.atleast_2d(Ad)) if Ad.size else np.zeros(0)
    blocks = []
    for z in lam:
        a = math.log(max(abs(z), LAMBDA_FLOOR)) / dt
        if z.imag > 1e-12:
            w = math.atan2(z.imag, z.real) / dt
            blocks.append(np.array([[a, w], [-w, a]]))
        elif z.imag >= -1e-12:
            blocks.append(np.array([[a]]))
    return block_diag(blocks)


def _modal_sparse(lam: np.ndarray, dt: float) -> scipy.sparse.csr_matrix:
    """:func:`modal_form` of the eigenvalues ``lam``, as a sparse matrix."""
    a = np.log(np.maximum(np.abs(lam), LAMBDA_FLOOR)) / dt
    w = np.arctan2(lam.imag, lam.real) / dt
    real = np.abs(lam.imag) <= 1e-12
    pair = lam.imag > 1e-12
    keep = real | pair
    width = np.where(pair, 2, 1)[keep]
    start = np.concatenate([[0], np.cumsum(width)[:-1]]).astype(np.intp)
    a, w, pair = a[keep], w[keep], pair[keep]
    rows = [start, start[pair], start[pair] + 1, start[pair] + 1]
    cols = [start, start[pair] + 1, start[pair], start[pair] + 1]
    vals = [a, w[pair], -w[pair], a[pair]]
    size = int(width.sum())
    return scipy.sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(size, size)
    )


def block_diag(blocks: Sequence[Any]) -> Any:
    """The blocks on a diagonal: sparse if any block is, else dense."""
    if any(scipy.sparse.issparse(b) for b in blocks):
        return scipy.sparse.block_diag(blocks, format="csr")
    size = sum(b.shape[0] for b in blocks)
    out = np.zeros((size, size))
    i = 0
    for b in blocks:
        k = b.shape[0]
        out[i : i + k, i : i + k] = b
        i += k
    return out
