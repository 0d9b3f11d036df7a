"""The candidate set C of modules to adapt (paper Eq. 16 and the hysteresis of §4.2).

Three selectors, chosen by the ``runtime`` block of the architecture file:

- ``threshold: τ`` — ``C = {m_i : |z_i| ≥ τ}`` (Eq. 16), :func:`threshold_candidates`;
- ``top_k: k`` — the ``k`` modules with the largest non-zero ``|z_i|``,
  :func:`top_k_candidates`;
- ``hysteresis: {on, off}`` — a module enters C when ``|z_i| ≥ τ_on`` and leaves it
  only when ``|z_i| < τ_off`` (τ_on > τ_off), :class:`HysteresisSelector`.

With ``runtime.localization: fit`` (the default) or ``source`` the same selectors
run on the source estimate ê (:mod:`~archself.runtime.sources`) instead of z; ``symbol`` names the
quantity in :meth:`CandidateSelector.describe`.

Every selector returns the candidates ordered by decreasing ``|z_i|``, equal
magnitudes by name. ``select(z, values)`` may be given ``values``, the array of
``z``'s values in its key order: the test on ``|z_i|`` then runs on the array
(same result, far cheaper on 10^4 modules).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from archself.model.architecture import Runtime

__all__ = [
    "CandidateSelector",
    "HysteresisSelector",
    "ThresholdSelector",
    "TopKSelector",
    "selector_from_runtime",
    "threshold_candidates",
    "top_k_candidates",
]


def _ranked(z: Mapping[str, float], names: Iterable[str]) -> list[str]:
    """Names by decreasing ``|z|``; ties (equal to 12 significant digits) by name.

    Comparing rounded magnitudes keeps the order of equal channels fixed when the
    last bits of z change with the BLAS or SuperLU build.
    """
    return sorted(names, key=lambda n: (-float(f"{abs(z[n]):.12g}"), n))


def _ranked_where(z: Mapping[str, float], mask: np.ndarray) -> list[str]:
    """:func:`_ranked` of the keys of ``z`` where the boolean array ``mask`` holds."""
    index = mask.nonzero()[0].tolist()
    if not index:  # most cycles: nothing to rank
        return []
    keys = list(z)
    return _ranked(z, [keys[i] for i in index])


def threshold_candidates(z: Mapping[str, float], tau: float) -> list[str]:
    """Modules with ``|z_i| ≥ τ`` (Eq. 16), largest first.

    Examples
    --------
    >>> threshold_candidates({"a": 0.2, "b": -0.9, "c": 0.6}, 0.55)
    ['b', 'c']
    """
    return _ranked(z, [n for n, v in z.items() if abs(v) >= tau])


def top_k_candidates(z: Mapping[str, float], k: int) -> list[str]:
    """The ``k`` modules with the largest ``|z_i|``, ignoring ``z_i = 0``.

    Examples
    --------
    >>> top_k_candidates({"a": 0.2, "b": -0.9, "c": 0.0}, 2)
    ['b', 'a']
    """
    return _ranked(z, [n for n, v in z.items() if v != 0.0])[:k]


class CandidateSelector:
    """Base class: ``select(z[, values]) -> list of module names``, largest ``|z|`` first.

    ``values``, when given, is ``numpy.array(list(z.values()))`` (computed
    already by the caller); selectors use it to test every module at once.
    ``symbol`` names the quantity selected on in :meth:`describe` (``z`` or ``ê``).
    """

    symbol = "z"

    def select(
        self, z: Mapping[str, float], values: np.ndarray | None = None
    ) -> list[str]:  # pragma: no cover - abstract
        raise NotImplementedError

    def entering(self, z: Mapping[str, float], values: np.ndarray | None = None) -> list[str]:
        """The modules that would enter C on ``z`` now, without changing the selector's state.

        A second look in the same cycle (the echo of a source whose action waits out the
        dwell time, :class:`~archself.runtime.mapek.MapeK`); stateless selectors select.
        """
        return self.select(z, values)

    def reset(self) -> None:
        """Forget any state (nothing for the stateless selectors)."""

    def describe(self) -> str:  # pragma: no cover - abstract
        raise NotImplementedError


class ThresholdSelector(CandidateSelector):
    """``|z_i| ≥ τ`` (Eq. 16)."""

    def __init__(self, tau: float, symbol: str = "z") -> None:
        self.tau = float(tau)
        self.symbol = symbol

    def select(self, z: Mapping[str, float], values: np.ndarray | None = None) -> list[str]:
        if values is None:
            return threshold_candidates(z, self.tau)
        return _ranked_where(z, np.abs(values) >= self.tau)

    def describe(self) -> str:
        return f"|{self.symbol}| >= {self.tau:g}"


class TopKSelector(CandidateSelector):
    """The ``k`` largest non-zero ``|z_i|``."""

    def __init__(self, k: int, symbol: str = "z") -> None:
        self.k = int(k)
        self.symbol = symbol

    def select(self, z: Mapping[str, float], values: np.ndarray | None = None) -> list[str]:
        if values is None:
            return top_k_candidates(z, self.k)
        return _ranked_where(z, values != 0.0)[: self.k]

    def describe(self) -> str:
        return f"top {self.k} by |{self.symbol}|"


class HysteresisSelector(CandidateSelector):
    """Candidate set with hysteresis: enter at ``|z| ≥ on``, leave at ``|z| < off``.

    Parameters
    ----------
    on, off : float
        Thresholds τ_on > τ_off ≥ 0.

    Examples
    --------
    >>> sel = HysteresisSelector(on=0.6, off=0.3)
    >>> sel.select({"a": 0.5})      # below on: not yet a candidate
    []
    >>> sel.select({"a": 0.7})      # crosses on: enters
    ['a']
    >>> sel.select({"a": 0.4})      # between off and on: stays
    ['a']
    >>> sel.select({"a": 0.2})      # below off: leaves
    []
    """

    def __init__(self, on: float, off: float, symbol: str = "z") -> None:
        self.symbol = symbol
        if not on > off:
            raise ValueError("hysteresis needs on > off")
        self.on = float(on)
        self.off = float(off)
        self.members: set[str] = set()

    def select(self, z: Mapping[str, float], values: np.ndarray | None = None) -> list[str]:
        keep = {n for n in self.members if n in z and abs(z[n]) >= self.off}
        if values is None:
            enter = {n for n, v in z.items() if abs(v) >= self.on}
        else:
            keys = list(z)
            enter = {keys[i] for i in (np.abs(values) >= self.on).nonzero()[0].tolist()}
        self.members = keep | enter
        return _ranked(z, self.members)

    def entering(self, z: Mapping[str, float], values: np.ndarray | None = None) -> list[str]:
        """``|z| ≥ on``, the members left as they are."""
        return threshold_candidates(z, self.on)

    def reset(self) -> None:
        self.members.clear()

    def describe(self) -> str:
        s = self.symbol
        return f"hysteresis on |{s}| >= {self.on:g}, off |{s}| < {self.off:g}"


def selector_from_runtime(runtime: Runtime) -> CandidateSelector:
    """The selector the ``runtime`` block declares (exactly one is given).

    It selects on z with ``localization: influence``, else on the source estimate ê.
    """
    symbol = "z" if runtime.localization == "influence" else "ê"
    if runtime.hysteresis is not None:
        return HysteresisSelector(runtime.hysteresis.on, runtime.hysteresis.off, symbol)
    if runtime.top_k is not None:
        return TopKSelector(runtime.top_k, symbol)
    assert runtime.threshold is not None
    return ThresholdSelector(runtime.threshold, symbol)
