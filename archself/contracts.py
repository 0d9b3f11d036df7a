"""The typed doors between the layers: what the MAPE-K loop needs of a system, what a
lane-batched module must offer.

Several classes play each role, and a third party may add its own:

==========================  ===========================================================
role                        implementations
==========================  ===========================================================
:class:`ManagedSystem`      :class:`~archself.system.live.LiveSystem` (simulation),
                            :class:`~archself.lanes.view.LaneView` (one lane of many),
                            :class:`~archself.live.system.MeasuredSystem` (a real plant)
:class:`LoopSystem`         ``LiveSystem`` and ``LaneView`` (every module's state: the
                            whole-loop stability check)
:class:`SystemSnapshot`     every :class:`ManagedSystem` (its ``snapshot()``), and
                            :class:`~archself.live.system.ModelSnapshot` (the compiled
                            models of a real plant: linearizable, never stepped)
:class:`BatchedModule`      :class:`~archself.lanes.module.LaneModule` and the packs'
                            batched classes (a module type's ``lanes =``)
==========================  ===========================================================

The protocols are checked by mypy (``tests/typing_doors.py``, ``mypy --strict``) and
at run time by :func:`archself.testing.check_pack`, which a pack runs to prove its
batched classes equal its per-run classes. The runtime (``archself.runtime``) reaches
a system only through :class:`ManagedSystem`; a system may offer more (``closed_loop``,
``rollout_scope``, ``dependencies``) and the runtime uses it where present
(docs/develop.md, "The live-system contract").

Examples
--------
>>> from archself.model.loader import load_architecture
>>> from archself.resources import data_dir
>>> from archself.system.live import compile_system
>>> arch = load_architecture(data_dir("architectures") / "process_plant.yaml").arch
>>> isinstance(compile_system(arch, seed=1), ManagedSystem)
True
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:
    import numpy as np

    from archself.linear.closed_loop import WholeLoop
    from archself.model.architecture import Architecture
    from archself.modules.base import RuntimeModule

__all__ = ["BatchedModule", "LoopSystem", "ManagedSystem", "SystemSnapshot"]


@runtime_checkable
class SystemSnapshot(Protocol):
    """A copy of a system the planner may change and judge without touching the original.

    ``step``, ``state_error`` and ``objective_error`` may raise an
    :class:`~archself.errors.ArchselfError` where the copy cannot be run forward (a real
    plant's models): the rollout and the Lyapunov test then fail closed.
    """

    @property
    def configuration(self) -> str:
        """The active configuration's name."""
        ...

    def apply_configuration(self, name: str) -> None:
        """Switch to configuration ``name`` (state handed over by role)."""
        ...

    def set_params(self, module: str, values: Mapping[str, Any]) -> None:
        """Apply a parameter update to ``module``."""
        ...

    def step(self) -> None:
        """Advance one step ``dt``."""
        ...

    def linearization(self, configuration: str | None = None) -> np.ndarray | None:
        """Closed-loop A (Eq. 20, continuous time) of ``configuration``, or None."""
        ...

    def state_error(self) -> np.ndarray:
        """x − x_ref, the vector of the Lyapunov test (Eq. 22)."""
        ...

    def objective_error(self) -> float:
        """J_obs: the ``runtime.objective`` error now."""
        ...


@runtime_checkable
class ManagedSystem(SystemSnapshot, Protocol):
    """The running system the MAPE-K loop observes and reconfigures (Algorithm 1)."""

    @property
    def arch(self) -> Architecture:
        """The architecture the system was compiled from."""
        ...

    @property
    def t(self) -> float:
        """Current time (s)."""
        ...

    @property
    def dt(self) -> float:
        """The step (s)."""
        ...

    @property
    def active(self) -> Collection[str]:
        """Names of the active modules."""
        ...

    @property
    def outputs(self) -> Mapping[str, dict[str, Any]]:
        """module → signal → value of the last step."""
        ...

    def local_signals(self) -> dict[str, dict[str, float]]:
        """module → residual signal → value (``RuntimeModule.local_signals``)."""
        ...

    def available(self) -> dict[str, bool]:
        """module → False when it raised, gave NaN, went silent or lost an input."""
        ...

    def health(self) -> dict[str, str | None]:
        """module → why it is unavailable, or None."""
        ...

    def snapshot(self, only: Collection[str] | None = None) -> SystemSnapshot:
        """An independent copy (``only``: the modules a rollout needs) for the planner."""
        ...


@runtime_checkable
class LoopSystem(ManagedSystem, Protocol):
    """A managed system whose every module's state the planner can read and move.

    What the whole-loop stability check (:func:`archself.runtime.stability.whole_loop_check`)
    needs: simulation (:class:`~archself.system.live.LiveSystem`) and lanes
    (:class:`~archself.lanes.view.LaneView`) offer it; a real plant
    (:class:`~archself.live.system.MeasuredSystem`) does not, and the check falls back.
    """

    @property
    def modules(self) -> Mapping[str, RuntimeModule]:
        """The active modules by name."""
        ...

    def whole_loop(self, configuration: str | None = None, steps: int = 1) -> WholeLoop:
        """The numerical linearization of ``configuration``'s ``steps``-step map around now."""
        ...

    def snapshot(self, only: Collection[str] | None = None) -> LoopSystem:
        """An independent copy, itself a :class:`LoopSystem`."""
        ...


@runtime_checkable
class BatchedModule(Protocol):
    """One module in N lanes (runs), stepped by one call (docs/lanes.md).

    ``lanes`` is ``slice(None)`` (every lane) or an index array; values are lane
    values (:mod:`archself.lanes.module`). ``failed`` holds the lanes that failed in
    the last call and why; the executor clears it.
    """

    n: int
    name: str
    failed: dict[int, str]

    def output(self, t: float, lanes: Any) -> dict[str, Any]:
        """Outputs from the state at ``t`` (modules without direct feedthrough)."""
        ...

    def step(self, t: float, dt: float, inputs: dict[str, Any], lanes: Any) -> dict[str, Any]:
        """Consume ``inputs`` at ``t``; the outputs (or the next state)."""
        ...

    def local_signals(self, lanes: Any) -> dict[str, Any]:
        """Residual signals per lane, NaN where unknown."""
        ...

    def store(self, lanes: Any) -> None:
        """Write the state of ``lanes`` into their per-run instances."""
        ...

    def load(self, lanes: Any) -> None:
        """Read the parameters and state of ``lanes`` from their per-run instances."""
        ...

    def state(self, lanes: Any = ...) -> Any:
        """Each lane's state vector, ``(L, n)``: the per-run class's ``state()`` layout."""
        ...

    def set_state(self, x: Any, lanes: Any = ...) -> None:
        """Write an ``(L, n)`` array of :meth:`state`'s layout back into ``lanes``."""
        ...
