"""A module's health from what it publishes: non-finite values, silence, stale noisy signals.

:class:`Publishing` is the part of :class:`archself.system.executor.LiveSystem` that applies
a module's faults to its outputs, publishes them and says why the module is
unavailable, if it is: a non-finite value (the module stays broken until it
publishes a good one), silence longer than the type's ``max_silence_s``, or a
signal with a declared noise level (``noise_levels``) that repeats the same value
:data:`STALE_REPEATS` times in a row (real noise never repeats bit for bit). It
works on the system's state (``outputs``, ``_pool``, ``_faults``, ``_heard``,
``_last``, ``_repeats``, ``_broken``, ``_not_numeric``), which ``LiveSystem``
creates and copies.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.modules.base import RuntimeModule

__all__ = ["NOT_NUMERIC", "Publishing", "STALE_REPEATS", "declared_limits", "is_bad",
           "needs_checks"]

_isfinite = math.isfinite
NOT_NUMERIC: frozenset[type] = frozenset({str, bool, type(None)})  # never numbers

#: A noisy signal repeating the same value this many times in a row is stale.
STALE_REPEATS = 3


def is_bad(value: Any) -> bool:
    """True for a non-finite float or an array with a non-finite entry."""
    tp = type(value)
    if tp is float:
        return not math.isfinite(value)
    if tp is np.ndarray:
        if value.dtype.kind != "f":
            return False
        flat = value.tolist() if value.ndim == 1 else value.ravel().tolist()
        return not math.isfinite(sum(flat))
    if isinstance(value, (float, np.floating)):
        return not math.isfinite(float(value))
    return False


def declared_limits(module: RuntimeModule) -> tuple[Any, Any]:
    """``(max_silence_s, noise_levels)`` of ``module``: what its silence and stale checks need."""
    return getattr(module, "max_silence_s", None), getattr(module, "noise_levels", None)


def needs_checks(module: RuntimeModule, faults: Any = None) -> bool:
    """Whether the executor checks what ``module`` publishes (:meth:`Publishing._publish`).

    False only when nothing there can fail: the type declares ``finite_outputs``
    (:class:`~archself.modules.base.RuntimeModule`: finite inputs give finite outputs),
    no fault is injected into its outputs, and it declares neither a silence limit
    (``max_silence_s``) nor noise levels (``noise_levels``). A type that declares
    nothing keeps every check. Raising and lost inputs are checked for every module.
    """
    return bool(
        faults
        or not getattr(type(module), "finite_outputs", False)
        or getattr(module, "max_silence_s", None) is not None
        or getattr(module, "noise_levels", None)
    )


class Publishing:
    """The publishing half of a :class:`~archself.system.executor.LiveSystem` step (a mixin)."""

    outputs: dict[str, dict[str, Any]]
    _pool: dict[str, RuntimeModule]
    _faults: dict[str, list[tuple[str, Any]]]
    _heard: dict[str, float]
    _last: dict[tuple[str, str], Any]
    _repeats: dict[tuple[str, str], int]
    _broken: set[str]
    _not_numeric: set[type]

    def _publish(
        self, name: str, out: dict[str, Any] | None, t: float, limits: tuple[Any, Any] | None = None
    ) -> str | None:
        """Apply the faults and publish ``out``; the reason the module is unavailable, or None.

        The reason covers the module's own output only: a non-finite value, silence
        longer than its ``max_silence_s``, or a noisy signal (``noise_levels``) that
        repeated itself ``STALE_REPEATS`` times. ``limits``: the module's
        ``(max_silence_s, noise_levels)`` as the caller read them (None: read here).
        """
        if out is None:
            out = {}
        faults = self._faults.get(name)
        if faults:
            out = dict(out)
            for sig, inj in faults:
                if sig in out:
                    out[sig] = inj.apply(t, out[sig])
        heard = False
        for v in out.values():
            if v is None:
                continue
            tp = type(v)
            if tp is float:  # inlined is_bad for the common types (a hot loop)
                bad = not _isfinite(v)
            elif tp is np.ndarray:
                bad = v.dtype.kind == "f" and not _isfinite(
                    sum(v.tolist() if v.ndim == 1 else v.ravel().tolist())
                )
            elif tp in self._not_numeric:  # model objects, strings: nothing to check
                bad = False
            else:
                bad = is_bad(v)
                if not bad and not isinstance(v, (float, int, np.number)):
                    self._not_numeric.add(tp)
            if bad:
                self._broken.add(name)
                return "non-finite output"
            heard = True
        self.outputs[name] = out
        if heard:
            self._heard[name] = t
            if self._broken:
                self._broken.discard(name)
        elif name in self._broken:  # its last value was NaN: broken until a good one comes
            return "non-finite output"
        limit, levels = limits or declared_limits(self._pool[name])
        if limit is not None:  # (quiet is 0 when heard now)
            quiet = t - self._heard.setdefault(name, t)
            if quiet > float(limit) + 1e-9:
                return f"silent for {quiet:.3g} s"
        return self._count_repeats(name, levels, out) if levels else None

    def _count_repeats(
        self, name: str, levels: dict[str, float], out: dict[str, Any]
    ) -> str | None:
        """Count bit-identical repeats of the noisy signals; the stale reason, or None.

        A signal without a value this step keeps its count (and stays stale).
        """
        last = self._last
        repeats = self._repeats
        reason = None
        for sig, level in levels.items():
            v = out.get(sig)
            if v is None or not level or level <= 0:
                n = repeats.get((name, sig), 0)
            else:
                key = (name, sig)
                cur = v.tobytes() if type(v) is np.ndarray else v
                n = repeats[key] = repeats.get(key, 0) + 1 if last.get(key) == cur else 0
                last[key] = cur
            if n >= STALE_REPEATS and reason is None:
                reason = f"stale {sig} ({n + 1} identical values)"
        return reason
