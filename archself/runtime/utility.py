"""Weighted utility of a configuration under the file's quality preferences.

``U(C) = Σ_q w_q · u_q(value_q(C)) / Σ_q w_q`` (:mod:`archself.model.architecture`):
``value_q(C)`` is the sum of the attribute's ``resource`` over the configuration's
modules, or its declared value; ``u_q`` its utility curve; ``w_q`` the preference.

The score of a declared action is Eq. 25 as it is; a configuration the planner reaches
in its place (a detour around an unavailable target, or an alternative that keeps the
same remedy, :mod:`archself.runtime.paths`) scores ``μ·(U(C) − U(T))`` more, T being the
declared target: the remedy's worth is the action's, the preferences say which of the
configurations holding it to land in. Without a ``qualities`` section U is 0.
"""

from __future__ import annotations

from typing import Any

from archself.model.architecture import Architecture

__all__ = ["Utility"]


class Utility:
    """U(C) and the attribute values behind it, cached per configuration.

    Parameters
    ----------
    arch : Architecture
        Reads ``qualities``, ``configurations`` and the modules' ``resources``.
    """

    def __init__(self, arch: Architecture) -> None:
        self.arch = arch
        self.qualities = arch.qualities
        self.weight = self.qualities.weight if self.qualities is not None else 0.0
        self._cache: dict[str, dict[str, Any]] = {}

    @property
    def on(self) -> bool:
        """Whether the file declares quality attributes."""
        return self.qualities is not None

    def of(self, configuration: str) -> dict[str, Any]:
        """``{"U": U(C), "attributes": {q: {"value", "utility"}}}`` of a configuration."""
        found = self._cache.get(configuration)
        if found is not None:
            return found
        q = self.qualities
        attrs: dict[str, dict[str, float]] = {}
        total = weights = 0.0
        conf = self.arch.configurations.get(configuration)
        if q is not None and conf is not None:
            for name, attr in q.attributes.items():
                if attr.resource is not None:
                    value = sum(
                        float(self.arch.modules[m].resources.get(attr.resource, 0.0))
                        for m in conf.modules if m in self.arch.modules
                    )
                else:
                    value = float((attr.values or {}).get(configuration, float("nan")))
                u = attr.utility_of(value) if value == value else 0.0
                attrs[name] = {"value": value, "utility": u}
                w = float(q.preferences.get(name, 0.0))
                total += w * u
                weights += w
        found = {"U": total / weights if weights > 0 else 0.0, "attributes": attrs}
        self._cache[configuration] = found
        return found

    def bonus(self, configuration: str, declared: str) -> float:
        """``μ·(U(configuration) − U(declared))`` (0 without qualities)."""
        if self.qualities is None or configuration == declared:
            return 0.0
        return self.weight * (self.of(configuration)["U"] - self.of(declared)["U"])
