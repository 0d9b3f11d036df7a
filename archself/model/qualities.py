"""The ``qualities`` section: quality attributes, their utility curves and preferences.

A quality attribute (energy, localization accuracy, cost, …) has one value per
configuration — the sum of a module ``resources`` entry over the configuration
(``resource``), or declared per configuration (``values``) — and a utility curve
``u(value) ∈ [0, 1]``, piecewise linear through ``utility`` points ``[value, u]``
(flat outside them). The utility of a configuration is the weighted sum
``U(C) = Σ_q w_q · u_q(value_q(C)) / Σ_q w_q`` under the stated ``preferences``
(weights ``w_q``). The planner (``archself.runtime.planner``) lets U rank the
configurations that deliver the same remedy; hard requirements stay constraints.
"""

from __future__ import annotations

from pydantic import Field, model_validator

from archself.model.values import Finite, Name, NonNeg, StrictModel

__all__ = ["Qualities", "Quality"]


class Quality(StrictModel):
    """A quality attribute: its value per configuration and its utility curve."""

    description: str | None = None
    unit: str | None = None
    resource: Name | None = Field(
        None, description="The value of a configuration is the sum of this module resource."
    )
    values: dict[Name, Finite] | None = Field(
        None, description="The value of each configuration, declared (configuration -> value)."
    )
    utility: list[tuple[Finite, float]] = Field(
        min_length=2,
        description="Points [value, utility in 0..1] of a piecewise-linear curve, values "
        "increasing; flat outside the first and last point.",
    )

    @model_validator(mode="after")
    def _one_source(self) -> Quality:
        if (self.resource is None) == (self.values is None):
            raise ValueError("a quality takes one of 'resource' or 'values'")
        xs = [x for x, _ in self.utility]
        if any(b <= a for a, b in zip(xs, xs[1:], strict=False)):
            raise ValueError("the utility points' values must increase")
        if any(not 0.0 <= u <= 1.0 for _, u in self.utility):
            raise ValueError("a utility is between 0 and 1")
        return self

    def utility_of(self, value: float) -> float:
        """``u(value)``: linear between the points, flat outside them."""
        pts = self.utility
        if value <= pts[0][0]:
            return float(pts[0][1])
        for (x0, u0), (x1, u1) in zip(pts, pts[1:], strict=False):
            if value <= x1:
                return float(u0 + (u1 - u0) * (value - x0) / (x1 - x0))
        return float(pts[-1][1])


class Qualities(StrictModel):
    """Quality attributes and the preferences (weights) the planner ranks by."""

    attributes: dict[Name, Quality] = Field(min_length=1)
    preferences: dict[Name, NonNeg] = Field(
        description="Weight of each attribute in U (attributes not named weigh 0)."
    )
    weight: NonNeg = Field(
        1.0,
        description="μ: a configuration other than the action's declared target scores "
        "μ·(U(other) − U(target)) more.",
    )

    @model_validator(mode="after")
    def _known(self) -> Qualities:
        unknown = sorted(set(self.preferences) - set(self.attributes))
        if unknown:
            raise ValueError(f"preferences name unknown attribute(s): {', '.join(unknown)}; "
                             f"declared: {', '.join(self.attributes)}")
        if not any(self.preferences.values()):
            raise ValueError("at least one preference weight must be above 0")
        return self
