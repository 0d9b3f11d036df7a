"""The generic MAPE-K runtime of Algorithm 1 (Franz & Yasin, §4.2).

Nothing here knows a module, configuration or scenario by name: everything is
read from the :class:`archself.model.architecture.Architecture`, and the running system is
reached only through the LiveSystem contract (docs/develop.md).

============================  ==============================================
file                          role (the loop's steps)
============================  ==============================================
``monitor.py``                Monitor: J_obs, r (Eq. 11), r_i (Eq. 12), κ_i
                              (``ModuleStatus``, ``StatusMap``), the residual
                              maths of one module, measured limits
``influence.py``              Analyze: W (Eq. 13), ρ(W), z = (I − Wᵀ)⁻¹ r
                              (Eq. 14–15), the local faults ê (``SourceFit``)
``planner.py``                Plan: candidate set C (Eq. 16, 28), s (Eq. 17),
                              Δ (Eq. 18, rollouts and risk), constraints
                              (Eq. 27), detours, utility, score and argmax
                              (Eq. 25–28)
``stability.py``              eigenvalue margin (Eq. 21), Lyapunov test (Eq. 24)
``strategies.py``             the running strategy's state and its cycle
``knowledge.py``              Knowledge: the live architecture graph, t_last,
                              the decision log (``DecisionRecord``,
                              ``ValueMap``), learned outcomes, online W/bands
``explanation.py``            :func:`explain` and ``explain_data``: the log for a person
``mapek.py``                  :class:`MapeK`: one cycle of Algorithm 1
============================  ==============================================
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

# Attributes are imported lazily (PEP 562) so that ``archself explain`` — which only
# needs :func:`explain` — does not pay for scipy and networkx.
_LAZY = {
    "ActionEvaluation": "knowledge",
    "DecisionRecord": "knowledge",
    "explain": "explanation",
    "explain_data": "explanation",
    "InfluenceSolver": "influence",
    "influence": "influence",
    "spectral_radius": "influence",
    "weight_matrix": "influence",
    "Knowledge": "knowledge",
    "MapeK": "mapek",
    "StabilityVerdict": "stability",
}

__all__ = [
    "ActionEvaluation",
    "DecisionRecord",
    "InfluenceSolver",
    "Knowledge",
    "MapeK",
    "StabilityVerdict",
    "explain",
    "influence",
    "spectral_radius",
    "weight_matrix",
]

if TYPE_CHECKING:  # pragma: no cover
    from archself.runtime.explanation import explain
    from archself.runtime.influence import (
        InfluenceSolver,
        influence,
        spectral_radius,
        weight_matrix,
    )
    from archself.runtime.knowledge import ActionEvaluation, DecisionRecord, Knowledge
    from archself.runtime.mapek import MapeK
    from archself.runtime.stability import StabilityVerdict


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'archself.runtime' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"archself.runtime.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
