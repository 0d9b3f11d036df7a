"""The interface every runtime module implements.

A runtime module is the live counterpart of one ``modules.<name>`` entry of an
architecture file. The system executor (:mod:`archself.system`) runs modules as
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
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np


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

    Examples
    --------
    >>> Param(0.2, "m").required, Param().required
    (False, True)
    """

    default: Any = REQUIRED
    unit: str = ""
    doc: str = ""

    @property
    def required(self) -> bool:
        """True when the file must give the value."""
        return self.default is REQUIRED


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
    residual_signals: ClassVar[tuple[str, ...]] = ()
    fault_kinds: ClassVar[frozenset[str]] = frozenset()
    direct_feedthrough: ClassVar[bool] = True
    parameters: ClassVar[Mapping[str, Param] | None] = None
    #: Nominal noise level per output signal (instance attribute of sensors): a noisy
    #: signal repeating itself bit for bit is stale (see :mod:`archself.system`).
    noise_levels: dict[str, float] | None = None
    #: Longest time without a published value before the module counts as silent (s).
    max_silence_s: float | None = None

    def __init__(self, name: str, params: dict[str, Any], rng: np.random.Generator) -> None:
        self.name = name
        self.params = self.default_params()
        self.params.update(params)
        self.rng = rng
        self.signals: dict[str, float] = {}
        self.configure()

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
        """Closed-loop system matrix A of Eq. 20 around the current point, if known."""
        return None

    # ----------------------------------------------------------------- hand-over
    def export_state(self) -> dict[str, Any]:
        """State a successor of the same role may start from (e.g. pose and covariance)."""
        return {}

    def import_state(self, state: dict[str, Any]) -> None:
        """Start from a predecessor's :meth:`export_state` (keys it does not know are ignored)."""

    def set_params(self, values: dict[str, Any]) -> None:
        """Apply a parameter update at run time (``parameter_update`` action) and re-configure."""
        self.params.update(values)
        self.configure()
