"""The generic MAPE-K runtime of Algorithm 1 (Franz & Yasin, §4.2).

Nothing here knows a module, configuration or scenario by name: everything is
read from the :class:`archself.model.architecture.Architecture`, and the running system is
reached only through the LiveSystem contract (docs/develop.md).

============================  ==============================================
file                          role
============================  ==============================================
``influence.py``              W (Eq. 13), ρ(W), z = (I − Wᵀ)⁻¹ r (Eq. 14–15)
``candidates.py``             candidate set C: τ, top-k, hysteresis (Eq. 16, 28)
``monitor.py``                J_obs, r (Eq. 11), r_i (Eq. 12), κ_i
``residuals.py``              one module's residual maths: filter gain, r_i, r_sat
``status.py``                 κ_i (``ModuleStatus``, ``StatusMap``), measured limits
``stability.py``              eigenvalue margin (Eq. 21), Lyapunov test (Eq. 24)
``planner.py``                s (Eq. 17), Δ (Eq. 18), score (Eq. 25), argmax (Eq. 26–28)
``constraints.py``            C(a, θ, e) ≤ 0 (Eq. 27): budgets, requires/excludes, ranges
``improvement.py``            Δ_k (Eq. 18): sensitivity, table, rollout
``knowledge.py``              the live architecture graph, t_last
``decisions.py``              the decision log (records, evaluations, ``ValueMap``)
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
    "ActionEvaluation": "decisions",
    "DecisionRecord": "decisions",
    "explain": "decisions",
    "explain_data": "decisions",
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
    from archself.runtime.decisions import ActionEvaluation, DecisionRecord, explain
    from archself.runtime.influence import (
        InfluenceSolver,
        influence,
        spectral_radius,
        weight_matrix,
    )
    from archself.runtime.knowledge import Knowledge
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
