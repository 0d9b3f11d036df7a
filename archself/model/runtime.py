"""The ``runtime`` section of an architecture file: the settings of Algorithm 1.

The clock (``step_s``, ``period_s``), the objective J (Eq. 11), the candidate selector
(τ, top-k or hysteresis; Eq. 16, 28), localization, warm-up, dwell time, the cost
weight λ (Eq. 25), the stability filter (Eq. 21–24), the ablation switches, learning from
outcomes, the risk attitude of Δ and the online updates of W and bands (docs/learning.md).
:class:`archself.model.architecture.Architecture` holds one :class:`Runtime`; the names are
importable from :mod:`archself.model.architecture` too.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, field_validator, model_validator

from archself.model.values import (
    MAX_HORIZON_STEPS,
    MAX_STEP_S,
    MAX_TIME_S,
    MIN_STEP_S,
    Name,
    NonNeg,
    Positive,
    PositiveSeconds,
    Seconds,
    StrictModel,
)

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
