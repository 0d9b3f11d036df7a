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
any GPS noise level — if the GPS noise is all there is. Dead reckoning also wanders
(wheel slip): the innovation carries a random walk of intensity ``q`` (m²/s per
coordinate), which the first differences cannot see (``q·Δt`` against ``2σ²``) but a
long, smooth template picks up. Given ``walk = q``, the numerator's variance is
``σ̂² Σ|G̃_j|² + q Σ_{i,j} G̃_i·G̃_j min(t_i, t_j)`` and ``z_m`` is N(0, 1) again in a
fault-free run at any GPS noise (without it the 99 % level of the per-run maximum
was 4.9 at 0.2 m of GPS noise against 4.2 at 0.4 m; ``bench/drift_detector.py``).
Unlike a straight-line trend the template follows the turns of
the path and grows quadratically from the onset, so one parameter is tested instead
of a 2-D slope.

Cost: the sums over ``j ≥ m`` are suffix sums of per-fix moments (a template
``G_j(t0) = A_j − A_m − (t_m − t_0)(D_j − D_m)`` expands into the running sums ``D``
and first moments ``A`` of ``d⊥`` about a time origin). :class:`DriftWindows` keeps,
per lane, a ring buffer of the fixes with their moments and the *prefix* sums before
each, so a new fix adds one row and a suffix sum is one subtraction (total − prefix);
a value still scans every onset of the window, O(window), in one pass of a dozen
array operations. The ring is written twice (slot ``s`` and ``s + capacity``), so a
lane's window, oldest first, is one contiguous slice: one run's scan reads views,
never gathers. The origin is moved to the window's oldest fix once it lies two
windows back (the moments and prefix sums re-based), so the sums stay as small as a
window's however long the run. The per-run class (:class:`DriftGlr`) and the
lane-batched odometry hold the same state and call the same code.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["DriftGlr", "DriftWindows", "drift_glr"]

#: a template whose projection cancels below this share of its terms counts as none
_CANCEL = 1e-9
#: χ²₁ at 0.95: the onsets within it of the best one form its 95 % profile-likelihood set
_CHI2_95 = 3.841
#: the rate found at an alarm is known to within this share of itself at best: an alarm
#: comes when the latest fixes' noise lies along the template (a stopping time), so the
#: fits are biased towards late onsets and steep rates even inside the likelihood set
#: (a 1× drift handed over at 14× its rate ± 16 %, docs/robustness.md)
_RATE_REL_STD = 0.5
#: the channels of a fix: e (2), D (2), A (2), A·e, D·e, A·A, A·D, D·D, |e − e_prev|²
_WIDTH = 12


class DriftWindows:
    """The drift GLR over sliding windows of GPS fixes in L lanes.

    Per lane a ring buffer of fixes (one capacity for all lanes, doubled when a lane
    fills it, a head and a count per lane; each slot stored twice, at ``s`` and
    ``s + capacity``, so that the window is the slice ``[head, head + capacity)``):
    the fix time, its channels (innovation ``e``, the running sums ``D`` and moments
    ``A`` of ``d⊥`` about the lane's time origin, their products and the squared step
    of ``e`` from the previous fix) and the sums of those channels over the lane's
    earlier fixes since its origin.

    Parameters
    ----------
    n : int
        Number of lanes.
    window_s, min_span_s, min_support_s : float
        The window's length; a value is NaN until the fixes span ``min_span_s`` (and
        at least 5 fixes); an onset candidate needs ``min_support_s`` of fixes after
        it. Per-lane arrays of the same names after construction (a sweep may set
        them per lane).
    capacity : int
        Fixes per lane before the buffers double.
    walk : float
        The random walk of dead reckoning against the true position, m²/s per
        coordinate (``q``; 0: the innovation is the GPS's white noise alone). Per-lane
        array ``walk`` after construction.

    Examples
    --------
    Two lanes driving straight at 0.5 m/s; in lane 1 the heading error grows by 0.01
    rad/s from t = 10 s; ±0.1 m of alternating GPS noise in both:

    >>> w = DriftWindows(2, 60.0, 20.0, 5.0)
    >>> lanes = np.arange(2)
    >>> moved = np.array([[0.0, -0.5, 0.0, -0.25]] * 2)  # d⊥ = (dy, −dx) over 1 s
    >>> for s in range(1, 31):
    ...     fall = 0.01 * 0.5 * max(s - 10.0, 0.0) ** 2 / 2
    ...     e = np.array([[0.0, 0.1 * (-1) ** s], [0.0, -fall + 0.1 * (-1) ** s]])
    ...     w.add(float(s), lanes, e, moved)
    >>> w.value(lanes).round(1).tolist()
    [0.5, 16.1]
    """

    def __init__(self, n: int, window_s: float = math.inf, min_span_s: float = 0.0,
                 min_support_s: float = 0.0, capacity: int = 16, walk: float = 0.0) -> None:
        self.window_s = np.full(n, float(window_s))
        self.walk = np.full(n, float(walk))
        self.min_span_s = np.full(n, float(min_span_s))
        self.min_support_s = np.full(n, float(min_support_s))
        self.cap = capacity
        self.t = np.zeros((n, 2 * capacity))
        # channel first: each channel of all lanes and slots is one contiguous array
        self.x = np.zeros((_WIDTH, n, 2 * capacity))  # the channels of each fix
        self.before = np.zeros((_WIDTH, n, 2 * capacity))  # their sums over the earlier fixes
        self.total = np.zeros((_WIDTH, n))  # ... over all fixes since the origin
        self.origin = np.zeros(n)
        self.head = np.zeros(n, dtype=int)
        self.count = np.zeros(n, dtype=int)

    @property
    def n(self) -> int:
        """Number of lanes."""
        return len(self.count)

    # ---------------------------------------------------------------- the buffers
    def _window(self, idx: np.ndarray, width: int | None = None) -> tuple[np.ndarray, ...]:
        """``t``, ``x`` and ``before`` of lanes ``idx``, oldest fix first, ``width``
        slots (default: the capacity): views where the lanes are one slice and share
        their head (one run; lanes whose fixes came at the same times), else copies."""
        width = self.cap if width is None else width
        head = self.head[idx]
        h = int(head[0])
        if not (head == h).all():
            rows, cols = idx[:, None], head[:, None] + np.arange(width)
            return self.t[rows, cols], self.x[:, rows, cols], self.before[:, rows, cols]
        first, k = int(idx[0]), len(idx)
        one: Any = slice(first, first + k) if idx[-1] - first == k - 1 and (
            k < 3 or (np.diff(idx) == 1).all()) else idx
        cols = slice(h, h + width)
        return self.t[one, cols], self.x[:, one, cols], self.before[:, one, cols]

    def _put(self, idx: np.ndarray, slot: np.ndarray, t: Any, x: Any, before: Any) -> None:
        """Write slots ``slot`` (``(k,)`` or ``(k, w)``, < capacity) of lanes ``idx``,
        both copies."""
        rows = idx if slot.ndim == 1 else idx[:, None]
        cols = np.stack([slot, slot + self.cap])  # (2, k[, w]): both copies in one write
        self.t[rows, cols] = t
        self.x[:, rows, cols] = np.expand_dims(x, 1)
        self.before[:, rows, cols] = np.expand_dims(before, 1)

    def _grow(self, size: int) -> None:
        cap = self.cap
        while cap < size:
            cap *= 2
        t, x, before = self._window(np.arange(self.n))
        self.cap = cap
        self.t = np.zeros((self.n, 2 * cap))
        self.x = np.zeros((_WIDTH, self.n, 2 * cap))
        self.before = np.zeros((_WIDTH, self.n, 2 * cap))
        width = t.shape[1]
        for lo in (0, cap):
            self.t[:, lo : lo + width] = t
            self.x[:, :, lo : lo + width] = x
            self.before[:, :, lo : lo + width] = before
        self.head[:] = 0

    def add(self, t: float | np.ndarray, idx: np.ndarray, e: np.ndarray, moved: np.ndarray
            ) -> None:
        """Add the fixes of lanes ``idx`` at ``t`` and drop the fixes out of the window.

        Parameters
        ----------
        t : float or (k,) array
            Fix time (per lane).
        idx : (k,) int array
            The lanes with a fix.
        e : (k, 2) array
            Innovations (GPS − odometry position).
        moved : (k, 4) array
            The odometry's turned displacement since each lane's previous fix: its sum
            ``ΔD`` (2) and moment ``ΔM = Σ (s − t_prev) d⊥`` (2) (ignored for a lane's
            first fix).
        """
        count = self.count[idx]
        if (count >= self.cap).any():
            self._grow(int(count.max()) + 1)
        cap = self.cap
        head = self.head[idx]
        first = count == 0
        some_first = first.any()
        prev_slot = (head + count - 1) % cap
        prev = self.x[:, idx, prev_slot]
        lag = self.t[idx, prev_slot] - self.origin[idx]  # the previous fix about the origin
        if some_first:
            self.origin[idx] = np.where(first, t, self.origin[idx])
        mv = moved.T
        row = np.empty((_WIDTH, len(idx)))
        row[0:2] = e.T
        np.add(prev[2:4], mv[:2], out=row[2:4])  # D
        np.add(prev[4:6], mv[2:] + lag * mv[:2], out=row[4:6])  # A
        step = row[0:2] - prev[0:2]
        row[11] = step[0] * step[0] + step[1] * step[1]
        sums = self.total[:, idx]  # (a copy)
        if some_first:
            row[2:6, first] = 0.0
            row[11, first] = 0.0
            sums[:, first] = 0.0
        _products(row)
        self._put(idx, (head + count) % cap, t, row, sums)
        self.total[:, idx] = sums + row
        count = count + 1
        cut = t - self.window_s[idx]
        old = self.t[idx, head] <= cut
        while old.any():  # (the new fix is never dropped: window_s > 0)
            head = np.where(old, (head + 1) % cap, head)
            count = count - old
            old = self.t[idx, head] <= cut
        self.head[idx] = head
        self.count[idx] = count
        stale = idx[t - self.origin[idx] >= 2.0 * self.window_s[idx]]
        if len(stale):
            self._rebase(stale)

    def _rebase(self, idx: np.ndarray) -> None:
        """Move the origin of lanes ``idx`` to their oldest fix; recompute the sums."""
        count = self.count[idx]
        width = int(count.max())
        t, x, _ = self._window(idx, width)
        x = x.copy()
        valid = np.arange(width) < count[:, None]
        shift = t[:, :1] - self.origin[idx, None]
        d = x[2:4] - x[2:4, :, :1]
        x[4:6] = x[4:6] - x[4:6, :, :1] - shift * d  # A about the new origin
        x[2:4] = d
        x[11, :, 0] = 0.0  # (the oldest fix's step reaches out of the window)
        _products(x)
        x *= valid
        sums = np.cumsum(x, axis=2)
        self._put(idx, (self.head[idx, None] + np.arange(width)) % self.cap, t, x, sums - x)
        self.total[:, idx] = sums[:, np.arange(len(idx)), count - 1]
        self.origin[idx] = t[:, 0]

    def clear(self, idx: np.ndarray) -> None:
        """Forget every fix of lanes ``idx``."""
        self.head[idx] = 0
        self.count[idx] = 0

    def copy_lane(self, i: int, other: DriftWindows, j: int) -> None:
        """Lane ``i`` becomes lane ``j`` of ``other`` (fixes, sums and settings, bit for bit)."""
        count = int(other.count[j])
        if count > self.cap:
            self._grow(count)
        t, x, before = other._window(np.array([j]), count)
        self._put(np.array([i]), np.arange(count)[None], t, x, before)
        self.total[:, i] = other.total[:, j]
        for name in ("origin", "count", "window_s", "min_span_s", "min_support_s", "walk"):
            getattr(self, name)[i] = getattr(other, name)[j]
        self.head[i] = 0

    def times(self, i: int) -> list[float]:
        """Lane ``i``'s fix times in the window, oldest first."""
        return self._window(np.array([i]), int(self.count[i]))[0][0].tolist()

    # ---------------------------------------------------------------- the statistic
    def value(self, idx: np.ndarray) -> np.ndarray:
        """``max_m |z_m|`` of lanes ``idx`` (NaN while too short, without noise or movement)."""
        out = np.full(len(idx), math.nan)
        scan = self._scan(idx)
        if scan is not None:
            z, found = scan[0], scan[4]
            out[found] = np.abs(z[found]).max(1)
        return out

    def estimate(self, idx: np.ndarray) -> tuple[np.ndarray, ...]:
        """The drift :meth:`value` finds in lanes ``idx``: at its most likely onset.

        The onset is the weakest part of the fit: a later onset with a steeper rate
        explains the same fall of the innovation almost as well, and the heading error
        now, ``rate·(t − onset)``, differs between them by a factor of several (the
        maximum over onsets also favours the short, noisy fits). The onsets the data
        cannot tell from the best form its profile-likelihood set,
        ``z_m² ≥ z_max² − χ²₁(0.95)`` of the same sign. The heading error is the best
        onset's, with a standard error that covers the set (the larger of the error
        given the onset and half the set's range); the rate is the set's *slowest*,
        with its error given its onset: just after an alarm the best onset's rate is
        often several times the true one, and a rate too fast keeps turning an
        estimator that takes it over, where one too slow is learned from the GPS. Even
        the slowest can be far too fast (the alarm selects noise along the template),
        so its error is at least half of it: an estimator that trusts it less unlearns
        a wrong one from the GPS.

        Returns
        -------
        z, onset : (k,) arrays
            The signed statistic ``z_m`` and the onset time ``t_m`` at the onset ``m``
            maximizing ``|z_m|``; NaN where :meth:`value` is NaN.
        rate, rate_std : (k,) arrays
            The slowest rate ``ḃ`` of the set (rad/s: the IMU's heading bias grows by
            it, beyond what the odometry takes off) and its standard error given its
            onset, at least half the rate (``_RATE_REL_STD``).
        error : (k, 2) array
            The fitted innovation at the last fix, ``a + ḃ·G_last``: the position error
            of the odometry (GPS − odometry) with the GPS noise averaged out.
        bias, bias_std : (k,) arrays
            The heading error the drift has built up by the last fix, the best onset's
            ``ḃ_m·(t_last − t_m)``, and its standard error.
        """
        k = len(idx)
        z_out, rate, std, onset, bias, bias_std = (np.full(k, math.nan) for _ in range(6))
        error = np.full((k, 2), math.nan)
        scan = self._scan(idx)
        if scan is None:
            return z_out, rate, std, onset, error, bias, bias_std
        z, num, den, noise, found, (t, x, last, tau, c, mean_g, mean_e, cand) = scan
        rows = np.flatnonzero(found)
        m = np.abs(z[rows]).argmax(1)
        slope = num[rows, m] / den[rows, m]
        z_out[rows] = z[rows, m]
        se = np.sqrt(noise[rows, m]) / den[rows, m]
        onset[rows] = t[rows, m]
        seen = t[rows, last[rows]] - onset[rows]
        bias[rows] = slope * seen
        # the onsets the data cannot tell from the best (95 % profile-likelihood set)
        zr, best = z[rows], z_out[rows, None]
        near = cand[rows] & (zr * best > 0.0) & (zr * zr >= best * best - _CHI2_95)
        with np.errstate(divide="ignore", invalid="ignore"):
            rates = np.where(near, num[rows] / np.where(near, den[rows], 1.0), np.nan)
        biases = rates * (t[rows, last[rows], None] - t[rows])
        # the rate: the slowest of the set, with its error given that onset
        slow = np.nanargmin(np.where(near, np.abs(rates), np.inf), 1)
        rate[rows] = rates[np.arange(len(rows)), slow]
        std[rows] = np.sqrt(noise[rows, slow]) / den[rows, slow]
        std[rows] = np.maximum(std[rows], _RATE_REL_STD * np.abs(rate[rows]))
        bias_std[rows] = np.maximum(seen * se, 0.5 * (np.nanmax(biases, 1) - np.nanmin(biases, 1)))
        # the fit at the last fix: mean(e) + ḃ (G_last − mean(G)),
        # G_last = A_last − τ_m D_last − c_m
        at_last = x[:, rows, last[rows]].T
        g_last = at_last[:, 4:6] - tau[rows, m][:, None] * at_last[:, 2:4] - c[:, rows, m].T
        error[rows] = mean_e[rows] + slope[:, None] * (g_last - mean_g[:, rows, m].T)
        return z_out, rate, std, onset, error, bias, bias_std

    def _scan(self, idx: np.ndarray) -> tuple[Any, ...] | None:
        """Per lane and slot ``m`` (onset): signed ``z_m``, its numerator ``Σ G̃·e``,
        denominator ``Σ|G̃|²`` and the numerator's variance, the lanes with a value, and
        what the fit at the last fix needs (None: no lane has a value)."""
        count = self.count[idx]
        t, x, before = self._window(idx)  # oldest first: slot m is the m-th fix of the window
        rows = np.arange(len(idx))
        last = count - 1
        span = t[rows, last] - t[:, 0]
        ok = (count >= 5) & (span >= self.min_span_s[idx])
        if not ok.any():
            return None
        r = self.total[:, idx, None] - before  # suffix sums over j ≥ m
        tau = t - self.origin[idx, None]
        n = np.maximum(count, 1).astype(float)
        k = (count[:, None] - np.arange(self.cap)).astype(float)
        valid = k > 0  # the slot holds a fix of the window (k: fixes j ≥ m)
        # (x, y) pairs as one (2, L, cap) array; ``(a * b).sum(0)`` is ``ax·bx + ay·by``
        c = x[4:6] - tau * x[2:4]  # the template's constant at onset m: A_m − τ_m D_m
        s_ge = r[6] - tau * r[7] - (c * r[0:2]).sum(0)
        s = r[4:6] - tau * r[2:4]  # Σ_{j≥m} (A_j − τ_m D_j)
        big = r[8] + tau * tau * r[10] + k * (c * c).sum(0)
        s_gg = big - 2.0 * tau * r[9] - 2.0 * (c * s).sum(0)
        s -= k * c  # Σ G over j ≥ m
        at_head = r[:, :, 0]
        mean_e = at_head[0:2] / n  # (2, L)
        num = s_ge - (s * mean_e[:, :, None]).sum(0)
        ss = (s * s).sum(0)
        den = s_gg - ss / n[:, None]
        pairs = at_head[11] - x[11, :, 0]
        var = pairs / (2.0 * np.maximum(count - 1, 1)) / 2.0
        onset = valid & ((t[rows, last][:, None] - t) >= self.min_support_s[idx, None])
        onset &= den > _CANCEL * big
        noise = den * var[:, None]  # the variance of the numerator: the GPS's white noise,
        walk = self.walk[idx]
        if walk.any():  # ... and the random walk of dead reckoning
            noise += walk[:, None] * _walk_quadratic(t, r, k, valid, n, tau, c, s, ss)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(onset, num / np.sqrt(np.where(onset, noise, 1.0)), 0.0)
        found = ok & onset.any(1) & (var > 0.0)
        mean_g = s / n[:, None]
        return z, num, den, noise, found, (t, x, last, tau, c, mean_g, mean_e.T, onset)


def _walk_quadratic(t, r, k, valid, n, tau, c, s, ss) -> np.ndarray:
    """Per lane and onset slot ``m``: ``Σ_{i,j} G̃_i·G̃_j (min(t_i, t_j) − t_first)``.

    The numerator ``Σ G̃_j·e_j`` of :meth:`DriftWindows._scan` has the variance
    ``q`` times this when the innovation carries a random walk of intensity ``q``
    (m²/s per coordinate; the offset is free, so the walk's start does not matter).
    With ``min(t_i, t_j) − t_first = Σ_{k ≤ min(i, j)} Δt_k`` it is
    ``Σ_k Δt_k |S_k|²``, ``S_k = Σ_{j ≥ k} G̃_j``: ``S_k = T·p_k/n`` for ``k ≤ m``
    (``T = Σ_{j≥m} G_j``, ``p_k`` the fixes before ``k``) and
    ``S_k = SA_k − τ_m SD_k − K_k u`` after it (``SA``, ``SD`` the suffix sums of the
    moments and sums, ``K_k`` the fixes from ``k`` on, ``u = c_m + T/n``), so the
    sum expands into suffix sums over the window of a few per-fix products: one
    pass, O(window), like the rest of the scan.

    Arguments are :meth:`DriftWindows._scan`'s arrays, oldest fix first ((L, cap); ``r``
    (12, L, cap); the pairs ``c`` (``c_m``) and ``s`` (``T``) (2, L, cap), ``ss = |s|²``).
    """
    dt = np.zeros_like(t)
    dt[:, 1:] = np.where(valid[:, 1:], t[:, 1:] - t[:, :-1], 0.0)
    big_k = np.where(valid, k, 0.0)
    fixes_before = n[:, None] - big_k
    sa, sd = r[4:6], r[2:4]
    f = np.empty((9, *t.shape))
    f[0] = (sa * sa).sum(0)
    f[1] = (sd * sd).sum(0)
    f[2] = (sa * sd).sum(0)
    f[3] = big_k * big_k
    f[4:6] = big_k * sa
    f[6:8] = big_k * sd
    f[8] = fixes_before * fixes_before
    f *= dt
    # suffix sums over the slots strictly after each
    after = np.cumsum(f[..., ::-1], axis=2)[..., ::-1] - f
    up_to = f[8].sum(1)[:, None] - after[8]  # Σ_{k ≤ m} Δt_k p_k²
    u = c + s / n[:, None]
    quad = ss / (n * n)[:, None] * up_to
    quad += after[0] - 2.0 * tau * after[2] + tau * tau * after[1]
    quad -= 2.0 * (u * (after[4:6] - tau * after[6:8])).sum(0)
    quad += (u * u).sum(0) * after[3]
    return np.maximum(quad, 0.0)


def _products(x: np.ndarray) -> None:
    """Channels 6–10 of fixes ``x`` (``(12, ...)``) from their ``e``, ``D`` and ``A``."""
    x[6] = x[4] * x[0] + x[5] * x[1]  # A·e
    x[7] = x[2] * x[0] + x[3] * x[1]  # D·e
    x[8] = x[4] * x[4] + x[5] * x[5]  # A·A
    x[9] = x[4] * x[2] + x[5] * x[3]  # A·D
    x[10] = x[2] * x[2] + x[3] * x[3]  # D·D


def drift_glr(
    t: np.ndarray,
    e: np.ndarray,
    moved: np.ndarray,
    count: np.ndarray,
    min_span_s: np.ndarray,
    min_support_s: np.ndarray,
    walk: np.ndarray | None = None,
) -> np.ndarray:
    """The drift GLR of L whole windows of fixes (the first ``count[l]`` slots of row ``l``).

    :meth:`DriftWindows.value` after adding every fix of each row (no fix dropped).

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
        As :class:`DriftWindows`'.
    walk : (L,) array, optional
        As :class:`DriftWindows`' (default 0).

    Returns
    -------
    (L,) array
        ``max_m |z_m|`` per row.

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
    lanes, width = t.shape
    w = DriftWindows(lanes, capacity=max(width, 1))
    w.min_span_s[:] = min_span_s
    w.min_support_s[:] = min_support_s
    if walk is not None:
        w.walk[:] = walk
    for j in range(width):
        idx = np.flatnonzero(j < count)
        if len(idx):
            w.add(t[idx, j], idx, e[idx, j], moved[idx, j])
    return w.value(np.arange(lanes))


class DriftGlr:
    """The drift GLR of one run: :class:`DriftWindows` of one lane, fed step by step.

    Call :meth:`move` with every odometry displacement and :meth:`add` with every
    innovation (after that step's :meth:`move`).

    Parameters
    ----------
    window_s, min_span_s, min_support_s : float
        As :class:`DriftWindows`'.

    Examples
    --------
    Straight at 0.5 m/s; from t = 10 s the heading error grows by 0.01 rad/s, so the
    position falls to the right; ±0.1 m of alternating GPS noise:

    >>> g = DriftGlr(60.0, 20.0, 5.0)
    >>> for k in range(1, 601):
    ...     s = 0.05 * k
    ...     g.move(s, 0.025, 0.0)
    ...     if k % 20 == 0:
    ...         fall = 0.01 * 0.5 * max(s - 10.0, 0.0) ** 2 / 2
    ...         g.add(s, 0.1 * (-1) ** k, -fall + 0.1 * (-1) ** (k // 20))
    >>> round(g.value(), 1)
    16.1
    """

    _ONE = np.zeros(1, dtype=int)

    def __init__(self, window_s: float, min_span_s: float, min_support_s: float) -> None:
        self.windows = DriftWindows(1, window_s, min_span_s, min_support_s)
        self.moved = [0.0, 0.0, 0.0, 0.0]  # ΔD, ΔM since the last fix
        self.last = 0.0  # time of the last fix

    def configure(self, window_s: float, min_span_s: float, min_support_s: float,
                  walk: float = 0.0) -> None:
        """Set the window's length, the value's minimum span and onset support and the
        dead reckoning's random walk (m²/s per coordinate)."""
        w = self.windows
        w.window_s[0], w.min_span_s[0], w.min_support_s[0] = window_s, min_span_s, min_support_s
        w.walk[0] = walk

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
        self.windows.add(t, self._ONE, np.array([[ex, ey]]), np.array([self.moved]))
        self.moved = [0.0, 0.0, 0.0, 0.0]
        self.last = t

    def times(self) -> list[float]:
        """The fix times in the window, oldest first."""
        return self.windows.times(0)

    def value(self) -> float:
        """``max_m |z_m|`` (NaN until the window spans ``min_span_s``)."""
        return float(self.windows.value(self._ONE)[0])

    def estimate(self) -> tuple[float, float, float, float, np.ndarray, float, float]:
        """``(z, rate, rate_std, onset, error, bias, bias_std)`` of the most likely drift
        (:meth:`DriftWindows.estimate`; NaNs until the window spans ``min_span_s``)."""
        z, rate, std, onset, error, bias, bias_std = self.windows.estimate(self._ONE)
        return (float(z[0]), float(rate[0]), float(std[0]), float(onset[0]), error[0],
                float(bias[0]), float(bias_std[0]))

    def clear(self) -> None:
        """Forget every fix and displacement."""
        self.windows.clear(self._ONE)
        self.moved = [0.0, 0.0, 0.0, 0.0]
