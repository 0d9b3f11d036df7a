"""The lane executor: N runs of one architecture stepped together, one call per module.

:class:`LaneSystem` takes N per-run systems (:class:`archself.system.LiveSystem`,
one per lane: its seed, its sweep point's parameters, its scenario's faults) of
the same structure and steps them as one: for every active module a
:class:`~archself.lanes.module.LaneModule` (the type's batched class, or
:class:`~archself.lanes.module.PerLane`) advances all lanes with one call, in the
order and with the routing of the per-run plan. What the per-run step does per
value it does per lane: edge noise from each lane's own stream, edge latencies,
the scenario's faults from each lane's own injectors, and a lane whose module
raised or whose value a fault made non-finite holds its last outputs.

Lane values follow :mod:`archself.lanes.module` (NaN = absent in that lane).
Not yet per lane: the availability bookkeeping (silence, stale signals, lost
inputs) that only the adaptation loop reads, and configuration changes — a lane
system runs one configuration, fixed.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from archself.errors import SimulationError
from archself.lanes.module import ALL, LaneModule, LaneNormals, PerLane
from archself.streams import module_rng
from archself.system import LiveSystem

__all__ = ["LaneSystem", "lane_module"]

#: Fault kinds applied to all lanes at once; the others go lane by lane.
_VECTOR_FAULTS = frozenset({"bias_drift", "bias", "effectiveness_loss", "dropout"})


def lane_module(modules: Sequence[Any]) -> LaneModule:
    """The batched module of N per-run instances: the type's ``lanes`` class or PerLane.

    ``lanes`` is a :class:`~archself.lanes.module.LaneModule` subclass or its
    ``"package.module:Class"`` path (imported on first use: a pack's batched code
    costs nothing to a run that does not batch).
    """
    kind = type(modules[0])
    cls = getattr(kind, "lanes", None)
    if isinstance(cls, str):
        import importlib

        where, _, attr = cls.partition(":")
        try:
            cls = getattr(importlib.import_module(where), attr)
        except (ImportError, AttributeError) as exc:
            raise SimulationError(
                f"module type {kind.__name__}: its lanes class {kind.lanes!r} "
                f"cannot be imported: {exc}"
            ) from None
    return cls(modules) if cls is not None else PerLane(modules)


class _LaneFault:
    """One fault of a scenario in every lane (one injector per lane)."""

    def __init__(self, signal: str, injectors: Sequence[Any]) -> None:
        self.signal = signal
        self.injectors = list(injectors)
        first = self.injectors[0]
        self.kind = first.kind
        self.vector = first.kind in _VECTOR_FAULTS and all(
            i.kind == first.kind for i in self.injectors
        )
        self.onset = np.array([i.onset for i in self.injectors])
        self.end = np.array([i.end for i in self.injectors])
        self.magnitude = np.array([i.magnitude for i in self.injectors])

    def apply(self, t: float, value: Any) -> tuple[Any, np.ndarray | None]:
        """The faulty lane value at ``t``, and the lanes made non-finite (or None)."""
        if value is None or type(value) is list:
            if self.kind != "dropout" or value is None:
                return value, None
        if self.vector:
            active = (self.onset <= t + 1e-9) & (t < self.end - 1e-9)
            if not active.any():
                return value, None
            out = np.array(value, dtype=float)
            a = active
            kind = self.kind
            if kind == "dropout":
                out[a] = math.nan
            elif kind == "bias_drift":
                add = self.magnitude[a] * (t - self.onset[a])
                out[a] = out[a] + (add if out.ndim == 1 else add[:, None])
            elif kind == "bias":
                add = self.magnitude[a]
                out[a] = out[a] + (add if out.ndim == 1 else add[:, None])
            else:  # effectiveness_loss
                f = 1.0 - self.magnitude[a]
                out[a] = out[a] * (f if out.ndim == 1 else f[:, None])
            return out, None
        from archself.lanes.module import row

        out = np.array(value, dtype=float)
        bad = []
        for j, inj in enumerate(self.injectors):
            before = row(value, j)
            after = inj.apply(t, before)
            if after is None:
                out[j] = math.nan
                continue
            arr = np.asarray(after, dtype=float)
            if before is not None and not np.isfinite(arr).all():
                bad.append(j)
                continue
            out[j] = arr
        return out, (np.array(bad) if bad else None)


class LaneSystem:
    """N lanes of one configuration of an architecture, stepped together.

    Parameters
    ----------
    systems : sequence of LiveSystem
        One compiled per-run system per lane, all of the same architecture
        structure (modules, types, edges) in the same configuration and at t = 0;
        their parameters, seeds and faults may differ.

    Raises
    ------
    SimulationError
        If the systems differ in structure, configuration or step.
    """

    def __init__(self, systems: Sequence[LiveSystem]) -> None:
        if not systems:
            raise SimulationError("a lane system needs at least one lane")
        self.systems = list(systems)
        first = self.systems[0]
        self.n = len(self.systems)
        self.dt = first.dt
        self.t = 0.0
        self.k = 0
        self.configuration = first.configuration
        plan = first._plan
        for s in self.systems[1:]:
            p = s._plan
            same = (
                s.configuration == self.configuration
                and s.dt == self.dt
                and p.active == plan.active
                and p.order == plan.order
                and {n: [r[:3] + r[4:] for r in rs] for n, rs in p.routes.items()}
                == {n: [r[:3] + r[4:] for r in rs] for n, rs in plan.routes.items()}
            )
            if not same:
                raise SimulationError(
                    "lanes must share the architecture's structure, configuration and step"
                )
        self.plan = plan
        self.modules: dict[str, LaneModule] = {
            name: lane_module([s._module(name) for s in self.systems]) for name in plan.active
        }
        self.outputs: dict[str, dict[str, Any]] = {}
        self.failed: dict[str, np.ndarray] = {}  # module -> lanes that failed in the last step
        self._faults: dict[str, list[_LaneFault]] = {}
        for name in plan.active:
            per_lane = [s._faults.get(name, []) for s in self.systems]
            if any(len(f) != len(per_lane[0]) for f in per_lane):
                raise SimulationError(f"lanes must have the same faults on {name!r}")
            self._faults[name] = [
                _LaneFault(per_lane[0][j][0], [f[j][1] for f in per_lane])
                for j in range(len(per_lane[0]))
            ]
        arch = first.arch
        self._edge_noise: dict[int, tuple[np.ndarray, LaneNormals]] = {}
        for name in plan.active:
            for _carries, _src, idx, _unc, _delay in plan.routes[name]:
                unc = np.array([_route_unc(s, name, idx) for s in self.systems])
                if (unc > 0).any():
                    e = arch.edges[idx]
                    rngs = [
                        module_rng(s.seed, f"edge:{e.source}->{e.target}:{e.carries}")
                        for s in self.systems
                    ]
                    self._edge_noise[idx] = (unc, LaneNormals(rngs))
        self._delay: dict[int, deque] = {}

    # ------------------------------------------------------------------ a step
    def _gather(self, name: str) -> dict[str, Any]:
        outs = self.outputs
        plan = self.plan
        multi = plan.multi.get(name, ())
        reads = plan.reads
        inputs: dict[str, Any] = {}
        for carries, src, idx, _unc, delay in plan.routes[name]:
            src_out = outs.get(src)
            sig = reads.get(idx, carries) if reads else carries
            val = src_out.get(sig) if src_out is not None else None
            if delay:
                line = self._delay.get(idx)
                if line is None:
                    line = self._delay[idx] = deque([None] * delay)
                line.append(val)
                val = line.popleft()
            noise = self._edge_noise.get(idx)
            if noise is not None and val is not None and type(val) is not list:
                val = _add_noise(val, *noise)
            if carries in multi:
                inputs.setdefault(carries, []).append(val)
            elif val is not None or carries not in inputs:
                inputs[carries] = val
        return inputs

    def _publish(self, name: str, out: dict[str, Any] | None, t: float) -> None:
        mod = self.modules[name]
        out = dict(out or {})
        bad = set(mod.failed)
        mod.failed.clear()
        for fault in self._faults.get(name, ()):
            sig = fault.signal
            if sig in out:
                out[sig], broken = fault.apply(t, out[sig])
                if broken is not None:
                    bad.update(int(j) for j in broken)
        if not bad:
            self.outputs[name] = out
            self.failed.pop(name, None)
            return
        lanes = np.array(sorted(bad))
        self.failed[name] = lanes
        old = self.outputs.get(name, {})
        merged: dict[str, Any] = {}
        for sig in {*out, *old}:
            merged[sig] = _hold(out.get(sig), old.get(sig), lanes, self.n)
        self.outputs[name] = merged

    def step(self) -> None:
        """Advance every lane by one step ``dt``."""
        t, dt = self.t, self.dt
        mods = self.modules
        gather = self._gather
        for name, stepped in self.plan.publishing:
            mod = mods[name]
            try:
                out = mod.step(t, dt, gather(name), ALL) if stepped else mod.output(t, ALL)
            except Exception as exc:  # noqa: BLE001 - every lane of the module failed
                mod.failed.update({i: f"raised {type(exc).__name__}" for i in range(self.n)})
                out = {}
            self._publish(name, out, t)
        for name in self.plan.nonft:
            mod = mods[name]
            try:
                mod.step(t, dt, gather(name), ALL)
            except Exception as exc:  # noqa: BLE001
                mod.failed.update({i: f"raised {type(exc).__name__}" for i in range(self.n)})
            mod.failed.clear()
        self.k += 1
        self.t = self.k * dt

    def signal(self, module: str, signal: str) -> Any:
        """The lane value of ``module.signal`` (None when no lane has it)."""
        out = self.outputs.get(module)
        return None if out is None else out.get(signal)

    def store(self) -> None:
        """Write every lane's state into its per-run system's modules."""
        for mod in self.modules.values():
            mod.store(ALL)


def _route_unc(system: LiveSystem, name: str, idx: int) -> float:
    """The uncertainty of edge ``idx`` into ``name`` in ``system``'s plan."""
    for _c, _s, i, unc, _d in system._plan.routes[name]:
        if i == idx:
            return float(unc)
    return 0.0


def _add_noise(val: np.ndarray, unc: np.ndarray, normals: LaneNormals) -> np.ndarray:
    """``val + unc·N(0, 1)`` per lane with a value (absent lanes draw nothing)."""
    width = 1 if val.ndim == 1 else val.shape[1]
    col = val if val.ndim == 1 else val[:, 0]
    present = ~np.isnan(col) & (unc > 0)
    if present.all():
        z = normals.take(ALL, width)
        return val + (unc[:, None] * z if val.ndim == 2 else unc * z[:, 0])
    idx = np.flatnonzero(present)
    out = val.copy()
    if len(idx):
        z = normals.take(idx, width)
        out[idx] = val[idx] + (unc[idx, None] * z if val.ndim == 2 else unc[idx] * z[:, 0])
    return out


def _hold(new: Any, old: Any, lanes: np.ndarray, n: int) -> Any:
    """``new`` with the rows of ``lanes`` replaced by ``old``'s (absent if ``old`` is)."""
    ref = new if new is not None else old
    if ref is None:
        return None
    if type(ref) is list:
        out = list(new) if new is not None else [None] * n
        for j in lanes:
            out[j] = None if old is None else old[j]
        return out
    shape = np.shape(ref)
    out = np.full(shape, math.nan) if new is None else np.array(new, dtype=float)
    out[lanes] = math.nan if old is None else np.asarray(old, dtype=float)[lanes]
    return out
