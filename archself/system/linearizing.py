"""The closed loop of a running configuration: the modules' linear models, wired.

:class:`Linearizing` is the part of :class:`archself.system.executor.LiveSystem` that asks
each module of a configuration for its :meth:`~archself.modules.base.RuntimeModule.linear_model`
around the current outputs (inactive modules on hand-over copies, so the live
system is not changed), wires the models along the configuration's edges with
:mod:`archself.linear.wiring` (a renamed edge through a stateless identity model) and
takes the ``linearization()`` blocks of the modules without a model. It works on
the system's plans (:class:`~archself.system.step_plan.StepPlan`), pool and outputs.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np

from archself.linear.wiring import ClosedLoop, Wire, gc_paused, interconnect, loop_modules, wiring
from archself.modules.base import LinearModel, Port, RuntimeModule
from archself.system.step_plan import StepPlan

__all__ = ["Linearizing"]


class Linearizing:
    """Closed loop and closed-loop A of a :class:`~archself.system.executor.LiveSystem`."""

    dt: float
    configuration: str
    outputs: dict[str, dict[str, Any]]
    _plan: StepPlan
    _pool: dict[str, RuntimeModule]
    _module: Callable[[str], RuntimeModule]  # LiveSystem's methods
    _make_plan: Callable[[str], StepPlan]

    def _linear_module(self, name: str, plan: StepPlan) -> RuntimeModule:
        """The module as it would run in ``plan``: live if active now, else a hand-over copy.

        An inactive module is evaluated on a copy that is first given the state of
        the active module of the same role (as a hand-over would); the live
        system is not changed.
        """
        mod = self._module(name)
        if name in self._plan.active_set:
            return mod
        mod = copy.deepcopy(mod)  # never change the live system
        for a in self._plan.active:
            other = self._pool[a]
            if other.role == mod.role and a not in plan.active_set:
                mod.import_state(other.export_state())
                break
        return mod

    def closed_loop(self, configuration: str | None = None) -> ClosedLoop:
        """The closed loop of ``configuration`` (default: the active one) around now.

        Modules whose type gives :meth:`RuntimeModule.linear_model` are wired along
        the configuration's active edges (:func:`archself.linear.wiring.interconnect`, in
        discrete time at the step); a module that gives none, or whose model closes
        no loop with the others, contributes its ``linearization()`` as a diagonal
        block. Inactive modules are evaluated on hand-over copies.

        Raises
        ------
        LinearizationError
            When the models cannot be wired (widths or periods disagree).
        """
        conf_name = configuration or self.configuration
        plan = self._make_plan(conf_name)
        if not plan.linearizable:  # no type of the configuration gives a model or a matrix
            return ClosedLoop(None, [])
        with gc_paused():  # many small acyclic objects (archself.model.loader.gc_paused)
            return self._closed_loop(plan)

    def _closed_loop(self, plan: StepPlan) -> ClosedLoop:
        """:meth:`closed_loop` of a plan that has modules giving models or matrices."""
        mods = {n: self._linear_module(n, plan) for n in plan.active}
        base = RuntimeModule.linear_model
        models: dict[str, LinearModel] = {}
        widths: dict[tuple[str, str], int] = {}
        outs = self.outputs
        for n in (*plan.nonft, *plan.order):
            mod = mods[n]
            if type(mod).linear_model is base:
                continue
            ports: dict[str, list[Port]] = {}
            for carries, src, idx, *_ in plan.routes[n]:  # carries: n's input port
                sig = plan.reads.get(idx, carries)
                value = (outs.get(src) or {}).get(sig) if src in self._plan.active_set else None
                ports.setdefault(carries, []).append(Port(src, widths.get((src, sig)), value))
            lm = mod.linear_model(self.dt, ports)
            if lm is None:
                continue
            models[n] = lm
            for sig, size in lm.outputs:  # type: ignore[misc]
                widths.setdefault((n, sig), size)
        wires = plan.wires() if models else []
        if plan.reads and models:
            wires = self._port_wires(plan, wires, models, widths)
        routes = wiring(models, wires) if models else []
        in_loop = loop_modules(models, wires, routes=routes) if models else set()
        blocks: list[tuple[str, np.ndarray]] = []
        for n in plan.active:
            if n in models and n in in_loop:
                continue
            try:
                A = mods[n].linearization()
            except Exception:  # noqa: BLE001 - a failing linearization is no model
                A = None
            if A is not None:
                blocks.append((n, np.atleast_2d(np.asarray(A, dtype=float))))
                models.pop(n, None)
        loop = interconnect(models, wires, self.dt, routes=routes) if models else None
        return ClosedLoop(loop, blocks)

    def _port_wires(
        self,
        plan: StepPlan,
        wires: list[Wire],
        models: dict[str, LinearModel],
        widths: dict[tuple[str, str], int],
    ) -> list[Wire]:
        """``wires`` with each renamed edge (``from: a.y, to: b.u``) through a pass-through.

        The edge becomes ``a --y--> [y→u] --u--> b``, a static identity model named
        ``a.y→b.u`` added to ``models``: no state, so the closed loop's eigenvalues are
        those of the direct wire.
        """
        out = list(wires)
        for n in plan.active:
            for port, src, idx, _unc, delay in plan.routes[n]:
                sig = plan.reads.get(idx)
                if sig is None:
                    continue
                out.remove(Wire(src, n, port, delay))
                width = widths.get((src, sig))
                if width is None or n not in models:
                    continue  # the source gives no model of it: the input is exogenous
                alias = f"{src}.{sig}→{n}.{port}"
                models[alias] = LinearModel(
                    [], [], [], np.eye(width), [(sig, width)], [(port, width)], dt=self.dt
                )
                out += [Wire(src, alias, sig, delay), Wire(alias, n, port)]
        return out

    def linearization(self, configuration: str | None = None) -> np.ndarray | None:
        """Closed-loop A (Eq. 20) of ``configuration`` (default: the active one), or None.

        The continuous-time matrix of :meth:`closed_loop` (:meth:`ClosedLoop.matrix`):
        the wired models' discrete closed loop as ``ln(λ)/dt`` in modal form, and the
        ``linearization()`` blocks of the modules without a model. None when no
        module provides either.
        """
        return self.closed_loop(configuration).matrix()
