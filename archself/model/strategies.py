"""The ``strategies`` section: named trees of tactics (the file's actions).

A strategy is keyed to a module, as an action is: when that module is a candidate and
the first step's condition holds, the MAPE-K loop runs the strategy instead of
scoring single actions. Each step names a tactic (an action id), an applicability
condition (``when``), a settle time, a timeout (how long the step may wait for its
tactic to become admissible), a post-condition checked once the tactic has settled
(``post``), and branches: ``success`` and ``failure`` name the next step, ``done``
(the strategy ends) or ``rollback`` (back to the configuration the strategy started
in). The loop runs one tactic per cycle (docs/strategies.md).
"""

from __future__ import annotations

from pydantic import Field, model_validator

from archself.model.values import Name, NonNeg, PositiveSeconds, Seconds, StrictModel

__all__ = ["EXITS", "Condition", "Step", "Strategy"]

#: The branch targets that end a strategy.
EXITS = ("done", "rollback")


class Condition(StrictModel):
    """What must hold (all the given parts): the configuration, the module's r_i, J."""

    configuration: list[Name] | None = Field(
        None, description="The current configuration is one of these."
    )
    residual_above: NonNeg | None = Field(None, description="r_i of the strategy's module > this.")
    residual_below: NonNeg | None = Field(None, description="r_i of the strategy's module < this.")
    objective_below: NonNeg | None = Field(None, description="J_obs < this (the objective's unit).")

    @model_validator(mode="after")
    def _something(self) -> Condition:
        if all(v is None for v in (self.configuration, self.residual_above,
                                   self.residual_below, self.objective_below)):
            raise ValueError("a condition needs at least one of configuration, residual_above, "
                             "residual_below, objective_below")
        return self


class Step(StrictModel):
    """One tactic of a strategy and where to go after it."""

    tactic: Name = Field(description="The id of the action this step executes.")
    when: Condition | None = Field(None, description="Applicability condition (default: always).")
    settle_s: Seconds = Field(0.0, description="Time after the tactic before the post-check.")
    timeout_s: PositiveSeconds | None = Field(
        None, description="How long the step may wait for its tactic to be admissible "
        "(default: one cycle); then the failure branch."
    )
    post: Condition | None = Field(None, description="Post-condition (default: success).")
    success: Name = Field("done", description="Next step, 'done' or 'rollback'.")
    failure: Name = Field("rollback", description="Next step, 'done' or 'rollback'.")


class Strategy(StrictModel):
    """A named tree of tactics for one module's degradation."""

    description: str | None = None
    module: Name = Field(description="m_i: the module whose degradation this strategy addresses.")
    start: Name = Field(description="The first step.")
    steps: dict[Name, Step] = Field(min_length=1)
