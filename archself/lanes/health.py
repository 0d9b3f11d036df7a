"""Per-lane health: what :mod:`archself.system.live` and the executor say of one run, for N lanes.

:class:`LaneHealth` keeps, for every module and lane, whether the module is
available and why not — the reasons of the per-run executor, in the same order
of precedence: ``raised <Exception>`` and ``non-finite output`` (the lanes a
module or a fault reports; their outputs are held), ``silent for <t> s`` (no
value for longer than the type's ``max_silence_s``), ``stale <signal> (<n>
identical values)`` (a signal with a declared noise level repeating itself
:data:`~archself.system.live.STALE_REPEATS` times) and ``lost input <signal>`` (a
required input absent in that lane).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import repeat
from operator import is_not
from typing import Any

import numpy as np

from archself.system.live import STALE_REPEATS

__all__ = ["LaneHealth"]


def _present(value: Any, n: int) -> np.ndarray:
    """Lanes (of ``n``) where a lane value is present."""
    if value is None:
        return np.zeros(n, dtype=bool)
    if type(value) is tuple:  # a multi-edge input is a list per run: never missing
        return np.ones(n, dtype=bool)
    if type(value) is list:  # by identity: `None in value` would call each item's __eq__
        present = [v is not None for v in value]
        return np.ones(n, dtype=bool) if all(present) else np.array(present, dtype=bool)
    col = value if value.ndim == 1 else value[:, 0]
    return ~np.isnan(col)


def _floats(value: Any) -> np.ndarray | None:
    """A per-run stale-count value (an array's bytes or a number) as a float row."""
    if value is None:
        return None
    if type(value) is bytes:
        return np.frombuffer(value, dtype=float)
    return np.asarray(value, dtype=float).ravel()


class LaneHealth:
    """Availability of every module in N lanes (the per-run ``_ok``/``_why`` bookkeeping).

    Parameters
    ----------
    n : int
        Number of lanes.
    """

    def __init__(self, n: int) -> None:
        self.n = n
        self.ok: dict[str, np.ndarray] = {}
        self.why: dict[str, dict[int, str]] = {}
        self.heard: dict[str, np.ndarray] = {}  # time of the last value, NaN: none yet
        self.broken: dict[str, np.ndarray] = {}
        self.last: dict[tuple[str, str], np.ndarray] = {}
        self.repeats: dict[tuple[str, str], np.ndarray] = {}
        self._constants: dict[str, tuple[Any, Any]] = {}
        self._any_broken: dict[str, bool] = {}

    def resume(self, systems: Sequence[Any]) -> None:
        """Take over the per-run systems' bookkeeping (one per lane): availability and
        reasons, the time each module was last heard, the broken modules, stale counts."""
        names = {n for s in systems for n in (*s._ok, *s._why, *s._heard, *s._broken)}
        for name in sorted(names):
            ok, why = self.arrays(name)
            for i, s in enumerate(systems):
                ok[i] = s._ok.get(name, True)
                if s._why.get(name):
                    why[i] = s._why[name]
                self.heard[name][i] = s._heard.get(name, math.nan)
                self.broken[name][i] = name in s._broken
            self._any_broken[name] = bool(self.broken[name].any())
        for key in {k for s in systems for k in s._repeats}:
            self.repeats[key] = np.array([s._repeats.get(key, 0) for s in systems])
            last = [_floats(s._last.get(key)) for s in systems]
            width = next((v.size for v in last if v is not None), None)
            if width is not None:
                arr = self.last[key] = np.full((self.n, width), math.nan)
                for i, v in enumerate(last):
                    if v is not None:
                        arr[i] = v

    def arrays(self, name: str) -> tuple[np.ndarray, dict[int, str]]:
        """``ok`` (per lane) and ``why`` (lane -> reason) of ``name``, made on first use."""
        ok = self.ok.get(name)
        if ok is None:
            ok = self.ok[name] = np.ones(self.n, dtype=bool)
            self.why[name] = {}
            self.heard[name] = np.full(self.n, math.nan)
            self.broken[name] = np.zeros(self.n, dtype=bool)
        return ok, self.why[name]

    def constants(self, name: str, modules: list[Any]) -> tuple[Any, Any]:
        """Per-lane noise levels of the noisy signals and silence limits of ``name`` (cached)."""
        got = self._constants.get(name)
        if got is None:
            first = modules[0]
            levels = None
            if getattr(first, "noise_levels", None):
                levels = {
                    sig: np.array([float((getattr(m, "noise_levels", None) or {}).get(sig) or 0.0)
                                   for m in modules])
                    for sig in first.noise_levels
                }
            limit = None
            if any(getattr(m, "max_silence_s", None) is not None for m in modules):
                limit = np.array([float(getattr(m, "max_silence_s", None) or math.inf)
                                  for m in modules])
            got = self._constants[name] = (levels, limit)
        return got

    def unjudged(self, name: str, modules: list[Any]) -> bool:
        """Whether a publishing of ``name`` that no lane failed has nothing to judge:
        no silence limit, no noisy signal, no lane broken (:meth:`published` gives ``{}``)."""
        levels, limit = self.constants(name, modules)
        return levels is None and limit is None and not self._any_broken.get(name)

    def invalidate(self) -> None:
        """A lane's parameters changed: read the noise levels and silence limits again."""
        self._constants.clear()

    def published(
        self,
        name: str,
        out: dict[str, Any],
        idx: np.ndarray,
        t: float,
        failed: dict[int, str],
        modules: list[Any],
    ) -> dict[int, str]:
        """The reasons (lane → why) of a publishing step of lanes ``idx`` (all lanes' values).

        ``out`` holds the lane values of the lanes ``idx`` (rows in their order);
        ``failed`` the lanes whose module raised or went non-finite (not published).
        """
        if not failed and self.unjudged(name, modules):
            return {}  # nothing to judge: no failure, no silence limit, no noisy signal
        levels, limit = self.constants(name, modules)
        self.arrays(name)
        heard_t = self.heard[name]
        broken = self.broken[name]
        reasons = dict(failed)
        m = len(idx)
        good = None
        if failed:
            for i, why in failed.items():
                if why == "non-finite output":
                    broken[i] = True
                    self._any_broken[name] = True
            good = np.array([i not in failed for i in idx.tolist()], dtype=bool)
        heard = np.zeros(m, dtype=bool)
        for v in out.values():
            if v is not None:
                present = _present(v, m)
                if present.all():
                    heard = present
                    break
                heard |= present
        if good is not None:
            heard &= good
        all_heard = heard.all()
        lanes_heard = idx if all_heard else idx[heard]
        heard_t[lanes_heard] = t
        if self._any_broken.get(name):
            broken[lanes_heard] = False
        if levels:
            self._repeats(name, out, idx, heard, levels, reasons)
        if all_heard:
            return reasons
        quiet = ~heard if good is None else good & ~heard
        quiet_lanes = idx[quiet]
        for i in quiet_lanes[broken[quiet_lanes]]:
            reasons.setdefault(int(i), "non-finite output")
        if limit is not None:
            fresh = np.isnan(heard_t[idx])
            heard_t[idx[fresh]] = t
            gap = t - heard_t[idx]
            for j in np.flatnonzero(quiet & (gap > limit[idx] + 1e-9)):
                reasons.setdefault(int(idx[j]), f"silent for {gap[j]:.3g} s")
        if levels:  # a quiet lane whose last values repeated: the first such signal
            for sig in levels:
                rep = self.repeats.get((name, sig))
                if rep is not None:
                    for i in quiet_lanes[rep[quiet_lanes] >= STALE_REPEATS].tolist():
                        reasons.setdefault(i, f"stale {sig} ({int(rep[i]) + 1} identical values)")
        return reasons

    def _repeats(self, name, out, idx, heard, levels, reasons) -> None:
        """Count bit-identical repeats of the noisy signals per lane (per run: the step's
        generated repeat counts, ``system.live._health_lines``).

        ``heard``: the lanes that published a value; only they can be stale here.
        """
        for sig, level in levels.items():
            key = (name, sig)
            rep = self.repeats.get(key)
            if rep is None:
                rep = self.repeats[key] = np.zeros(self.n, dtype=np.int64)
            v = out.get(sig)
            if v is not None and type(v) is not list:
                rows = v if v.ndim == 2 else v[:, None]
                use = heard & _present(v, len(idx)) & (level[idx] > 0)
                last = self.last.get(key)
                if last is None:
                    last = self.last[key] = np.full((self.n, rows.shape[1]), math.nan)
                if use.all():
                    same = (rows == last[idx]).all(axis=1)
                    rep[idx] = np.where(same, rep[idx] + 1, 0)
                    last[idx] = rows
                else:
                    lanes = idx[use]
                    if len(lanes):
                        same = (rows[use] == last[lanes]).all(axis=1)
                        rep[lanes] = np.where(same, rep[lanes] + 1, 0)
                        last[lanes] = rows[use]
            for i in idx[heard & (rep[idx] >= STALE_REPEATS)].tolist():
                reasons.setdefault(i, f"stale {sig} ({int(rep[i]) + 1} identical values)")

    def settle(self, name: str, idx: np.ndarray, reasons: dict[int, str]) -> None:
        """Set ``ok``/``why`` of lanes ``idx`` from ``reasons`` (the lanes not named are ok)."""
        ok, why = self.arrays(name)
        if why:  # a lane is down: ok is False exactly where why has a reason
            ok[idx] = True
            for i in idx.tolist():
                why.pop(i, None)
        for i, r in reasons.items():
            ok[i] = False
            why[i] = r

    def lost_inputs(
        self, inputs: dict[str, Any], required: tuple[str, ...], idx: np.ndarray,
        reasons: dict[int, str],
    ) -> None:
        """Add ``lost input <s>`` to the lanes of ``idx`` without a reason whose ``s`` is absent."""
        for s in required:
            v = inputs.get(s)
            if type(v) is np.ndarray:  # present in every lane unless the sum is NaN
                if not math.isnan(np.add.reduce(v if v.ndim == 1 else v[:, 0])):
                    continue
            elif type(v) is list and all(map(is_not, v, repeat(None))):
                continue  # objects in every lane (by identity, no item's __eq__)
            for i in idx[~_present(v, len(idx))].tolist():
                reasons.setdefault(i, f"lost input {s}")

    def forget(self, name: str, lanes: np.ndarray) -> None:
        """A module deactivated in ``lanes``: its availability and silence clock start over."""
        if name in self.ok:
            self.ok[name][lanes] = True
            for i in lanes.tolist():
                self.why[name].pop(i, None)
            self.heard[name][lanes] = math.nan
            self.broken[name][lanes] = False

    def any_down(self) -> bool:
        """Whether some module is unavailable in some lane."""
        return any(self.why.values())

    def available(self, name: str, i: int) -> bool:
        """Whether ``name`` is available in lane ``i``."""
        ok = self.ok.get(name)
        return True if ok is None else bool(ok[i])

    def reason(self, name: str, i: int) -> str | None:
        """Why ``name`` is unavailable in lane ``i`` (None when it is available)."""
        if self.available(name, i):
            return None
        return self.why[name].get(i)
