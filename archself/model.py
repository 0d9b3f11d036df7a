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
admissible architectures  ``configurations``
A(m_i) (Eq. 18, 25)       ``actions[*]``
C(a, θ, e) ≤ 0 (Eq. 27)   ``constraints[*]``
environment e             ``scenarios``
Algorithm 1 settings      ``runtime``
========================  ==========================================
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, Literal, Union

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    field_validator,
    model_validator,
)

if TYPE_CHECKING:
    from archself.ports import EdgePorts

FORMAT_VERSION = 1

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


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True, frozen=False)


#: Series every run records (archself.sim.run); ``runtime.record`` may not reuse them.
_SERIES = ("t", "J", "reference", "actual", "configuration")
_STRUCTURAL = ["substitute", "activate", "deactivate", "rewire"]
_SELECTORS = ("threshold", "top_k", "hysteresis")

# What the model validators below enforce, stated for other JSON Schema validators too.
_ACTION_RULES: dict[str, Any] = {
    "if": {"properties": {"kind": {"enum": _STRUCTURAL}}, "required": ["kind"]},
    "then": {"required": ["to"], "properties": {"to": {"type": "string"}}},
    "else": {"required": ["set"], "properties": {"set": {"type": "object", "minProperties": 1},
                                                  "to": {"type": "null"}}},
}
_ONE_SELECTOR: dict[str, Any] = {
    "oneOf": [
        {"required": [k], "properties": {k: {"not": {"type": "null"}}}} for k in _SELECTORS
    ]
}


# --------------------------------------------------------------------------- modules
class Parameter(_Strict):
    """One dimension of a module's parameter space Θ_i (Eq. 6, 10)."""

    value: ParamValue = Field(description="Nominal value; must lie inside the space.")
    min: Finite | None = Field(None, description="Lower bound (numbers).")
    max: Finite | None = Field(None, description="Upper bound (numbers).")
    choices: list[ParamValue] | None = Field(None, description="Admissible discrete values.")
    unit: str | None = Field(None, description="SI unit, e.g. m, rad/s, Hz.")
    description: str | None = None


class Residual(_Strict):
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


class ModuleConstraints(_Strict):
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


class Module(_Strict):
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
class Edge(_Strict):
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
    weight: Finite = Field(description="Influence ω_ji = W_ji of m_j on m_i, ≥ 0 (Eq. 13).")
    carries: Name = Field(
        "",  # "" until archself.ports fills it from a port; no default in the schema
        description="The signal that flows, named as the source outputs it; required unless "
        "`from` or `to` names a port (`module.port`).",
        json_schema_extra=lambda s: s.pop("default", None),  # type: ignore[arg-type,misc]
    )
    latency_s: Seconds = Field(0.0, description="Communication latency in seconds.")
    uncertainty: NonNeg = Field(0.0, description="Standard deviation added to the carried value.")
    description: str | None = None


# --------------------------------------------------------------------------- configurations
class Configuration(_Strict):
    """An admissible architecture a ∈ A: the active modules (and optionally edges)."""

    description: str | None = None
    modules: list[Name] = Field(min_length=1, description="Active modules.")
    disabled_edges: list[tuple[Name, Name]] = Field(
        default_factory=list,
        description="Edges [from, to] between active modules that are switched off here.",
    )
    initial: bool = Field(False, description="The configuration a run starts from.")


# --------------------------------------------------------------------------- actions
class SensitivityEstimate(_Strict):
    """Δ_k ≈ −(∂J/∂θ_i)·Δθ_i^k (Eq. 18), Δθ as a fraction of the module's deviation."""

    method: Literal["sensitivity"]
    delta_theta: Finite = Field(
        description="Δθ_i^k as a fraction of the current deviation δθ_i (−1 removes it)."
    )


class RolloutEstimate(_Strict):
    """Δ_k from a short-horizon rollout of a snapshot of the running system."""

    method: Literal["rollout"]
    horizon_s: PositiveSeconds = Field(description="Length of the rollout.")


class TableEstimate(_Strict):
    """Δ_k from a precomputed performance table keyed by candidate module."""

    method: Literal["table"]
    values: dict[Name, Finite] = Field(description="Δ when the named module is the candidate.")
    default: Finite = Field(0.0, description="Δ for any other candidate.")


Improvement = Annotated[
    SensitivityEstimate | RolloutEstimate | TableEstimate, Field(discriminator="method")
]


class Action(_Strict):
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
class Budget(_Strict):
    """A system constraint C(a, θ, e) = Σ_{m_i active} use_i(resource) − max ≤ 0 (Eq. 3, 27)."""

    resource: Name = Field(description="Resource summed over active modules, e.g. power_w.")
    max: Finite = Field(description="Budget the sum must not exceed.")
    description: str | None = None


# --------------------------------------------------------------------------- scenarios
FaultKind = Literal[
    "bias_drift", "bias", "effectiveness_loss", "noise_increase", "dropout", "stuck", "nan"
]


class Fault(_Strict):
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


class Scenario(_Strict):
    """An environment e: a duration, a seed and the faults injected."""

    description: str | None = None
    duration_s: PositiveSeconds
    seed: int = Field(0, ge=0, lt=2**64)
    faults: list[Fault] = Field(default_factory=list)


# --------------------------------------------------------------------------- runtime
class Stability(_Strict):
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


class Hysteresis(_Strict):
    """Hysteresis on the candidate threshold: τ_on > τ_off (Eq. 28, alternative)."""

    on: Positive
    off: NonNeg

    @model_validator(mode="after")
    def _order(self) -> Hysteresis:
        if not self.on > self.off:
            raise ValueError("hysteresis needs on > off")
        return self


class Ablation(_Strict):
    """Stages of Algorithm 1 that can be switched off (all on by default)."""

    propagation: bool = Field(True, description="false: z = r (W = 0 in Analyze).")
    stability: bool = Field(True, description="false: no stability filter (Eq. 21–24).")
    dwell: bool = Field(True, description="false: no dwell time (T_min = 0).")


class Objective(_Strict):
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


class Runtime(_Strict):
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
    localization: Literal["influence", "source"] = Field(
        "influence",
        description="What drives candidate selection and the planner's weight: influence, the "
        "paper's z = (I − Wᵀ)⁻¹ r (Eq. 14: largest downstream of a fault), or source, the local "
        "faults e ≥ 0 that explain r = (I − Wᵀ)⁻¹ e (largest at the fault's origin). Both are "
        "logged.",
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
        chosen = [k for k in ("threshold", "top_k", "hysteresis") if getattr(self, k) is not None]
        if len(chosen) != 1:
            raise ValueError("give exactly one of threshold, top_k or hysteresis")
        return self


# --------------------------------------------------------------------------- file
class Architecture(_Strict):
    """An architecture file: a = (M, Γ) with its configurations, actions and scenarios."""

    schema_: str | None = Field(None, alias="$schema", description="Optional schema URL.")
    archself: Literal[1] = Field(description="Format version.")
    name: Name
    description: str | None = None
    modules: dict[Name, Module] = Field(min_length=1, description="M = M_P ∪ M_F ∪ M_M.")
    edges: list[Edge] = Field(default_factory=list, description="Γ ⊆ M × M with attributes.")
    configurations: dict[Name, Configuration] = Field(
        min_length=1, description="Admissible architectures A."
    )
    actions: list[Action] = Field(default_factory=list, description="Admissible actions A(m_i).")
    constraints: list[Budget] = Field(default_factory=list, description="C(a, θ, e) ≤ 0.")
    scenarios: dict[Name, Scenario] = Field(default_factory=dict, description="Environments e.")
    runtime: Runtime

    _edge_ports: Any = PrivateAttr(None)  # one archself.ports.EdgePorts, not one per edge

    @model_validator(mode="after")
    def _ports(self) -> Architecture:
        from archself.ports import resolve_edges

        self._edge_ports = resolve_edges(self.modules, self.edges)
        return self

    @property
    def edge_ports(self) -> EdgePorts:
        """The ports the edges name (``from``/``to`` as ``module.port``), by edge index.

        Made when the model is built; made again (keeping the ports of the edges it
        knew) when ``edges`` has changed since. Read it once per pass over the edges.
        """
        from archself.ports import resolve_edges

        table = self._edge_ports
        if table is None or not table.describes(self.edges):
            table = self._edge_ports = resolve_edges(self.modules, self.edges, table)
        return table

    def initial_configuration(self) -> str:
        """Name of the configuration marked ``initial`` (else the first one)."""
        for name, conf in self.configurations.items():
            if conf.initial:
                return name
        return next(iter(self.configurations))
