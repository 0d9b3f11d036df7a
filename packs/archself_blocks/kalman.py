"""The Kalman filters' maths, once: predict and the Joseph-form update, stacked.

``generic.kalman`` (:class:`~archself_blocks.estimators.KalmanFilter`) and
``generic.ekf`` (:class:`~archself_blocks.estimators.AugmentedEkf`) run these
functions on their own vectors and matrices (``x`` ``(n,)``, ``P`` ``(n, n)``), their
lane classes on stacks of L (``(L, n)``, ``(L, n, n)``;
:mod:`~archself_blocks.lanes_estimators`, :mod:`~archself_blocks.lanes_observers`):
the same numpy calls, so a lane is its run. The formulas are filterpy's
(``KalmanFilter.predict``/``update``; ``ExtendedKalmanFilter.predict``/``update``
with the linear ``h`` of the augmented filter), which stays the tests' oracle
(``tests/test_blocks.py``, 1e-12); a run imports no filterpy.

Matrix products go through ``numpy.matmul``: a stack's ``A[i] @ x[i]`` is the
unstacked product bit for bit on the platforms tested (x86-64, numpy 2.4).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

#: the identity of each state size (read only)
_EYE: dict[int, np.ndarray] = {}

__all__ = ["matvec", "nis", "predict", "update"]


def matvec(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``A[i] @ x[i]`` for every lane: ``(L, p, n)`` by ``(L, n)`` gives ``(L, p)``
    (and ``(p, n)`` by ``(n,)`` gives ``(p,)``).

    Examples
    --------
    >>> matvec(np.array([[[1.0, 2.0]], [[0.0, 1.0]]]), np.array([[1.0, 1.0], [3.0, 4.0]]))
    array([[3.],
           [4.]])
    """
    return np.matmul(A, x[..., None])[..., 0]


def _t(a: np.ndarray) -> np.ndarray:
    """The (stacked) transposes."""
    return a.swapaxes(-1, -2)


def predict(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray,
            Bu: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """``x⁺ = F x + B u`` and ``P⁺ = F P Fᵀ + Q`` (filterpy's ``predict``).

    Parameters
    ----------
    x : (n,) or (L, n) array
    P, F, Q : (n, n) or (L, n, n) arrays
    Bu : array shaped as x, or 0
        The input's part ``B u`` (0: filterpy's ``B = 0``, which adds an exact 0).

    Examples
    --------
    >>> x, P = predict(np.array([[1.0]]), np.array([[[2.0]]]), np.array([[[0.5]]]),
    ...                np.array([[[0.1]]]), np.array([[3.0]]))
    >>> x.tolist(), P.tolist()
    ([[3.5]], [[[0.6]]])
    """
    return matvec(F, x) + Bu, (F @ P) @ _t(F) + Q


def update(x: np.ndarray, P: np.ndarray, nu: np.ndarray, H: np.ndarray, R: np.ndarray,
           inv: Callable[[np.ndarray], Any]
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[int, Exception]]:
    """filterpy's ``update`` in Joseph form, with innovation ``nu = z − H x``.

    ``K = P Hᵀ S⁻¹`` with ``S = H P Hᵀ + R``, ``x + K ν`` and
    ``(I − K H) P (I − K H)ᵀ + K R Kᵀ``. ``inv`` is the filter's inverse (filterpy's
    ``KalmanFilter``: ``numpy.linalg.inv``; its ``ExtendedKalmanFilter``:
    ``scipy.linalg.inv``), batched where it can be, else matrix by matrix. Shapes
    as :func:`predict`'s: one filter, or a stack of L.

    Returns
    -------
    x, P : arrays
        Updated (a stack's row whose ``S`` could not be inverted: ``x`` as given).
    S : (k, k) or (L, k, k) array
        The innovation covariance(s).
    errors : dict
        Stack row -> the exception ``inv`` raised for it (one filter: it is raised).

    Examples
    --------
    >>> x, P, S, errors = update(np.array([[0.0]]), np.array([[[1.0]]]), np.array([[2.0]]),
    ...                          np.array([[[1.0]]]), np.array([[[1.0]]]), np.linalg.inv)
    >>> x.tolist(), P.tolist(), S.tolist(), errors
    ([[1.0]], [[[0.5]]], [[[2.0]]], {})
    """
    PHT = P @ _t(H)
    S = H @ PHT + R
    errors: dict[int, Exception] = {}
    try:
        SI = inv(S)
        if SI.shape != S.shape:
            raise ValueError("not batched")
    except (ValueError, np.linalg.LinAlgError):  # one by one
        if S.ndim == 2:
            raise
        SI = np.zeros_like(S)
        for j in range(len(S)):
            try:
                SI[j] = inv(S[j])
            except (ValueError, np.linalg.LinAlgError) as exc:
                errors[j] = exc
    K = PHT @ SI
    n = P.shape[-1]
    eye = _EYE.get(n)
    if eye is None:
        eye = _EYE[n] = np.eye(n)
    I_KH = eye - K @ H
    return (x + matvec(K, nu), (I_KH @ P) @ _t(I_KH) + (K @ R) @ _t(K), S, errors)


def nis(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """The normalized innovation squared ``νᵀ S⁻¹ ν`` (a number, or ``(L,)`` for a stack).

    Examples
    --------
    >>> nis(np.array([[2.0]]), np.array([[[4.0]]])).tolist()
    [1.0]
    >>> float(nis(np.array([2.0]), np.array([[4.0]])))
    1.0
    """
    return (nu[..., None, :] @ np.linalg.solve(S, nu[..., None]))[..., 0, 0]
