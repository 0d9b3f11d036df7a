"""κ_i, the status indicators of the modules (Eq. 17), and the measured limits they check.

:class:`ModuleStatus` is one module's κ; :class:`StatusMap` is κ of every module
over the Monitor's arrays, building a :class:`ModuleStatus` only when one is looked
up. :func:`limit_violations` judges a module's declared ``max_<signal>`` /
``min_<signal>`` limits against its signals; :func:`is_limit_violation` tells those
lines from ``requires``/``excludes`` ones.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from archself.runtime.residuals import to_float

__all__ = ["ModuleStatus", "StatusMap", "is_limit_violation", "limit_violations"]


@dataclass
class ModuleStatus:
    """κ_i: status indicators of one module (Eq. 17)."""

    active: bool
    available: bool = True
    residual_ok: bool = True
    confidence: float = 1.0
    violations: list[str] = field(default_factory=list)
    reason: str | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "active": self.active,
            "available": self.available,
            "residual_ok": self.residual_ok,
            "confidence": float(self.confidence),
            "violations": list(self.violations),
        }
        if self.reason is not None:
            out["reason"] = self.reason
        return out


@dataclass(eq=False, repr=False)
class StatusMap(Mapping[str, ModuleStatus]):
    """κ of every module (Eq. 17) as a read-only mapping, built on demand.

    The Monitor keeps the status of all modules in arrays; a
    :class:`ModuleStatus` is only created when a module is looked up (and then
    kept, so repeated look-ups give the same object). :meth:`findings` lists the
    modules with something to report without touching the others, which is what
    keeps a cycle on 10^4 modules cheap.

    Parameters
    ----------
    names : list of str
        All modules, in index order (iteration order of the mapping).
    index : dict
        name -> position in ``names``.
    active, available, residual_ok : numpy.ndarray of bool
        Per position.
    confidence : callable
        position -> confidence of the module's residual filter.
    violations : dict
        name -> violated constraints (active modules with at least one).
    reasons : dict
        name -> reason of an active unavailable module (may be None).
    finding : numpy.ndarray of int
        Positions of the active modules that are unavailable, have an unusable
        residual signal or violate a constraint, ascending.
    unavailable : set of str
        The names where ``available`` is False.
    """

    _names: list[str]
    _index: dict[str, int]
    _active: np.ndarray
    _available: np.ndarray
    _residual_ok: np.ndarray
    _confidence: Callable[[int], float]
    _violations: dict[str, list[str]]
    _reasons: dict[str, str | None]
    _finding: np.ndarray
    _down: set[str]
    _built: dict[str, ModuleStatus] = field(default_factory=dict, init=False)

    def __getitem__(self, name: str) -> ModuleStatus:
        status = self._built.get(name)
        if status is None:
            k = self._index[name]
            status = ModuleStatus(
                active=bool(self._active[k]),
                available=bool(self._available[k]),
                residual_ok=bool(self._residual_ok[k]),
                confidence=self._confidence(k),
                violations=list(self._violations.get(name, ())),
                reason=self._reasons.get(name),
            )
            self._built[name] = status
        return status

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)

    def findings(self) -> list[tuple[str, ModuleStatus]]:
        """``(name, κ)`` of the active modules with a finding, in index order.

        A finding is: unavailable, residual signal unusable, or a violated
        constraint (what the decision log records).
        """
        names = self._names
        return [(names[k], self[names[k]]) for k in self._finding.tolist()]

    def unavailable(self) -> set[str]:
        """Names of the modules the system reports unavailable (active or not)."""
        return self._down


def limit_violations(
    limits: Mapping[str, Any], local: Mapping[str, Any], outputs: Mapping[str, Any] | None = None
) -> list[str]:
    """Declared ``max_<signal>``/``min_<signal>`` limits the module's signals break (e).

    The signal is a local (residual) signal, else a scalar output the module published
    this step; a limit on anything else (a parameter, θ) is judged by the planner.
    Each line starts with the limit's key (:func:`is_limit_violation`).
    """
    out = []
    for key, limit in limits.items():
        for prefix, worse in (("max_", float.__gt__), ("min_", float.__lt__)):
            if key.startswith(prefix):
                name = key[len(prefix) :]
                if name in local:
                    raw = local[name]
                else:
                    raw = outputs.get(name) if outputs else None
                    if isinstance(raw, np.ndarray):
                        raw = raw.item() if raw.size == 1 else None
                value = to_float(math.nan if raw is None else raw)
                if math.isfinite(value) and worse(value, float(limit)):
                    out.append(f"{key} {limit:g} violated ({value:g})")
    return out


def is_limit_violation(text: str) -> bool:
    """True for a κ violation line of a measured limit (not ``requires``/``excludes``)."""
    return text.startswith(("max_", "min_"))
