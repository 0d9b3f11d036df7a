"""A heading-drift detector for dead reckoning: the template-matched GLR of the GPS innovation.

A heading error ``β(s)`` turns the odometry's displacement ``v ds`` by ``β``, so its
position falls off the true one by ``δp(t) = −∫ β(s) n̂(s) v ds`` with ``n̂ = (−sin θ,
cos θ)`` the odometry's own heading normal. A heading bias that drifts from an unknown
onset ``t0`` at an unknown rate ``ḃ`` (either sign), ``β = ḃ (s − t0)₊``, moves the
innovation ``e = GPS − odometry`` along a *known* template::

    e(t_j) = a + ḃ G_j(t0) + w_j,    G_j(t0) = ∫_{t0}^{t_j} (s − t0) d⊥(s),

``d⊥ = (dy, −dx)`` the odometry's displacement turned by −90°, ``a`` a constant
offset (a nuisance) and ``w`` the GPS noise. For each candidate onset ``t0 = t_m``
(the fix times in the window, leaving at least ``min_support_s`` after it) the
least-squares estimate of ``ḃ`` with ``a`` free, over its standard error, is::

    z_m = Σ_j G̃_j·e_j / (σ̂ √Σ_j |G̃_j|²),    G̃_j = G_j − mean(G),

and the statistic is ``max_m |z_m|``: the generalized likelihood ratio's root. The
noise ``σ̂`` is measured from the same fixes by their first differences (as
:class:`~archself_diffdrive.estimators.InnovationTrend` does), so one band holds at
any GPS noise level. Unlike a straight-line trend the template follows the turns of
the path and grows quadratically from the onset, so one parameter is tested instead
of a 2-D slope.

Cost: the sums over ``j ≥ m`` are suffix sums of the per-fix moments (a template
``G_j(t0) = A_j − A_m − (t_m − t_0)(D_j − D_m)`` expands into the window's running
sums ``D`` and first moments ``A`` of ``d⊥``), so one value takes O(window). The
maths is :func:`drift_glr` on arrays with a leading lane axis: the per-run class and
the lane-batched twin call the same function.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

__all__ = ["DriftGlr", "drift_fit", "drift_glr"]

#: a template whose projection cancels below this share of its terms counts as none
_CANCEL = 1e-9


def drift_glr(
    t: np.ndarray,
    e: np.ndarray,
    moved: np.ndarray,
    count: np.ndarray,
    min_span_s: np.ndarray,
    min_support_s: np.ndarray,
) -> np.ndarray:
    """The drift GLR of L windows of fixes (the first ``count[l]`` slots of row ``l``).

    Parameters
    ----------
    t : (L, W) array
        Fix times, oldest first.
    e : (L, W, 2) array
        Innovations (GPS − odometry position) at the fixes.
    moved : (L, W, 4) array
        Per fix ``j``, the odometry's turned displacement ``d⊥`` since fix ``j − 1``:
        its sum ``ΔD`` (2) and its moment ``ΔM = Σ (s − t_{j−1}) d⊥`` (2). Slot 0's is
        not used (it lies before the window).
    count : (L,) int array
        Valid slots per row.
    min_span_s, min_support_s : (L,) arrays
        A row is NaN until its fixes span ``min_span_s`` (and at least 5 fixes); an
        onset candidate needs ``min_support_s`` of fixes after it.

    Returns
    -------
    (L,) array
        ``max_m |z_m|`` per row (NaN while too short, without noise or movement).

    Examples
    --------
    A robot driving straight at 0.5 m/s whose heading error grows by 0.01 rad/s
    from t = 10 s, under ±0.1 m of alternating GPS noise:

    >>> ts = np.arange(31.0)
    >>> ramp = np.clip(ts - 10.0, 0.0, None)
    >>> e = np.zeros((1, 31, 2))
    >>> e[0, :, 1] = -0.01 * 0.5 * ramp**2 / 2 + 0.1 * (-1.0) ** ts
    >>> moved = np.zeros((1, 31, 4))
    >>> moved[0, :, 1] = -0.5  # d⊥ = (dy, −dx): 0.5 m a second along x
    >>> moved[0, :, 3] = -0.5 * 0.5  # moment: the displacement at mid-interval
    >>> z = drift_glr(ts[None], e, moved, np.array([31]), np.array([20.0]), np.array([5.0]))
    >>> round(float(z[0]), 1)
    16.4
    """
    scan = _scan(t, e, moved, count, min_span_s, min_support_s)
    out = np.full(len(t), math.nan)
    if scan is not None:
        z, found = scan[0], scan[4]
        out[found] = np.abs(z[found]).max(1)
    return out


def drift_fit(
    t: np.ndarray,
    e: np.ndarray,
    moved: np.ndarray,
    count: np.ndarray,
    min_span_s: np.ndarray,
    min_support_s: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The drift that :func:`drift_glr` finds: at its most likely onset, per row.

    Same arguments as :func:`drift_glr`.

    Returns
    -------
    z, rate, rate_std, onset : (L,) arrays
        The signed statistic ``z_m``, the rate ``ḃ`` (rad/s: the IMU's heading bias
        grows by it, beyond what the odometry takes off), its standard error and the
        onset time ``t_m`` at the onset ``m`` maximizing ``|z_m|``; NaN where
        :func:`drift_glr` is NaN. The heading error at time ``t ≥ t_m`` is
        ``rate·(t − t_m)``.
    error : (L, 2) array
        The fitted innovation at the last fix, ``a + ḃ·G_last``: the position error of
        the odometry (GPS − odometry) with the GPS noise averaged out.
    """
    n_rows = len(t)
    z_out, rate, std, onset = (np.full(n_rows, math.nan) for _ in range(4))
    error = np.full((n_rows, 2), math.nan)
    scan = _scan(t, e, moved, count, min_span_s, min_support_s)
    if scan is None:
        return z_out, rate, std, onset, error
    z, num, den, var, found, (a_last, d_last, c, tau, mean_g, mean_e) = scan
    rows = np.flatnonzero(found)
    m = np.abs(z[rows]).argmax(1)
    slope = num[rows, m] / den[rows, m]
    z_out[rows] = z[rows, m]
    rate[rows] = slope
    std[rows] = np.sqrt(var[rows] / den[rows, m])
    onset[rows] = t[rows, m]
    # the fit at the last fix: mean(e) + ḃ (G_last − mean(G)), G_last = A_last − τ_m D_last − c_m
    g_last = a_last[rows] - tau[rows, m][:, None] * d_last[rows] - c[rows, m]
    error[rows] = mean_e[rows] + slope[:, None] * (g_last - mean_g[rows, m])
    return z_out, rate, std, onset, error


def _scan(
    t: np.ndarray,
    e_in: np.ndarray,
    moved: np.ndarray,
    count: np.ndarray,
    min_span_s: np.ndarray,
    min_support_s: np.ndarray,
) -> tuple[Any, ...] | None:
    """Per row and onset ``m``: signed ``z_m``, its numerator ``Σ G̃·e`` and denominator
    ``Σ|G̃|²``, the noise variance per row, the rows with a value, and the sums the fit
    at the last fix needs (None: no row has a value)."""
    n_rows, width = t.shape
    if width < 5:
        return None
    rows = np.arange(n_rows)
    slot = np.arange(width)
    valid = slot < count[:, None]
    last = np.maximum(count - 1, 0)
    tau = np.where(valid, t - t[:, :1], 0.0)
    span = tau[rows, last]
    ok = (count >= 5) & (span >= min_span_s)
    if not ok.any():
        return None
    vmask = valid[:, :, None]
    # per fix: e (2), D (2), A (2) and the products the suffix sums need, in one array
    x = np.empty((n_rows, width, 11))
    e = x[:, :, 0:2]
    np.copyto(e, np.where(vmask, e_in, 0.0))
    step = np.where(vmask & (slot > 0)[None, :, None], moved, 0.0)
    prev = np.concatenate([np.zeros((n_rows, 1)), tau[:, :-1]], axis=1)
    d, a = x[:, :, 2:4], x[:, :, 4:6]
    np.cumsum(step[:, :, :2], axis=1, out=d)  # D_j: Σ d⊥ from the first fix
    np.cumsum(step[:, :, 2:] + prev[:, :, None] * step[:, :, :2], axis=1, out=a)  # A_j: Σ τ d⊥
    d *= vmask
    a *= vmask
    np.einsum("lwk,lwk->lw", a, e, out=x[:, :, 6])
    np.einsum("lwk,lwk->lw", d, e, out=x[:, :, 7])
    np.einsum("lwk,lwk->lw", a, a, out=x[:, :, 8])
    np.einsum("lwk,lwk->lw", a, d, out=x[:, :, 9])
    np.einsum("lwk,lwk->lw", d, d, out=x[:, :, 10])
    r = np.cumsum(x[:, ::-1], axis=1)[:, ::-1]  # suffix sums over j ≥ m, every column at once
    r_e, r_d, r_a = r[:, :, 0:2], r[:, :, 2:4], r[:, :, 4:6]
    r_ae, r_de, r_aa, r_ad, r_dd = (r[:, :, i] for i in range(6, 11))
    k = (count[:, None] - slot).astype(float)  # fixes j ≥ m
    tv = tau[:, :, None]
    c = a - tv * d  # the template's constant at onset m: A_m − τ_m D_m
    s_ge = r_ae - tau * r_de - np.einsum("lwk,lwk->lw", c, r_e)
    r_ad_m = r_a - tv * r_d  # Σ_{j≥m} (A_j − τ_m D_j)
    s_g = r_ad_m - k[:, :, None] * c
    big = r_aa + tau * tau * r_dd + k * np.einsum("lwk,lwk->lw", c, c)
    s_gg = big - 2 * tau * r_ad - 2 * np.einsum("lwk,lwk->lw", c, r_ad_m)
    n = np.maximum(count, 1).astype(float)[:, None]
    mean_e = r_e[:, :1, :] / n[:, :, None]
    num = s_ge - np.einsum("lwk,lwk->lw", s_g, np.broadcast_to(mean_e, s_g.shape))
    den = s_gg - np.einsum("lwk,lwk->lw", s_g, s_g) / n
    dif = np.diff(e, axis=1)
    pairs = np.einsum("lwk,lwk->l", dif, dif * valid[:, 1:, None])
    var = pairs / (2.0 * np.maximum(count - 1, 1)) / 2.0
    onset = valid & ((span[:, None] - tau) >= min_support_s[:, None]) & (den > _CANCEL * big)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(onset, num / np.sqrt(np.where(onset, den, 1.0) * var[:, None]), 0.0)
    found = ok & onset.any(1) & (var > 0.0)
    # what drift_fit needs for the fit's innovation at the last fix
    at_last = (a[rows, last], d[rows, last], c, tau, s_g / n[:, :, None], mean_e[:, 0])
    return z, num, den, var, found, at_last



class DriftGlr:
    """The drift GLR over a sliding window of GPS fixes (:func:`drift_glr`, one lane).

    Call :meth:`move` with every odometry displacement and :meth:`add` with every
    innovation (after that step's :meth:`move`).

    Parameters
    ----------
    window_s : float
        Length of the window (s).
    min_span_s : float
        The value is NaN until the fixes span this long (and at least 5 fixes).
    min_support_s : float
        An onset candidate needs this long of fixes after it.

    Examples
    --------
    Straight at 0.5 m/s; from t = 10 s the heading error grows by 0.01 rad/s, so the
    position falls to the right; ±0.1 m of alternating GPS noise:

    >>> g = DriftGlr(60.0, 20.0, 5.0)
    >>> x = y = 0.0
    >>> for k in range(1, 601):
    ...     s = 0.05 * k
    ...     g.move(s, 0.025, 0.0)
    ...     if k % 20 == 0:
    ...         fall = 0.01 * 0.5 * max(s - 10.0, 0.0) ** 2 / 2
    ...         g.add(s, 0.1 * (-1) ** k, -fall + 0.1 * (-1) ** (k // 20))
    >>> round(g.value(), 1)
    16.1
    """

    def __init__(self, window_s: float, min_span_s: float, min_support_s: float) -> None:
        self.window_s = float(window_s)
        self.min_span_s = float(min_span_s)
        self.min_support_s = float(min_support_s)
        #: per fix ``(t, ex, ey, ΔDx, ΔDy, ΔMx, ΔMy)``
        self.items: deque[tuple[float, ...]] = deque()
        self.moved = [0.0, 0.0, 0.0, 0.0]  # ΔD, ΔM since the last fix
        self.last = 0.0  # time of the last fix

    def move(self, t: float, dx: float, dy: float) -> None:
        """The odometry moved by ``(dx, dy)`` in the step ending at ``t``."""
        lag = t - self.last
        m = self.moved
        m[0] += dy
        m[1] -= dx
        m[2] += lag * dy
        m[3] -= lag * dx

    def add(self, t: float, ex: float, ey: float) -> None:
        """Add the innovation ``(ex, ey)`` observed at ``t`` and drop old fixes."""
        self.items.append((t, ex, ey, *self.moved))
        self.moved = [0.0, 0.0, 0.0, 0.0]
        self.last = t
        while self.items[0][0] <= t - self.window_s:
            self.items.popleft()

    def _args(self) -> tuple[np.ndarray, ...]:
        a = np.array(self.items)
        return (a[None, :, 0], a[None, :, 1:3], a[None, :, 3:], np.array([len(a)]),
                np.array([self.min_span_s]), np.array([self.min_support_s]))

    def value(self) -> float:
        """``max_m |z_m|`` (NaN until the window spans ``min_span_s``)."""
        if len(self.items) < 5:
            return math.nan
        return float(drift_glr(*self._args())[0])

    def estimate(self) -> tuple[float, float, float, float, np.ndarray]:
        """``(z, rate, rate_std, onset, error)`` of the most likely drift
        (:func:`drift_fit`; NaNs until the window spans ``min_span_s``)."""
        if len(self.items) < 5:
            return math.nan, math.nan, math.nan, math.nan, np.full(2, math.nan)
        z, rate, std, onset, error = drift_fit(*self._args())
        return float(z[0]), float(rate[0]), float(std[0]), float(onset[0]), error[0]

    def clear(self) -> None:
        """Forget every fix and displacement."""
        self.items.clear()
        self.moved = [0.0, 0.0, 0.0, 0.0]
