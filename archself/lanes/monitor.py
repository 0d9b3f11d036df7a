"""The Monitor stage of many lanes at once: their residual filters updated as one array.

Every lane keeps its own :class:`~archself.runtime.monitor.Monitor` (inside its
MAPE-K loop): its filter state, its layout, its clock. :func:`observe_group`
does what :meth:`Monitor.observe` does for each lane of one configuration group,
with the filter update, the residuals and the trust test as ``(lanes, modules)``
array operations — the same elementwise operations, so the same numbers — and
returns each lane's :class:`~archself.runtime.monitor.Observation`, which the
lane's loop takes instead of observing (``MapeK(view, observation=...)``).

A lane is left to its own Monitor (no observation returned) whenever the bulk
path would have to decide more than the common case: a module of the lane is
unavailable, or a module of the configuration declares operating ``limits`` (read
from its outputs). A sample that is missing or not finite is handled here as the
Monitor does: that filter keeps its value and the module's κ has a finding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from archself.runtime.monitor import (
    MAX_RESIDUAL,
    Monitor,
    Observation,
    StatusMap,
    confidence_reader,
)

__all__ = ["Observed", "observe_group"]

_NO_FLAGS = np.zeros(0, dtype=np.intp)


def observe_group(
    monitors: list[Monitor], lanes: Any, idx: np.ndarray, j_now: np.ndarray
) -> Observed | None:
    """The Monitor stage of the lanes ``idx`` (one configuration) that the bulk path can make.

    Every observed lane's filters are updated and stored back into its Monitor; its
    :class:`~archself.runtime.monitor.Observation` is made on demand
    (:meth:`Observed.observation`): a lane whose residuals are all 0 and whose κ has no
    finding (:attr:`Observed.zero`) is recorded from the group's numbers
    (:meth:`~archself.runtime.mapek.MapeK.quiet_zeros`) and needs none.

    Parameters
    ----------
    monitors : list of Monitor
        Every lane's Monitor (indexed by lane).
    lanes : LaneSystem
    idx : numpy.ndarray
        The lanes of one configuration group.
    j_now : numpy.ndarray
        J of every lane at this step (the loop's J_obs).

    Returns
    -------
    Observed or None
        The observed lanes; None (or a lane not in :attr:`Observed.lanes`): the lanes
        left out observe on their own.
    """
    group = _gather(monitors, lanes, idx)
    if group is None:
        return None
    return _observed(monitors, group, j_now, *_update(group))


@dataclass(frozen=True)
class _Group:
    """The lanes of a group that the bulk path observes, and what they share."""

    first: Monitor
    lay0: Any
    keep: list[int]
    lays: list[Any]
    X: np.ndarray
    F: np.ndarray
    partial: bool
    whole: np.ndarray | None
    t: float
    dt: float


def _gather(monitors: list[Monitor], lanes: Any, idx: np.ndarray) -> _Group | None:
    """The samples of the lanes ``idx`` the bulk path can observe; None when it cannot
    (operating limits, every lane unavailable, no residual, a lane out of step, bands
    that differ between lanes)."""
    first = monitors[int(idx[0])]
    active = lanes.active_set(int(idx[0]))
    lay0 = first.layout(active)
    if any(limits for *_, limits in lay0.constrained):
        return None
    health = lanes.health
    down = {i for why in health.why.values() for i in why}
    keep = [int(i) for i in idx.tolist() if i not in down]
    if not keep or not lay0.pairs:
        return None
    table = lanes.signal_arrays
    cols = [table(m)[sig] for m, sig in lay0.pairs]
    sel = np.array(keep, dtype=np.intp)
    X = np.stack([np.asarray(c, dtype=float)[sel] for c in cols], axis=1)
    F = np.isfinite(X)  # the usable samples; a filter without one keeps its value
    t = float(lanes.t)
    period = first.arch.runtime.period_s
    prev = first._t_prev
    dt = period if prev is None else t - prev
    if dt <= 0:
        dt = period
    if any(monitors[i]._t_prev != prev for i in keep):
        return None  # a lane out of step with the group: every lane observes alone
    if not _same_bands([monitors[i].nominal for i in keep], first.nominal):
        return None  # bands that differ (runtime.online.bands): every lane observes alone
    lays = [monitors[i].layout(active) for i in keep]
    partial = not F.all()
    whole = F.all(axis=1) if partial else None  # the lanes with every sample usable
    return _Group(first, lay0, keep, lays, X, F, partial, whole, t, dt)


def _same_bands(nominals: list[np.ndarray], first: np.ndarray) -> bool:
    """Whether every lane's bands equal ``first`` (one comparison over the lanes)."""
    if all(nom is first for nom in nominals):
        return True
    try:
        return bool((np.stack(nominals) == first).all())
    except ValueError:  # bands of another size
        return False


def _update(g: _Group) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The filters of every lane updated as ``(lanes, modules)`` arrays, as
    :meth:`Monitor.observe` updates one lane's: ``(value, samples, valid_time, r)``."""
    first, lay0, X, F, dt = g.first, g.lay0, g.X, g.F, g.dt
    # np.array of equal-shaped rows: np.stack's copy, without its Python loops over the lanes
    V = np.array([lay.value for lay in g.lays])
    S = np.array([lay.samples for lay in g.lays])
    VT = np.array([lay.valid_time for lay in g.lays])
    gain = lay0.gains(first, dt)
    with np.errstate(all="ignore"):
        new = V + gain * (X - V)
        if lay0.any_instant:
            f = lay0.instant & (S == 0)
            if f.any():
                new = np.where(f, X, new)
        if g.partial:
            new = np.where(F, new, V)
            S1 = S + F
            VT1 = VT + F * max(dt, 0.0)
        else:
            S1 = S + 1
            VT1 = VT + max(dt, 0.0)
        sens, nom = lay0.sensitivity, lay0.nominal
        if first.normalization == "none":
            res = sens * np.abs(new)
        else:
            res = sens * np.maximum(np.abs(new) - nom, 0.0) / nom
        res = np.where(np.isfinite(new), np.minimum(res, MAX_RESIDUAL), 0.0)
        untrusted = VT1 < np.array([lay.trust_time for lay in g.lays])  # per lane (at start)
        if g.partial:
            untrusted |= ~F  # no residual from a filter that took no sample
        if untrusted.any():
            res = np.where(untrusted, 0.0, res)
    return new, S1, VT1, res


class Observed:
    """The Monitor stage of a configuration group's observed lanes (:func:`observe_group`).

    Attributes
    ----------
    lanes : list of int
        The observed lanes, one row each.
    t : float
        The cycle's time.
    j_obs, j_ref : list of float
        J_obs and J_ref per row (sweep points may differ in ``runtime.objective``).
    zero : numpy.ndarray of bool
        Per row: every r_i is +0 (none negative zero) and κ has no finding (every
        sample usable, no violated constraint).
    """

    __slots__ = ("_R", "_flagged", "_g", "_monitors", "_violated", "_violations", "j_obs",
                 "j_ref", "lanes", "t", "zero")

    def __init__(self, monitors: list[Monitor], g: _Group, j_obs: list[float], R: np.ndarray,
                 violations: dict[str, list[str]], violated: np.ndarray,
                 flagged: np.ndarray) -> None:
        self._monitors, self._g, self._R = monitors, g, R
        self._violations, self._violated, self._flagged = violations, violated, flagged
        self.lanes, self.t, self.j_obs = g.keep, g.t, j_obs
        self.j_ref = [float(monitors[i].arch.runtime.objective.acceptable) for i in g.keep]
        if flagged.size:
            self.zero = np.zeros(len(g.keep), dtype=bool)
        else:
            self.zero = ~(R.astype(bool).any(axis=1) | np.signbit(R).any(axis=1))
            if g.whole is not None:
                self.zero &= g.whole

    def observation(self, row: int) -> Observation:
        """The :class:`Observation` of row ``row`` (as :meth:`Monitor.observe` makes it)."""
        g, lay = self._g, self._g.lays[row]
        mon = self._monitors[g.keep[row]]
        ok, residual_ok, found = lay.all_ok, mon._true, self._flagged
        if g.whole is not None and not g.whole[row]:  # as Monitor._update with unusable samples
            ok = g.F[row]
            residual_ok = mon._true.copy()
            residual_ok[lay.on_pos] = ok
            found = ((self._violated | ~residual_ok) & lay.active).nonzero()[0]
        kappa = StatusMap(
            mon.names, mon.index, lay.active, mon._true, residual_ok, confidence_reader(lay),
            dict(self._violations), {}, found, set(),
        )
        j_obs, j_ref = self.j_obs[row], self.j_ref[row]
        return Observation(
            self.t, j_obs, j_ref, j_ref - j_obs, self._R[row].copy(), kappa,
            lay.on_names, lay.value, ok,
        )


def _observed(
    monitors: list[Monitor], g: _Group, j_now: np.ndarray, new: np.ndarray, S1: np.ndarray,
    VT1: np.ndarray, res: np.ndarray,
) -> Observed:
    """Each lane's filters stored back into its Monitor; the group's :class:`Observed`."""
    first, lay0, t = g.first, g.lay0, g.t
    n = len(first.names)
    R = np.zeros((len(g.keep), n))
    R[:, lay0.on_pos] = res
    violations = {name: list(fixed) for _k, name, fixed, _l in lay0.constrained if fixed}
    violated = np.zeros(n, dtype=bool)
    if violations:
        violated[[k for k, name, *_ in lay0.constrained if name in violations]] = True
    flagged = (violated & lay0.active).nonzero()[0] if violations else _NO_FLAGS
    for i, lay, value, samples, valid in zip(g.keep, g.lays, new, S1, VT1, strict=True):
        monitors[i]._t_prev = t
        lay.value, lay.samples, lay.valid_time = value, samples, valid
    j_obs = j_now[g.keep].tolist()
    return Observed(monitors, g, [math.nan if j != j else j for j in j_obs], R, violations,
                    violated, flagged)
