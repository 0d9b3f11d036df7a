"""The interface every runtime module implements.

A runtime module is the live counterpart of one ``modules.<name>`` entry of an
architecture file. The system executor (:mod:`archself.system.live`) runs modules as
a synchronous data-flow graph with Simulink semantics:

1. every module with ``direct_feedthrough = False`` (a plant, a filter whose
   output depends on its state only) publishes :meth:`RuntimeModule.output`
   from its state at time ``t``;
2. the other modules run :meth:`RuntimeModule.step` in topological order of the
   active edges (edges *into* non-feedthrough modules are cut, which breaks every
   feedback loop), each receiving ``inputs`` = {signal name: value} from the
   edges that end at it;
3. the non-feedthrough modules then :meth:`RuntimeModule.step` with their inputs
   to advance their state from ``t`` to ``t + dt``.

Signals are named by the edge's ``carries``: the source publishes it in its
output dict and the target receives it under the same key. A value of ``None``
means "not available this step" (a GPS between fixes, a sensor in dropout);
modules must tolerate missing inputs.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, NamedTuple

import numpy as np

from archself.errors import ArchselfError, SimulationError


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()  #: the default of a parameter the file must give


@dataclasses.dataclass(frozen=True)
class Param:
    """A parameter a module type declares: its default and unit, written once.

    Parameters
    ----------
    default : object, optional
        Value used when the file does not give one; leave it out for a parameter
        the file must give.
    unit : str, optional
        Unit of the value (documentation and reports).
    doc : str, optional
        One line on what it sets.
    min, max : float, optional
        The physically meaningful range of every number of the value (a scalar, or
        each entry of a list or matrix). ``archself validate`` refuses a file value,
        a file ``min``/``max`` or an action's ``set`` outside it; without them only
        the global cap ``archself.model.architecture.MAX_MAGNITUDE`` (1e9) applies.
    period : bool, optional
        The value is the time between two events (unit ``s``) or their rate (unit
        ``Hz``): ``archself validate`` refuses a nonzero one shorter than
        ``runtime.step_s`` (the events could not happen that often).

    Examples
    --------
    >>> Param(0.2, "m").required, Param().required
    (False, True)
    >>> Param(0.5, "m", "wheel base", min=0.01, max=10.0).max
    10.0
    """

    default: Any = REQUIRED
    unit: str = ""
    doc: str = ""
    min: float | None = None
    max: float | None = None
    period: bool = False

    @property
    def required(self) -> bool:
        """True when the file must give the value."""
        return self.default is REQUIRED

    def outside(self, value: Any) -> str | None:
        """Why ``value`` (a number, or a list or matrix of them) leaves the range, or None.

        Examples
        --------
        >>> Param(0.5, "m", min=0.01, max=100.0).outside([0.5, 1e8])
        '1e+08 is outside [0.01, 100] m'
        >>> Param(0.5, "m", min=0.01).outside(0.5) is None
        True
        """
        lo, hi = self.min, self.max
        if lo is None and hi is None:
            return None
        stack = [value]
        while stack:
            v = stack.pop()
            if isinstance(v, (list, tuple)):
                stack.extend(reversed(v))
            elif isinstance(v, (int, float)) and not isinstance(v, bool):
                if (lo is not None and v < lo) or (hi is not None and v > hi):
                    low = "-∞" if lo is None else f"{lo:g}"
                    high = "∞" if hi is None else f"{hi:g}"
                    unit = f" {self.unit}" if self.unit else ""
                    return f"{v:g} is outside [{low}, {high}]{unit}"
        return None


class Port(NamedTuple):
    """One active edge into a module, as :meth:`RuntimeModule.linear_model` sees it.

    A named tuple: a closed loop of 10^4 modules passes some 10^4 of them.

    Attributes
    ----------
    source : str
        The module the edge comes from.
    size : int or None
        Width of the signal in the source's :class:`LinearModel` (None: the source
        gives no linear model, or not this signal).
    value : object
        The source's current value of the signal (None: nothing published yet).
    """

    source: str
    size: int | None = None
    value: Any = None


@dataclasses.dataclass
class LinearModel:
    """A module's linear model with named inputs and outputs (state space).

    ``x⁺ = A x + B u, y = C x + D u`` in discrete time with period ``dt`` (the
    run's step), or ``ẋ = A x + B u, y = C x + D u`` when ``dt = 0`` (the system
    discretizes it with a zero-order hold at its step). ``u`` stacks the
    ``inputs`` and ``y`` the ``outputs`` in the order given, as python-control's
    named-signal ``ss`` systems do. An input port ``(signal, size)`` receives the
    sum of every active edge that carries ``signal`` into the module; a port
    ``(signal, size, k)`` only the ``k``-th of them (0-based, in file order).

    Parameters
    ----------
    A, B, C, D : array_like
        The matrices (n×n, n×m, p×n, p×m; n may be 0 for a static block).
    inputs, outputs : sequence of tuple
        ``(signal, size)`` or ``(signal, size, edge)`` per port.
    dt : float
        0 for continuous time, else the sample time (s).
    states : sequence of str, optional
        A label per state (reports say which states an unstable mode lives in).

    Examples
    --------
    >>> g = LinearModel([], [], [], [[2.0]], inputs=[("u", 1)], outputs=[("y", 1)], dt=0.1)
    >>> g.n, g.m, g.p
    (0, 1, 1)
    """

    A: Any
    B: Any
    C: Any
    D: Any
    inputs: Sequence[tuple[Any, ...]] = ()
    outputs: Sequence[tuple[Any, ...]] = ()
    dt: float = 0.0
    states: Sequence[str] = ()

    def __post_init__(self) -> None:
        self.inputs = tuple(
            (str(p[0]), int(p[1]), None if len(p) < 3 or p[2] is None else int(p[2]))
            for p in self.inputs
        )
        self.outputs = tuple((str(p[0]), int(p[1])) for p in self.outputs)
        m = sum(p[1] for p in self.inputs)
        q = sum(p[1] for p in self.outputs)
        A = np.asarray(self.A, dtype=float)
        n = A.shape[0] if A.size else 0
        self.A = A.reshape(n, n)
        self.B = np.asarray(self.B, dtype=float).reshape(n, m)
        self.C = np.asarray(self.C, dtype=float).reshape(q, n)
        self.D = np.asarray(self.D, dtype=float).reshape(q, m)
        self.dt = float(self.dt)
        labels = tuple(str(s) for s in self.states)
        self.states = labels if len(labels) == n else tuple(f"x{k}" for k in range(n))

    @property
    def n(self) -> int:
        """Number of states."""
        return int(self.A.shape[0])

    @property
    def m(self) -> int:
        """Width of the stacked input."""
        return int(self.B.shape[1])

    @property
    def p(self) -> int:
        """Width of the stacked output."""
        return int(self.C.shape[0])


class RuntimeModule:
    """Base class of runtime modules.

    Parameters
    ----------
    name : str
        The module's name in the architecture file.
    params : dict
        Nominal parameter values (``modules.<name>.params.<p>.value``).
    rng : numpy.random.Generator
        The module's own random stream (deterministic per seed and name).

    Attributes
    ----------
    type_key : str
        Registry key, set by :func:`archself.registry.register`.
    role : str
        What the module does: ``plant``, ``sensor``, ``actuator``, ``estimator``,
        ``controller``, ``planner``, ``model`` or another word a plugin chooses.
    inputs : tuple of str
        Signals the module needs; a configuration is incomplete if one of them
        has no active edge delivering it.
    optional_inputs : tuple of str
        Signals the module uses when present.
    multi_inputs : tuple of str
        Inputs (among the two above) that may arrive over several active edges:
        the module receives a list with one value per edge (in file order; None
        where a source has nothing this step). Any other signal delivered by two
        active edges is a validation error.
    outputs : tuple of str
        Signals the module publishes.
    residual_signals : tuple of str
        Local signals usable as ``residual.signal`` (Eq. 12).
    fault_kinds : frozenset of str
        Fault kinds a scenario may inject into this module's outputs.
    direct_feedthrough : bool
        False when outputs depend only on the state (plants).
    parameters : mapping of str to Param, or None
        Every parameter the type reads, with its default and unit: the one place a
        parameter is named. ``self.params`` holds the defaults overlaid with the
        file's values; ``archself validate`` reports missing required and unknown
        parameters. None (the default for plugins that predate it): not checked.
    ports : sequence of archself.model.architecture.Input and Output, or None
        Every signal the type takes and gives, with unit and doc, next to
        ``parameters``: ``inputs``, ``optional_inputs``, ``multi_inputs``, ``outputs``
        and ``output_sizes`` are derived from it when the class defines it
        (:mod:`archself.model.architecture`). None: the tuples are set directly.
    """

    type_key: ClassVar[str] = ""
    role: ClassVar[str] = "module"
    inputs: ClassVar[tuple[str, ...]] = ()
    optional_inputs: ClassVar[tuple[str, ...]] = ()
    multi_inputs: ClassVar[tuple[str, ...]] = ()
    outputs: ClassVar[tuple[str, ...]] = ()
    #: Length of each vector output (a scalar is 1); lets ``validate`` check the
    #: objective's component indices. Signals not listed are not checked.
    output_sizes: ClassVar[Mapping[str, int]] = {}
    #: Names of a vector output's elements (``{"pose": ("x", "y", "theta")}``): a run's
    #: columns are ``actual_x`` … instead of ``actual_0`` … (``RunResult.to_pandas``).
    output_elements: ClassVar[Mapping[str, tuple[str, ...]]] = {}
    residual_signals: ClassVar[tuple[str, ...]] = ()
    fault_kinds: ClassVar[frozenset[str]] = frozenset()
    direct_feedthrough: ClassVar[bool] = True
    parameters: ClassVar[Mapping[str, Param] | None] = None
    ports: ClassVar[Sequence[Any] | None] = None
    #: Nominal noise level per output signal (instance attribute of sensors): a noisy
    #: signal repeating itself bit for bit is stale (see :mod:`archself.system.live`).
    noise_levels: dict[str, float] | None = None
    #: Longest time without a published value before the module counts as silent (s).
    max_silence_s: float | None = None
    #: True when finite inputs and parameters always give finite outputs (or None): the
    #: executor then skips the scan of this type's outputs for NaN/inf, unless a fault
    #: is injected into them; the stale and silence checks of ``noise_levels`` and
    #: ``max_silence_s`` stay (:func:`archself.system.live.publish_checks`). False (the
    #: default, safe): every output is checked every step (docs/hardening.md).
    finite_outputs: ClassVar[bool] = False
    #: The batched class of this type (a :class:`archself.lanes.LaneModule` subclass built
    #: from N instances, or its ``"package.module:Class"`` path), or None: lanes of it run
    #: one by one (:class:`archself.lanes.PerLane`). See docs/lanes.md.
    lanes: ClassVar[type | str | None] = None
    #: The instance attributes that hold the module's dynamic state (floats and float
    #: arrays, in this order): what :meth:`state` packs and :meth:`set_state` writes back,
    #: the columns the whole-loop linearization perturbs (docs/stability.md). None (the
    #: default): every float or float-array instance attribute that ``configure()`` does
    #: not set (those are parameters) and that is not monitoring bookkeeping
    #: (:data:`NOT_STATE`); ``()``: no state (a timer, a clock-driven source).
    state_fields: ClassVar[tuple[str, ...] | None] = None
    #: True on the copies the whole-loop linearization steps: a module whose step is
    #: smooth but for a quantizer (a sensor's resolution) leaves it out there, so the
    #: slope is the quantizer's mean gain 1 rather than 0 (docs/stability.md).
    smooth: bool = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        from archself.model.architecture import declare

        declare(cls)  # the signal tuples from ``ports``, when the class declares them

    def __init__(self, name: str, params: dict[str, Any], rng: np.random.Generator) -> None:
        self.name = name
        self.params = self.default_params()
        self.params.update(params)
        self.rng = rng
        self.signals: dict[str, float] = {}
        self.configure()

    @classmethod
    def memory_estimate(cls, params: dict[str, Any], dt: float) -> int:
        """Bytes a module of this type would allocate when built with ``params`` (the
        file's values over the defaults) and run at step ``dt``; 0: nothing worth counting.

        ``archself validate`` refuses a module over ``check_runs.MAX_MODULE_BYTES``
        before it is built (a type whose memory grows with a parameter, e.g. a path
        table with its length, says so here).
        """
        return 0

    @classmethod
    def param_warnings(cls, params: dict[str, Any], residual: str | None) -> list[tuple[str, str]]:
        """``(parameter, why)`` of values that are valid but likely mean something else:
        ``archself validate`` warns at each parameter. ``params`` are the file's values,
        ``residual`` the module's residual signal (None: none). Default: none.
        """
        return []

    @classmethod
    def check_params(cls, name: str, params: dict[str, Any], dt: float) -> str | None:
        """Why ``params`` cannot make a module of this type, or None: ``archself validate``
        turns it into an error located at the module's parameters.

        By default one module is built and dropped (its constructor is the check of
        shapes and combinations the declared ranges cannot state); the exception's
        message is the reason. A type whose construction is expensive may check its
        parameters here without building.
        """
        try:
            cls(name, params, np.random.default_rng(0))
        except Exception as exc:  # any refusal of the type, said as its message
            text = " ".join(str(exc).split()) or type(exc).__name__
            return text if isinstance(exc, (ValueError, ArchselfError)) else (
                f"{type(exc).__name__}: {text}")
        return None

    @classmethod
    def default_params(cls) -> dict[str, Any]:
        """The declared defaults (fresh copies: a module may change its own)."""
        return {k: copy.deepcopy(p.default) for k, p in (cls.parameters or {}).items()
                if not p.required}

    def configure(self) -> None:
        """Derive working values from ``self.params``.

        Called at the end of construction and after every :meth:`set_params`, so a
        type that caches anything computed from its parameters does it here, once.
        """

    # ----------------------------------------------------------------- data flow
    def output(self, t: float) -> dict[str, Any]:
        """Outputs from the state at ``t`` (non-feedthrough modules only)."""
        return {}

    def step(self, t: float, dt: float, inputs: dict[str, Any]) -> dict[str, Any]:
        """Consume ``inputs`` at ``t``; return outputs (feedthrough) or advance the state."""
        return {}

    # ----------------------------------------------------------------- monitoring
    def local_signals(self) -> dict[str, float]:
        """Current values of :attr:`residual_signals` (Eq. 12), NaN when unknown."""
        return dict(self.signals)

    def linearization(self) -> np.ndarray | None:
        """Closed-loop system matrix A of Eq. 20 around the current point, if known.

        The fallback of :meth:`linear_model`: a module that gives no linear model
        contributes this matrix as a diagonal block of the configuration's A, and so
        does a module whose linear model closes no loop with the others (a
        controller over a plant that has no model of its own).
        """
        return None

    def linear_model(self, dt: float, inputs: Mapping[str, Sequence[Port]]) -> LinearModel | None:
        """This module's linear model around the current point, with named signals.

        The system wires the models of a configuration's modules along its active
        edges (signals by ``carries``) into the closed-loop A of Eq. 20
        (:meth:`archself.system.live.LiveSystem.closed_loop`); it asks in execution order,
        so the ports of a feedthrough module know their sources' widths.

        Parameters
        ----------
        dt : float
            The run's step (s): a discrete model must have this period.
        inputs : mapping of str to sequence of Port
            Every input signal with an active edge in the configuration, one
            :class:`Port` per edge (file order).

        Returns
        -------
        LinearModel or None
            None (the default): the module has no linear model; its
            :meth:`linearization`, if any, is used instead.
        """
        return None

    # ----------------------------------------------------------------- state vector
    def state_names(self) -> tuple[str, ...]:
        """The attributes :meth:`state` packs (:attr:`state_fields`, or the automatic default).

        The default is found once per class: the float and float-array attributes
        of this instance minus those a fresh ``configure()`` assigns.
        """
        fields = type(self).state_fields
        if fields is None:
            fields = tuple(
                k for k, v in vars(self).items()
                if k not in NOT_STATE and k not in _configured(self) and _numeric(v)
            )
        return fields

    def state(self) -> np.ndarray:
        """The module's dynamic state as one 1-D float array (empty: no state).

        Examples
        --------
        >>> class Tank(RuntimeModule):
        ...     def __init__(self, name, params, rng):
        ...         super().__init__(name, params, rng)
        ...         self.h, self.q = 1.0, np.array([0.5, 2.0])
        ...     def configure(self):
        ...         self.area = 2.0
        >>> tank = Tank("tank", {}, None)
        >>> tank.state_names(), tank.state().tolist()
        (('h', 'q'), [1.0, 0.5, 2.0])
        >>> tank.set_state([3.0, 0.0, 1.0]); tank.h, tank.q.tolist()
        (3.0, [0.0, 1.0])
        """
        parts = [np.asarray(getattr(self, k), dtype=float).ravel() for k in self.state_names()
                 if _numeric(getattr(self, k, None))]
        return np.concatenate(parts) if parts else np.zeros(0)

    def set_state(self, x: Any) -> None:
        """Write a vector of :meth:`state`'s layout back (arrays keep their shapes)."""
        x = np.asarray(x, dtype=float).ravel()
        i = 0
        for k in self.state_names():
            v = getattr(self, k, None)
            if not _numeric(v):
                continue
            if isinstance(v, np.ndarray):
                setattr(self, k, x[i:i + v.size].reshape(v.shape).copy())
                i += v.size
            elif isinstance(v, list):
                setattr(self, k, x[i:i + len(v)].tolist())
                i += len(v)
            else:
                setattr(self, k, float(x[i]))
                i += 1
        if i != x.size:
            raise SimulationError(f"{self.name}: a state of {x.size} values for {i} state values")

    # ----------------------------------------------------------------- hand-over
    def export_state(self) -> dict[str, Any]:
        """State a successor of the same role may start from (e.g. pose and covariance)."""
        return {}

    def import_state(self, state: dict[str, Any]) -> None:
        """Start from a predecessor's :meth:`export_state` (keys it does not know are ignored)."""

    def set_params(self, values: dict[str, Any]) -> None:
        """Apply a parameter update at run time (``parameter_update`` action) and re-configure.

        Raises
        ------
        SimulationError
            When a value leaves the range the type declares (:meth:`Param.outside`);
            nothing is changed then. The planner rejects such an update before it
            gets here (``limit``).
        """
        for key, value in values.items():
            spec = (self.parameters or {}).get(key)
            why = spec.outside(value) if isinstance(spec, Param) else None
            if why:
                raise SimulationError(
                    f"{self.name}.{key}: {why}, the range type '{self.type_key}' declares"
                )
        self.params.update(values)
        self.configure()


#: Attributes the automatic :attr:`RuntimeModule.state_fields` never takes: monitoring and
#: health bookkeeping, not the loop's dynamics.
NOT_STATE = frozenset({"name", "params", "rng", "signals", "noise_levels", "max_silence_s"})


def _numeric(v: Any) -> bool:
    """A float, a float array or a list of floats (a state; ints and bools are counters, flags)."""
    if isinstance(v, np.ndarray):
        return v.dtype.kind == "f"
    if isinstance(v, list):
        return bool(v) and all(isinstance(e, float) for e in v)
    return isinstance(v, (float, np.floating))


_CONFIGURED: dict[type, frozenset[str]] = {}


def _configured(mod: RuntimeModule) -> frozenset[str]:
    """The attributes ``configure()`` assigns on a copy of ``mod`` (its parameters; per class)."""
    cls = type(mod)
    found = _CONFIGURED.get(cls)
    if found is None:
        seen: set[str] = set()

        def record(self: Any, key: str, value: Any) -> None:
            seen.add(key)
            object.__setattr__(self, key, value)

        attrs = {"__setattr__": record, "__module__": cls.__module__}
        probe_cls = type(cls.__name__, (cls,), attrs)
        probe: Any = object.__new__(probe_cls)
        probe.__dict__.update(copy.deepcopy(vars(mod)))
        try:
            probe.configure()
        except Exception:  # noqa: BLE001 - a configure that needs more: no field excluded
            pass
        found = _CONFIGURED[cls] = frozenset(seen)
    return found
