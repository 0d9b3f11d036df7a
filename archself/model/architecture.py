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
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import AfterValidator, ConfigDict, Field, PrivateAttr, model_validator

from archself.model.qualities import Qualities, Quality
from archself.model.runtime import (
    Ablation,
    Hysteresis,
    Objective,
    Runtime,
    Stability,
)
from archself.model.strategies import Strategy
from archself.model.values import (
    MAX_HORIZON_STEPS,
    MAX_MAGNITUDE,
    MAX_PARAM_NUMBERS,
    MAX_STEP_S,
    MAX_TIME_S,
    MIN_SCALE,
    MIN_STEP_S,
    Finite,
    Name,
    NonNeg,
    ParamValue,
    Positive,
    PositiveSeconds,
    Scale,
    Seconds,
    StrictModel,
)

if TYPE_CHECKING:
    from archself.model.ports import EdgePorts

__all__ = [
    "MAX_HORIZON_STEPS", "MAX_MAGNITUDE", "MAX_PARAM_NUMBERS", "MAX_STEP_S",
    "MAX_TIME_S", "MIN_SCALE", "MIN_STEP_S", "Finite", "Name", "NonNeg", "ParamValue",
    "Positive", "PositiveSeconds", "Scale", "Seconds", "StrictModel",
    "Parameter", "Residual", "ModuleConstraints", "Module", "Edge", "Configuration",
    "Subsystem", "expand_modes",
    "SensitivityEstimate", "RolloutEstimate", "TableEstimate", "Improvement", "Action",
    "Budget", "FaultKind", "Fault", "Scenario",
    "Stability", "Hysteresis", "Ablation", "Objective", "Runtime", "Architecture",
    "Qualities", "Quality", "Strategy",
]

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
        "",  # "" until archself.model.ports fills it from a port; no default in the schema
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
    (:func:`archself.check.graph.check_subsystems` reports it).

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

    _edge_ports: Any = PrivateAttr(None)  # one archself.model.ports.EdgePorts, not one per edge

    @model_validator(mode="after")
    def _ports(self) -> Architecture:
        from archself.model.ports import resolve_edges

        expand_modes(self.configurations, self.subsystems, self.modules)
        self._edge_ports = resolve_edges(self.modules, self.edges)
        return self

    @property
    def edge_ports(self) -> EdgePorts:
        """The ports the edges name (``from``/``to`` as ``module.port``), by edge index.

        Made when the model is built; made again (keeping the ports of the edges it
        knew) when ``edges`` has changed since. Read it once per pass over the edges.
        """
        from archself.model.ports import resolve_edges

        table = self._edge_ports
        if table is None or not table.describes(self.edges):
            table = self._edge_ports = resolve_edges(self.modules, self.edges, table)
        return table

    def initial_configuration(self) -> str:
        """Name of the configuration marked ``initial`` (else the first one)."""
        return next((name for name, conf in self.configurations.items() if conf.initial),
                    next(iter(self.configurations)))
