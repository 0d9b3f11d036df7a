"""Pydantic models of an architecture file: the single source of truth.

An architecture ``a = (M, Γ)`` (paper Eq. 4) is written as a YAML file whose
structure is defined here. ``schemas/architecture.schema.json`` is generated from
these models (``archself schema``); the semantic rules that a schema cannot state
(references resolve, ρ(W) < 1, ...) live in :mod:`archself.check`.

Paper concepts and the keys that hold them:

========================  ==========================================
Concept (paper)           Key
========================  ==========================================
modules M (Eq. 5–7)       ``modules.<name>`` with ``kind``
type τ_i (Eq. 6)          ``modules.<name>.type``
parameter space Θ_i       ``modules.<name>.params``
constraints k_i           ``modules.<name>.constraints``
r_i (Eq. 12)              ``modules.<name>.residual``
edges Γ, ω=W_ji (Eq. 13)  ``edges[*]`` with ``weight``
admissible architectures  ``configurations`` (flat, or composed from
                          ``subsystems`` modes)
A(m_i) (Eq. 18, 25)       ``actions[*]``
C(a, θ, e) ≤ 0 (Eq. 27)   ``constraints[*]``
environment e             ``scenarios``
Algorithm 1 settings      ``runtime``
========================  ==========================================

The values an architecture file may hold: the caps and the constrained number types.

:mod:`archself.model.architecture` builds the file's models from these; the caps are the ranges
docs/format.md states (no number beyond ``MAX_MAGNITUDE``, no time beyond
``MAX_TIME_S``, ...), and :mod:`archself.model.messages` names them in its messages.

The ``strategies`` section: named trees of tactics (the file's actions).

A strategy is keyed to a module, as an action is: when that module is a candidate and
the first step's condition holds, the MAPE-K loop runs the strategy instead of
scoring single actions. Each step names a tactic (an action id), an applicability
condition (``when``), a settle time, a timeout (how long the step may wait for its
tactic to become admissible), a post-condition checked once the tactic has settled
(``post``), and branches: ``success`` and ``failure`` name the next step, ``done``
(the strategy ends) or ``rollback`` (back to the configuration the strategy started
in). The loop runs one tactic per cycle (docs/strategies.md).

The ``qualities`` section: quality attributes, their utility curves and preferences.

A quality attribute (energy, localization accuracy, cost, …) has one value per
configuration — the sum of a module ``resources`` entry over the configuration
(``resource``), or declared per configuration (``values``) — and a utility curve
``u(value) ∈ [0, 1]``, piecewise linear through ``utility`` points ``[value, u]``
(flat outside them). The utility of a configuration is the weighted sum
``U(C) = Σ_q w_q · u_q(value_q(C)) / Σ_q w_q`` under the stated ``preferences``
(weights ``w_q``). The planner (``archself.runtime.planner``) lets U rank the
configurations that deliver the same remedy; hard requirements stay constraints.

The ``runtime`` section of an architecture file: the settings of Algorithm 1.

The clock (``step_s``, ``period_s``), the objective J (Eq. 11), the candidate selector
(τ, top-k or hysteresis; Eq. 16, 28), localization, warm-up, dwell time, the cost
weight λ (Eq. 25), the stability filter (Eq. 21–24), the ablation switches, learning from
outcomes, the risk attitude of Δ and the online updates of W and bands (docs/learning.md).
:class:`archself.model.architecture.Architecture` holds one :class:`Runtime`; the names are
importable from :mod:`archself.model.architecture` too.

Named ports: what a module type takes and gives, and edges that name them.

A module type declares its ports once, next to its parameters::

    ports = (
        Input("q_in", "W", "heat delivered by the heaters", multi=True),
        Input("setpoint", "K", required=False),
        Output("temperature", "K", "air temperature of the zone"),
    )

(a sequence, not a mapping: a plant may take ``u`` and publish the ``u`` it applied)

from which :class:`~archself.modules.base.RuntimeModule` derives ``inputs``,
``optional_inputs``, ``multi_inputs``, ``outputs`` and ``output_sizes`` (the
tuples every other part of archself reads; a type may still set those directly).

An edge names its ends' ports as ``module.port``::

    - {from: heater.q_out, to: zone.q_in, weight: 0.6}

``carries`` is then the source port (``from: heater.q_out`` is ``from: heater``
with ``carries: q_out``) and the target receives the value under its own port name
(``into``). Without ports an edge works as before: ``carries`` names the signal on
both sides. ``archself validate`` (:func:`check_ports`) reports a port the type
does not have (with "did you mean") and a ``carries`` that contradicts ``from``;
the ``double-input`` and ``incomplete`` rules of :mod:`archself.check` count
inputs by the target's port, so a port driven twice in one configuration and a
required input left undriven are errors there.

Examples
--------
>>> split_ref("heater.q_out", ["heater", "zone"])
('heater', 'q_out')
>>> split_ref("zone", ["heater", "zone"])
('zone', None)
>>> split_ref("cell.1.temp", ["cell.1"])   # module names may hold dots
('cell.1', 'temp')
"""

from __future__ import annotations

import dataclasses
import operator
from collections.abc import Iterable, Mapping, Sequence
from typing import Annotated, Any, Literal, Union

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    field_validator,
    model_validator,
)

__all__ = [
    "Ablation", "Action", "Architecture", "Budget", "Condition", "Configuration", "EXITS",
    "Edge", "Fault", "FaultKind", "Finite", "Hysteresis", "Improvement",
    "MAX_HORIZON_STEPS", "MAX_MAGNITUDE", "MAX_PARAM_NUMBERS", "MAX_STEP_S", "MAX_TIME_S",
    "MIN_SCALE", "MIN_STEP_S", "Module", "ModuleConstraints", "Name", "NonNeg", "Objective",
    "ParamValue", "Parameter", "Positive", "PositiveSeconds", "Qualities", "Quality",
    "Residual", "RolloutEstimate", "Runtime", "Scale", "Scenario", "Seconds",
    "SensitivityEstimate", "Stability", "Step", "Strategy", "StrictModel", "Subsystem",
    "TableEstimate", "expand_modes"
]


#: No number of a file is larger in magnitude (in its SI unit): 1e9 m is 2.6 times the
#: distance to the Moon, 1e9 s 31 years. A backstop for quantities without a tighter range:
#: it keeps squares and sums of file values far from float overflow (1e308).
MAX_MAGNITUDE = 1e9
#: The longest time a file states (s): 10^7 s, about 116 days.
MAX_TIME_S = 1e7
#: The shortest simulation step or MAPE-K period (s): 1 µs.
MIN_STEP_S = 1e-6
#: The longest simulation step (s): one hour.
MAX_STEP_S = 3600.0
#: The smallest scale a residual is divided by (``nominal``): below it r_i overflows.
MIN_SCALE = 1e-12
#: Numbers in one parameter value (a 316 × 316 matrix, 100,000 waypoint coordinates).
MAX_PARAM_NUMBERS = 100_000
#: Steps of one Lyapunov rollout (Eq. 22–24), per candidate action and cycle.
MAX_HORIZON_STEPS = 10_000

Finite = Annotated[
    float, Field(allow_inf_nan=False, ge=-MAX_MAGNITUDE, le=MAX_MAGNITUDE)
]
NonNeg = Annotated[float, Field(ge=0, le=MAX_MAGNITUDE, allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, le=MAX_MAGNITUDE, allow_inf_nan=False)]
Seconds = Annotated[float, Field(ge=0, le=MAX_TIME_S, allow_inf_nan=False)]
PositiveSeconds = Annotated[float, Field(gt=0, le=MAX_TIME_S, allow_inf_nan=False)]
Scale = Annotated[float, Field(ge=MIN_SCALE, le=MAX_MAGNITUDE, allow_inf_nan=False)]
Name = Annotated[
    str,
    Field(
        min_length=1,
        max_length=128,
        pattern=r"^[^\x00-\x1f\x7f]+$",
        description="A name: any printable text without control characters.",
    ),
]
def _few_numbers(value: Any) -> Any:
    if isinstance(value, list):
        count = sum(len(v) if isinstance(v, list) else 1 for v in value)
        if count > MAX_PARAM_NUMBERS:
            raise ValueError(
                f"{count:,} numbers in one parameter value, more than the cap of "
                f"{MAX_PARAM_NUMBERS:,}"
            )
    return value


ParamValue = Annotated[
    Union[bool, Finite, str, list[Finite], list[list[Finite]]],  # noqa: UP007
    AfterValidator(_few_numbers),
]


class StrictModel(BaseModel):
    """Base of every model of the file: unknown keys are errors (``extra="forbid"``)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True, frozen=False, defer_build=True)


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


#: Series every run records (archself.sim.run); ``runtime.record`` may not reuse them.
_SERIES = ("t", "J", "reference", "actual", "configuration")
_SELECTORS = ("threshold", "top_k", "hysteresis")

# What the model validator below enforces, stated for other JSON Schema validators too.
_ONE_SELECTOR: dict[str, Any] = {
    "oneOf": [
        {"required": [k], "properties": {k: {"not": {"type": "null"}}}} for k in _SELECTORS
    ]
}


class Stability(StrictModel):
    """Stability-aware action filtering (Eq. 21–24)."""

    margin: Positive = Field(description="ε: require max Re λ(A_k) ≤ −ε (Eq. 21).")
    lyapunov_alpha: Positive = Field(description="α: require E[ΔV|a_k] ≤ −α‖x_t‖² (Eq. 24).")
    horizon_steps: int = Field(
        gt=0, le=MAX_HORIZON_STEPS, description="Rollout length of the Lyapunov test."
    )
    verify: Literal["off", "warning", "error"] = Field(
        "off",
        description="What `archself validate` does with the closed-loop stability of every "
        "configuration and of every action's result (Eq. 21 with this margin, where the "
        "modules give linear models or linearizations): off (default: not checked, and "
        "validate stays light), warning or error (an unstable configuration is a finding of "
        "that severity, located at the configuration, naming max Re λ and the modules the "
        "unstable mode lives in). The check compiles the modules, so it imports what their "
        "types need (python-control, filterpy); only a file that opts in pays for it.",
    )
    marginal: Literal["pass", "warning", "error"] = Field(
        "warning",
        description="What the whole-loop check (with `verify` on) does with a configuration "
        "whose linearized one-step map has a mode with |λ| within 1e-4 of 1 (an integrator "
        "nothing closes, e.g. dead reckoning): pass, warning (default) or error. Such a "
        "configuration is reported as marginal, with the modules the mode lives in.",
    )
    linearize_s: NonNeg = Field(
        0.0,
        le=60.0,
        description="The span of the map the whole-loop check linearizes (s): 0 (default) "
        "the one-step map; a loop closed by a sampled correction (a GPS fix every second) "
        "is closed only over the sampling period, so give that period. |λ| is reported per "
        "step either way.",
    )
    settle_s: NonNeg = Field(
        2.0,
        le=600.0,
        description="The operating point of the whole-loop check at validate: each "
        "configuration is compiled (seed 0) and run this long before it is linearized.",
    )


class Hysteresis(StrictModel):
    """Hysteresis on the candidate threshold: τ_on > τ_off (Eq. 28, alternative)."""

    on: Positive
    off: NonNeg

    @model_validator(mode="after")
    def _order(self) -> Hysteresis:
        if not self.on > self.off:
            raise ValueError("hysteresis needs on > off")
        return self


class Ablation(StrictModel):
    """Stages of Algorithm 1 that can be switched off (all on by default)."""

    propagation: bool = Field(True, description="false: z = r (W = 0 in Analyze).")
    stability: bool = Field(True, description="false: no stability filter (Eq. 21–24).")
    dwell: bool = Field(True, description="false: no dwell time (T_min = 0).")
    paths: bool = Field(
        True,
        description="false: no detour to another configuration when an action's target is "
        "unavailable (archself.runtime.planner).",
    )


class Learning(StrictModel):
    """Learning from outcomes (docs/learning.md): off by default."""

    enabled: bool = Field(
        False,
        description="true: after an action settles, its realized improvement (J before minus J "
        "after, the Monitor's J_obs) updates that action's estimate for its context (the "
        "module it was keyed to, the configuration it was taken in); a failed action is held "
        "back for hold_s. The table is saved with --save-knowledge and loaded with "
        "--knowledge (archself simulate) or MapeK(arch, learned=...).",
    )
    settle_s: Seconds = Field(
        20.0,
        description="The window after an action over which its outcome is measured; J over "
        "its second half is compared with J over the same length before the action.",
    )
    tolerance: NonNeg = Field(
        0.0,
        description="An outcome fails when J after exceeds J before by more than this (J's "
        "unit) plus one standard error of the two means.",
    )
    hold_s: Seconds = Field(
        300.0,
        description="How long an action that failed in a context is held back in it.",
    )
    min_factor: Annotated[float, Field(gt=0, le=1)] = Field(
        0.1,
        description="Floor of the learned factor (successes + 1)/(trials + 1) that scales "
        "the action's estimated Δ in its context.",
    )


class OnlineWeights(StrictModel):
    """Online W (docs/learning.md): the identify fit over a sliding window of the run."""

    enabled: bool = Field(
        False,
        description="true: every every_s the weights of the active edges between modules with "
        "a residual are refitted from the residual history of the last window_s (the fit of "
        "archself identify, on the run's own fluctuations), each change bounded and logged.",
    )
    every_s: PositiveSeconds = Field(60.0, description="Time between two refits.")
    window_s: PositiveSeconds = Field(
        120.0, description="The sliding window of residual history a refit uses."
    )
    max_change: Annotated[float, Field(gt=0, le=1)] = Field(
        0.2,
        description="An update moves a weight by at most this share of its current value.",
    )
    max_factor: Annotated[float, Field(ge=1, le=100)] = Field(
        4.0,
        description="In total a weight stays within [declared/max_factor, declared·max_factor] "
        "(and ≥ 0; a weight declared 0 stays 0).",
    )
    min_r2: Annotated[float, Field(ge=0, le=1)] = Field(
        0.5,
        description="A target's fit counts only with an uncentred R² of at least this; "
        "otherwise its weights are kept (logged as rejected).",
    )
    min_excitation: NonNeg = Field(
        0.05,
        description="A source whose residual moves by no more than this in the window (its "
        "unit: r's) is not identifiable: its weight is kept.",
    )


class OnlineBands(StrictModel):
    """Online bands (docs/learning.md): the calibrate statistics over nominal windows."""

    enabled: bool = Field(
        False,
        description="true: every every_s the bands (residual.nominal) of the active modules "
        "are recomputed from the largest filtered signal in each of the last `windows` "
        "nominal windows (J within acceptable, no action, not in dwell), as archself "
        "calibrate does over runs, each change bounded and logged.",
    )
    every_s: PositiveSeconds = Field(60.0, description="Time between two updates.")
    window_s: PositiveSeconds = Field(20.0, description="The length of one window.")
    windows: int = Field(
        10, ge=3, le=10_000,
        description="The nominal windows an update pools (the most recent); none before "
        "this many.",
    )
    rate: Annotated[float, Field(gt=0, lt=1)] = Field(
        0.01,
        description="The share of nominal windows in which a band may raise a candidate "
        "(split over the active channels, as calibrate's p over runs).",
    )
    max_step: Annotated[float, Field(ge=1, le=100)] = Field(
        1.5, description="An update moves a band by at most this factor."
    )
    max_factor: Annotated[float, Field(ge=1, le=100)] = Field(
        2.0,
        description="In total a band stays at most declared·max_factor: what a fault that "
        "grows inside windows judged nominal (a slow drift) can widen it by.",
    )
    min_factor: Annotated[float, Field(ge=0.01, le=1)] = Field(
        1.0,
        description="In total a band stays at least declared·min_factor: 1 (default), never "
        "tighter than the file's (a band learned in quiet windows would false-alarm when "
        "the conditions change); lower it to let a band the file set too wide come down.",
    )


class Online(StrictModel):
    """Online updates of W and of the residual bands: off by default, bounded, logged."""

    weights: OnlineWeights = Field(
        default_factory=lambda: OnlineWeights.model_validate({}),
        description="W refitted over a sliding window (the identify fit).",
    )
    bands: OnlineBands = Field(
        default_factory=lambda: OnlineBands.model_validate({}),
        description="Residual bands from nominal windows (the calibrate statistics).",
    )

    @property
    def enabled(self) -> bool:
        """Whether either update runs."""
        return self.weights.enabled or self.bands.enabled


class Risk(StrictModel):
    """How sure Δ is: rollouts over sampled noise draws and the rule that ranks them."""

    draws: int = Field(
        1,
        ge=1,
        le=64,
        description="K: a rollout estimate is made over K noise draws (1: one draw, the "
        "snapshots' own random state, as before). Sensitivity and table estimates have one.",
    )
    rule: Literal["mean", "mean_std", "cvar"] = Field(
        "mean",
        description="What ranks the draws: mean; mean_std, mean − kappa·std; cvar, the mean "
        "of the worst alpha share of the draws.",
    )
    kappa: NonNeg = Field(1.0, description="κ of mean_std.")
    alpha: Annotated[float, Field(gt=0, le=1)] = Field(
        0.25, description="The level of cvar: the share of worst draws averaged."
    )


class Objective(StrictModel):
    """J: the error between an actual and a reference signal (Eq. 11)."""

    actual: Name = Field(description="'module.signal' of the true state, e.g. chassis.pose.")
    reference: Name = Field(description="'module.signal' of the reference.")
    components: list[int] = Field(
        default_factory=lambda: [0], description="Vector components compared."
    )
    acceptable: NonNeg = Field(0.0, description="J_ref: the acceptable error level.")
    unit: str | None = Field(
        None,
        description="Unit of J (of the compared components), e.g. m; reports label the error "
        "metrics with it.",
    )


class Runtime(StrictModel):
    """Settings of Algorithm 1 and of the simulation clock; one selector: τ, top-k or hysteresis."""

    model_config = ConfigDict(json_schema_extra=_ONE_SELECTOR)

    step_s: float = Field(
        ge=MIN_STEP_S, le=MAX_STEP_S, allow_inf_nan=False,
        description="Simulation step (1 µs to 1 h).",
    )
    period_s: float = Field(
        ge=MIN_STEP_S, le=MAX_TIME_S, allow_inf_nan=False,
        description="Period of one MAPE-K cycle.",
    )
    objective: Objective
    record: dict[Name, Name] = Field(
        default_factory=dict,
        description="Series a run records besides J and the objective's signals: series name → "
        "output signal, taken each step from the first active module (file order) whose type "
        "publishes it.",
    )
    threshold: Positive | None = Field(None, description="τ of Eq. 16.")
    top_k: int | None = Field(
        None, gt=0, le=10**6, description="Alternative to τ: the k largest |z_i|."
    )
    hysteresis: Hysteresis | None = Field(None, description="τ_on/τ_off instead of τ.")
    localization: Literal["influence", "source", "fit"] = Field(
        "fit",
        description="What drives candidate selection and the planner's weight: fit (default), "
        "few non-negative local faults e on observed and hidden modules that explain the "
        "observed residuals (r_O = P_O e, P = (I − Wᵀ)⁻¹; modules the data cannot tell apart "
        "are kept together as equivalent candidates); source, the clipped inverse "
        "max(0, (I − Wᵀ) r) on the observed modules only; influence, the paper's "
        "z = (I − Wᵀ)⁻¹ r (Eq. 14: largest downstream of a fault, kept as the ablation). "
        "z and the estimate are both logged.",
    )
    normalization: Literal["nominal", "none"] = Field(
        "nominal",
        description="z channels divided by the nominal level each would have (nominal) or raw.",
    )
    warmup_s: Seconds = Field(
        0.0,
        description="Seconds from the first cycle without adaptation (the loop still monitors). "
        "Residuals are also trusted per module, see min_confidence.",
    )
    warmup_steps: int = Field(
        0, ge=0, le=10**9,
        description="Deprecated (use warmup_s): MAPE-K cycles without adaptation.",
    )
    min_confidence: Annotated[float, Field(ge=0, lt=1)] = Field(
        0.5,
        description="A module's residual counts only once its filter has settled: confidence "
        "1 − exp(−t_valid/T) ≥ this (0.5: after T·ln 2 of usable samples). Before, r_i = 0.",
    )
    trust_at_start: bool = Field(
        False,
        description="Filters that start with the run count from their first sample: started at "
        "0, a filter's mean and variance stay below the settled ones its band bounds, so a "
        "healthy module crosses the band no more often; a filter restarted later (a module "
        "activated by a switch, its hand-over transient) waits for min_confidence.",
    )
    isolate_compensated: bool = Field(
        True,
        description="After a structural action keyed to a module, that module's residual is no "
        "longer propagated through W (its own z_i = r_i still shows it) until an action keyed to "
        "it applies again: a compensated fault stops pulling z onto other modules.",
    )
    ablation: Ablation = Field(
        default_factory=lambda: Ablation.model_validate({}),
        description="Stages of Algorithm 1 that can be switched off for an ablation study.",
    )
    dwell_s: Seconds = Field(0.0, description="T_min of Eq. 28.")
    cost_weight: NonNeg = Field(description="λ of Eq. 25.")
    stability: Stability
    max_spectral_radius: Annotated[float, Field(gt=0, lt=1)] = Field(
        0.95, description="ρ(W) must stay below this (Eq. 13)."
    )
    learning: Learning = Field(
        default_factory=lambda: Learning.model_validate({}),
        description="Learning from the outcomes of actions (off by default; docs/learning.md).",
    )
    risk: Risk = Field(
        default_factory=lambda: Risk.model_validate({}),
        description="Δ over sampled noise draws and the risk attitude that ranks them.",
    )
    online: Online = Field(
        default_factory=lambda: Online.model_validate({}),
        description="Online updates of W and of the residual bands (off by default; "
        "docs/learning.md).",
    )

    @property
    def warmup_time_s(self) -> float:
        """The warm-up in seconds: ``max(warmup_s, warmup_steps · period_s)``."""
        return max(float(self.warmup_s), self.warmup_steps * float(self.period_s))

    @field_validator("record")
    @classmethod
    def _series_names(cls, record: dict[str, str]) -> dict[str, str]:
        taken = [k for k in record if k in _SERIES or k.startswith("residual.")]
        if taken:
            raise ValueError(
                f"series name '{taken[0]}' is taken by the run itself "
                f"({', '.join(_SERIES)}, residual.<module>)"
            )
        return record

    @model_validator(mode="after")
    def _one_selector(self) -> Runtime:
        chosen = [k for k in _SELECTORS if getattr(self, k) is not None]
        if len(chosen) != 1:
            raise ValueError("give exactly one of threshold, top_k or hysteresis")
        return self


@dataclasses.dataclass(frozen=True)
class Input:
    """An input port of a module type.

    Parameters
    ----------
    name : str
        The signal name edges deliver it under (``to: module.name``).
    unit : str, optional
        Unit of the value (documentation).
    doc : str, optional
        One line on what the module does with it.
    required : bool, optional
        True (default): a configuration in which no active edge drives it is
        incomplete. False: the module uses it when present.
    multi : bool, optional
        The port takes several edges; the module receives a list, one value per
        edge (file order). Any other port driven by two active edges is an error.
    """

    name: str
    unit: str = ""
    doc: str = ""
    required: bool = True
    multi: bool = False


@dataclasses.dataclass(frozen=True)
class Output:
    """An output port of a module type.

    Parameters
    ----------
    name : str
        The signal name the module publishes it under (``from: module.name``).
    unit : str, optional
        Unit of the value (documentation).
    doc : str, optional
        One line on what it is.
    size : int, optional
        Length of a vector value (lets ``validate`` check objective components).
    elements : tuple of str, optional
        Names of a vector value's elements, in order (``("x", "y", "theta")``): a
        run's table names its columns by them (``actual_x``), not by index.
    """

    name: str
    unit: str = ""
    doc: str = ""
    size: int | None = None
    elements: tuple[str, ...] = ()


def declare(cls: Any) -> None:
    """Derive the signal tuples of ``cls`` from its own ``ports``, if it declares them.

    Raises
    ------
    TypeError
        For an entry that is not an :class:`Input` or :class:`Output`, or a name
        declared twice on the same side.
    """
    ports = cls.__dict__.get("ports")
    if not ports:
        return
    odd = [p for p in ports if not isinstance(p, (Input, Output))]
    if odd:
        raise TypeError(f"{cls.__name__}.ports: {odd[0]!r} is neither an Input nor an Output")
    ins = [p for p in ports if isinstance(p, Input)]
    outs = [p for p in ports if isinstance(p, Output)]
    for side in (ins, outs):
        names = [p.name for p in side]
        twice = next((n for n in names if names.count(n) > 1), None)
        if twice is not None:
            raise TypeError(f"{cls.__name__}.ports: {type(side[0]).__name__} '{twice}' twice")
    cls.inputs = tuple(p.name for p in ins if p.required)
    cls.optional_inputs = tuple(p.name for p in ins if not p.required)
    cls.multi_inputs = tuple(p.name for p in ins if p.multi)
    cls.outputs = tuple(p.name for p in outs)
    cls.output_sizes = {p.name: p.size for p in outs if p.size is not None}
    cls.output_elements = {p.name: tuple(p.elements) for p in outs if p.elements}


def split_ref(ref: str, modules: Iterable[str]) -> tuple[str, str | None]:
    """``module.port`` → ``(module, port)``; a plain module name → ``(module, None)``.

    The module is the longest declared name ``ref`` starts with (followed by a
    dot), so module names with dots work; an undeclared module splits at the first
    dot (the ``reference`` rule then names the unknown module).
    """
    names = modules if isinstance(modules, (set, frozenset, dict)) else set(modules)
    if ref in names:
        return ref, None
    cut = len(ref)
    while (cut := ref.rfind(".", 0, cut)) > 0:  # the longest prefix first: O(dots), not O(M)
        if ref[:cut] in names and cut + 1 < len(ref):
            return ref[:cut], ref[cut + 1 :]
    mod, dot, port = ref.partition(".")
    return (mod, port) if dot and mod and port else (ref, None)


@dataclasses.dataclass(frozen=True)
class EdgePorts:
    """The ports the edges of an architecture name, by edge index (``arch.edge_ports``).

    One plain table per architecture, made once by :func:`resolve_edges`, so the
    loops over 10^5 edges (``validate``, the executor's routes) index tuples instead
    of reading per-edge state off the pydantic models.

    Attributes
    ----------
    edges : tuple of Edge
        The edges it describes, in file order (``arch.edge_ports`` rebuilds the table
        when ``arch.edges`` no longer holds these objects).
    from_port : tuple of str or None
        The output port ``from`` names (``module.port``), else None.
    to_port : tuple of str or None
        The input port ``to`` names (``module.port``), else None.
    """

    edges: tuple[Any, ...]
    from_port: tuple[str | None, ...]
    to_port: tuple[str | None, ...]

    def into(self, i: int) -> str:
        """The input of edge ``i``'s target the value arrives at: the port in ``to``, else
        ``carries``."""
        return self.to_port[i] or self.edges[i].carries

    def describes(self, edges: Sequence[Any]) -> bool:
        """True when ``edges`` are exactly the edge objects of this table, in order."""
        return len(edges) == len(self.edges) and all(map(operator.is_, edges, self.edges))


def resolve_edges(modules: Mapping[str, Any], edges: Iterable[Any],
                  known: EdgePorts | None = None) -> EdgePorts:
    """Split ``from``/``to`` of every edge into module and port: the :class:`EdgePorts`.

    ``carries`` defaults to the source port, else to the target port; an edge's
    ``source``/``target`` are module names afterwards, whatever the file wrote (the
    edges are changed in place). Edges ``known`` describes keep their ports (they
    were split before).
    """
    names = modules if isinstance(modules, (set, frozenset, dict)) else set(modules)
    edges = tuple(edges)
    from_ports: list[str | None] = [None] * len(edges)
    to_ports: list[str | None] = [None] * len(edges)
    before: dict[int, int] = {}  # id of a known edge -> its index in known
    if known is not None:  # known holds its edges, so their ids are not reused meanwhile
        before = {id(e): j for j, e in enumerate(known.edges)}
        for i, e in enumerate(edges):
            j = before.get(id(e))
            if j is not None:
                from_ports[i], to_ports[i] = known.from_port[j], known.to_port[j]
    # the common case, both ends module names, in one comprehension; the rest split here
    for i in [i for i, e in enumerate(edges) if e.source not in names or e.target not in names]:
        e = edges[i]
        if id(e) in before:  # split before (an undeclared module stays one)
            continue
        if e.source not in names:
            e.source, from_ports[i] = split_ref(e.source, names)
        if e.target not in names:
            e.target, to_ports[i] = split_ref(e.target, names)
        if not e.carries and (from_ports[i] or to_ports[i]):
            e.carries = from_ports[i] or to_ports[i]
    return EdgePorts(edges, tuple(from_ports), tuple(to_ports))


_STRUCTURAL = ["substitute", "activate", "deactivate", "rewire"]

# What the model validators below enforce, stated for other JSON Schema validators too.
_ACTION_RULES: dict[str, Any] = {
    "if": {"properties": {"kind": {"enum": _STRUCTURAL}}, "required": ["kind"]},
    "then": {"required": ["to"], "properties": {"to": {"type": "string"}}},
    "else": {"required": ["set"], "properties": {"set": {"type": "object", "minProperties": 1},
                                                  "to": {"type": "null"}}},
}


# --------------------------------------------------------------------------- modules
class Parameter(StrictModel):
    """One dimension of a module's parameter space Θ_i (Eq. 6, 10)."""

    value: ParamValue = Field(description="Nominal value; must lie inside the space.")
    min: Finite | None = Field(None, description="Lower bound (numbers).")
    max: Finite | None = Field(None, description="Upper bound (numbers).")
    choices: list[ParamValue] | None = Field(None, description="Admissible discrete values.")
    unit: str | None = Field(None, description="SI unit, e.g. m, rad/s, Hz.")
    description: str | None = None


class Residual(StrictModel):
    """How the module's local residual r_i = (∂J/∂θ_i)·δθ_i is formed (Eq. 12).

    δθ_i is approximated by a local signal the module publishes (an estimator
    innovation, an actuator command-versus-measured error, a tracking residual),
    divided by its nominal noise level so that channels are comparable.
    """

    signal: Name = Field(description="Name of the local signal the module publishes.")
    sensitivity: Finite = Field(1.0, description="∂J/∂θ_i of Eq. 12 (dimensionless).")
    nominal: Scale = Field(
        description="Nominal noise level of the signal; r_i is expressed in multiples of it "
        "(≥ 1e-12)."
    )
    smoothing_s: Seconds = Field(
        0.0, description="Time constant of a first-order filter on the signal (0 = none)."
    )


class ModuleConstraints(StrictModel):
    """Operational and compatibility constraints k_i (Eq. 6)."""

    requires: list[Name] = Field(
        default_factory=list, description="Modules that must be active whenever this one is."
    )
    excludes: list[Name] = Field(
        default_factory=list, description="Modules that must not be active with this one."
    )
    limits: dict[Name, Finite] = Field(
        default_factory=dict,
        description="Operating limits `max_<x>` / `min_<x>` (C(a, θ, e) ≤ 0, Eq. 27). x is a "
        "parameter of the module (θ: a parameter_update whose new value breaks the limit is "
        "not admissible, rejection `limit`) or a signal it publishes, a residual signal or a "
        "scalar output (e: measured every cycle; a violation is reported in κ_i and blocks "
        "the actions named in `blocks`).",
    )
    blocks: list[Name] | Literal["all"] = Field(
        default_factory=list,
        description="Actions that are not admissible while one of this module's measured "
        "limits is violated: action ids, or `all` (every action whose target configuration "
        "keeps this module active). Empty (default): measured limits are only reported in κ.",
    )


class Module(StrictModel):
    """A module m_i = (τ_i, Θ_i, k_i) of kind physical, functional or model (Eq. 5–7)."""

    kind: Literal["physical", "functional", "model"] = Field(
        description="M_P (sensors, actuators, structure), M_F (processes) or M_M (models)."
    )
    type: Name = Field(description="τ_i: key of a registered module type.")
    description: str | None = None
    params: dict[Name, Parameter] = Field(default_factory=dict, description="Θ_i.")
    constraints: ModuleConstraints = Field(default_factory=ModuleConstraints, description="k_i.")
    resources: dict[Name, NonNeg] = Field(
        default_factory=dict,
        description="Resource use while active, e.g. power_w, compute, latency_ms.",
    )
    residual: Residual | None = Field(None, description="Local residual r_i (Eq. 12).")


# --------------------------------------------------------------------------- edges
def _influence(w: float) -> float:
    if w < 0:
        raise ValueError(f"negative weight {w:g}: influence weights must be ≥ 0 (Eq. 13)")
    return w


class Edge(StrictModel):
    """A dependency (m_j, m_i) ∈ Γ: m_j provides ``carries`` to m_i (Eq. 8–9).

    ``from``/``to`` may name ports as ``module.port`` (see Named ports): the source's
    output port is then ``carries``, and the target receives the value under its input
    port. Without a port in ``to`` the target receives it under ``carries``. Once the
    :class:`Architecture` is built, ``source``/``target`` are module names and the ports
    are in :attr:`Architecture.edge_ports` (one table, not state on each edge).
    """

    # for other JSON Schema validators: carries, or a port in from or to
    model_config = ConfigDict(json_schema_extra={"anyOf": [
        {"required": ["carries"]},
        {"properties": {"from": {"pattern": "[.]"}}},
        {"properties": {"to": {"pattern": "[.]"}}},
    ]})

    source: Name = Field(
        alias="from",
        description="Providing module m_j, or its output port as `module.port` (then "
        "`carries` may be left out).",
    )
    target: Name = Field(
        alias="to",
        description="Receiving module m_i, or its input port as `module.port` (default: the "
        "input named like `carries`).",
    )
    weight: Annotated[Finite, AfterValidator(_influence)] = Field(
        description="Influence ω_ji = W_ji of m_j on m_i, ≥ 0 (Eq. 13).",
        json_schema_extra={"minimum": 0},  # editors refuse a negative weight too
    )
    carries: Name = Field(
        "",  # "" until archself.model.architecture fills it from a port; no default in the schema
        description="The signal that flows, named as the source outputs it; required unless "
        "`from` or `to` names a port (`module.port`).",
        json_schema_extra=lambda s: s.pop("default", None),  # type: ignore[arg-type,misc]
    )
    latency_s: Seconds = Field(0.0, description="Communication latency in seconds.")
    uncertainty: NonNeg = Field(0.0, description="Standard deviation added to the carried value.")
    description: str | None = None


# --------------------------------------------------------------------------- configurations
class Subsystem(StrictModel):
    """A part of the system with its own modes (ROS 2 system_modes' sub-system).

    Each mode names the modules the subsystem runs in it; a configuration composed
    from modes (``Configuration.modes``) picks one mode per subsystem.
    """

    description: str | None = None
    modes: dict[Name, list[Name]] = Field(
        min_length=1, description="Mode name -> the modules active in that mode."
    )


class Configuration(StrictModel):
    """An admissible architecture a ∈ A: the active modules (and optionally edges).

    Flat: ``modules`` lists every active module. Composed: ``modes`` picks a mode of
    each subsystem (subsystem -> mode) and ``modules`` lists the modules outside the
    subsystems; the model expands it into the flat list (file order of ``modules``
    of the file), the one the runtime uses (:func:`expand_modes`).
    """

    model_config = ConfigDict(json_schema_extra={"anyOf": [
        {"required": ["modules"], "properties": {"modules": {"minItems": 1}}},
        {"required": ["modes"]},
    ]})

    description: str | None = None
    modules: list[Name] = Field(
        default_factory=list,
        description="Active modules (composed: those outside the subsystems). Required "
        "unless `modes` is given.",
    )
    modes: dict[Name, Name] | None = Field(
        None, description="Composed from subsystem modes: subsystem -> its mode here "
        "(`subsystems`); a subsystem not named is off."
    )
    disabled_edges: list[tuple[Name, Name]] = Field(
        default_factory=list,
        description="Edges [from, to] between active modules that are switched off here.",
    )
    initial: bool = Field(False, description="The configuration a run starts from.")

    _own: list[str] | None = PrivateAttr(None)  # a composed one's own modules, as written

    @property
    def own_modules(self) -> list[str]:
        """The modules as written: a composed configuration's own (outside its modes)."""
        return self.modules if self._own is None else self._own

    @model_validator(mode="after")
    def _something(self) -> Configuration:
        if not self.modules and self.modes is None:
            raise ValueError("a configuration needs 'modules' (flat) or 'modes' (composed "
                             "from subsystem modes)")
        return self


def expand_modes(
    configurations: dict[str, Configuration], subsystems: dict[str, Subsystem], order: Any
) -> None:
    """Expand every composed configuration into its flat module list, in place.

    The modules are those of the chosen modes plus the configuration's own, once each,
    in the order of ``order`` (the file's modules; names it does not hold last, as
    written, for the checks to report). An unknown subsystem or mode adds nothing
    (:func:`archself.check.rules.check_subsystems` reports it).

    Examples
    --------
    >>> subs = {"loc": Subsystem(modes={"dr": ["odo"], "fused": ["ekf"]})}
    >>> confs = {"a": Configuration(modules=["plant"], modes={"loc": "fused"})}
    >>> expand_modes(confs, subs, ["plant", "odo", "ekf"])
    >>> confs["a"].modules
    ['plant', 'ekf']
    """
    rank = {m: i for i, m in enumerate(order)}
    for conf in configurations.values():
        if conf.modes is None:
            continue
        if conf._own is None:
            conf._own = list(conf.modules)
        wanted = list(conf._own)
        for sub, mode in conf.modes.items():
            wanted += subsystems[sub].modes.get(mode, []) if sub in subsystems else []
        unique = list(dict.fromkeys(wanted))
        conf.modules = sorted(unique, key=lambda m: rank.get(m, len(rank)))


# --------------------------------------------------------------------------- actions
class SensitivityEstimate(StrictModel):
    """Δ_k ≈ −(∂J/∂θ_i)·Δθ_i^k (Eq. 18), Δθ as a fraction of the module's deviation."""

    method: Literal["sensitivity"]
    delta_theta: Finite = Field(
        description="Δθ_i^k as a fraction of the current deviation δθ_i (−1 removes it)."
    )


class RolloutEstimate(StrictModel):
    """Δ_k from a short-horizon rollout of a snapshot of the running system."""

    method: Literal["rollout"]
    horizon_s: PositiveSeconds = Field(description="Length of the rollout.")


class TableEstimate(StrictModel):
    """Δ_k from a precomputed performance table keyed by candidate module."""

    method: Literal["table"]
    values: dict[Name, Finite] = Field(description="Δ when the named module is the candidate.")
    default: Finite = Field(0.0, description="Δ for any other candidate.")


Improvement = Annotated[
    SensitivityEstimate | RolloutEstimate | TableEstimate, Field(discriminator="method")
]


class Action(StrictModel):
    """An admissible action a_k ∈ A(m_i) (paper §4.2, Planning stage).

    ``parameter_update`` changes parameters of ``module`` (``set``); the structural
    kinds ``substitute``, ``activate``, ``deactivate`` and ``rewire`` move the system
    to the declared configuration ``to``; the change they make is the difference
    between the current configuration and ``to``.
    """

    model_config = ConfigDict(json_schema_extra=_ACTION_RULES)

    id: Name
    module: Name = Field(description="m_i: the module whose degradation this action addresses.")
    kind: Literal["parameter_update", "substitute", "activate", "deactivate", "rewire"]
    cost: NonNeg = Field(description="Cost(a_k) of Eq. 25: switching or computational penalty.")
    to: Name | None = Field(None, description="Target configuration of a structural action.")
    applies_in: list[Name] | None = Field(
        None, description="Configurations in which the action is admissible (default: all)."
    )
    set: dict[Name, ParamValue] | None = Field(
        None, description="New parameter values of a parameter_update."
    )
    improvement: Improvement = Field(description="How Δ_k is estimated (Eq. 18).")
    description: str | None = None

    @model_validator(mode="after")
    def _kind_fields(self) -> Action:
        if self.kind == "parameter_update":
            if not self.set:
                raise ValueError("a parameter_update needs 'set' with the new values")
            if self.to is not None:
                raise ValueError("a parameter_update takes 'set', not 'to'")
        elif self.to is None:
            raise ValueError(f"a {self.kind} action needs 'to': the configuration it leads to")
        return self


# --------------------------------------------------------------------------- constraints
class Budget(StrictModel):
    """A system constraint C(a, θ, e) = Σ_{m_i active} use_i(resource) − max ≤ 0 (Eq. 3, 27)."""

    resource: Name = Field(description="Resource summed over active modules, e.g. power_w.")
    max: Finite = Field(description="Budget the sum must not exceed.")
    description: str | None = None


# --------------------------------------------------------------------------- scenarios
FaultKind = Literal[
    "bias_drift", "bias", "effectiveness_loss", "noise_increase", "dropout", "stuck", "nan"
]


class Fault(StrictModel):
    """A fault of the environment e acting on one module's output.

    ``bias_drift``: an offset growing at ``magnitude`` units/s from onset;
    ``bias``: a constant offset; ``effectiveness_loss``: output scaled by
    (1 − magnitude); ``noise_increase``: noise standard deviation multiplied by
    ``magnitude``; ``dropout``: no output; ``stuck``: output frozen at onset;
    ``nan``: the output becomes NaN (a broken value).
    """

    module: Name
    kind: FaultKind
    onset_s: Seconds
    end_s: PositiveSeconds | None = Field(
        None, description="When the fault clears (default: never)."
    )
    magnitude: Finite = 0.0
    signal: Name | None = Field(
        None, description="Affected output (default: the module's main one)."
    )

    @model_validator(mode="after")
    def _window(self) -> Fault:
        if self.end_s is not None and self.end_s <= self.onset_s:
            raise ValueError("end_s must be after onset_s")
        return self


class Scenario(StrictModel):
    """An environment e: a duration, a seed and the faults injected."""

    description: str | None = None
    duration_s: PositiveSeconds
    seed: int = Field(0, ge=0, lt=2**64)
    faults: list[Fault] = Field(default_factory=list)


# --------------------------------------------------------------------------- file
class Architecture(StrictModel):
    """An architecture file: a = (M, Γ) with its configurations, actions and scenarios."""

    def __repr__(self) -> str:
        """One line of counts (the whole model is ``model_dump()``; ``archself info``)."""
        return (f"Architecture(name={self.name!r}, modules={len(self.modules)}, "
                f"edges={len(self.edges)}, configurations={len(self.configurations)}, "
                f"actions={len(self.actions)}, scenarios={len(self.scenarios)})")

    __str__ = __repr__

    def _repr_html_(self) -> str:
        """A short card for notebooks: counts and the first few names of each section."""
        from collections import Counter

        from archself.io.html import card, few

        kinds = Counter(m.kind for m in self.modules.values())
        initial = self.initial_configuration()
        return card(f"{self.name}: " + (self.description or "architecture"), [
            ("modules", f"{len(self.modules)} ({', '.join(f'{v} {k}' for k, v in kinds.items())})"
                        f": {few(list(self.modules))}"),
            ("edges", len(self.edges)),
            ("configurations", few([f"{c} (initial)" if c == initial else c
                                    for c in self.configurations])),
            ("actions", few([a.id for a in self.actions]) or "none"),
            ("scenarios", few(list(self.scenarios)) or "none"),
        ])

    schema_: str | None = Field(None, alias="$schema", description="Optional schema URL.")
    archself: Literal[1] = Field(description="Format version.")
    name: Name
    description: str | None = None
    modules: dict[Name, Module] = Field(min_length=1, description="M = M_P ∪ M_F ∪ M_M.")
    edges: list[Edge] = Field(default_factory=list, description="Γ ⊆ M × M with attributes.")
    subsystems: dict[Name, Subsystem] = Field(
        default_factory=dict,
        description="Parts with their own modes; a configuration may be composed from "
        "them (`configurations.<c>.modes`, docs/format.md).",
    )
    configurations: dict[Name, Configuration] = Field(
        min_length=1, description="Admissible architectures A."
    )
    actions: list[Action] = Field(default_factory=list, description="Admissible actions A(m_i).")
    constraints: list[Budget] = Field(default_factory=list, description="C(a, θ, e) ≤ 0.")
    scenarios: dict[Name, Scenario] = Field(default_factory=dict, description="Environments e.")
    runtime: Runtime
    qualities: Qualities | None = Field(
        None, description="Quality attributes, utility curves and preferences (docs/strategies.md)."
    )
    strategies: dict[Name, Strategy] = Field(
        default_factory=dict, description="Named trees of tactics (docs/strategies.md)."
    )

    _edge_ports: Any = PrivateAttr(None)  # one EdgePorts, not one per edge

    @model_validator(mode="after")
    def _ports(self) -> Architecture:
        expand_modes(self.configurations, self.subsystems, self.modules)
        self._edge_ports = resolve_edges(self.modules, self.edges)
        return self

    @property
    def edge_ports(self) -> EdgePorts:
        """The ports the edges name (``from``/``to`` as ``module.port``), by edge index.

        Made when the model is built; made again (keeping the ports of the edges it
        knew) when ``edges`` has changed since. Read it once per pass over the edges.
        """
        table = self._edge_ports
        if table is None or not table.describes(self.edges):
            table = self._edge_ports = resolve_edges(self.modules, self.edges, table)
        return table

    def initial_configuration(self) -> str:
        """Name of the configuration marked ``initial`` (else the first one)."""
        return next((name for name, conf in self.configurations.items() if conf.initial),
                    next(iter(self.configurations)))
