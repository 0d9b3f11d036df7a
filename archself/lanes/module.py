"""The batched module interface: N lanes of one module stepped by one call.

A *lane* is one run — a seed, a sweep point — of the same architecture; a
:class:`LaneModule` holds the state of one module in every lane, with a leading
lane axis, so a step of N runs costs one Python call per module instead of N.

It is built from the N per-run instances (:class:`~archself.modules.base.RuntimeModule`,
one per lane, each with its lane's parameters and random stream) and keeps them:
they are where a lane's state goes when the per-run API is needed (:meth:`store`,
then ``export_state``, ``linear_model``, a deep copy …) and where it comes back
from (:meth:`load`).

Values across the ``L`` lanes a call steps (``lanes``: ``slice(None)`` for all, or
an index array into ``0 … N−1``):

* ``None`` — absent in every lane (a GPS between fixes);
* a float array of shape ``(L,)`` (a scalar signal) or ``(L, w)`` (a vector), in
  which a NaN entry (a NaN row) marks a lane where the value is absent;
* a list of ``L`` objects — values that are not numbers (model objects);
* a tuple of lane values, one per active edge — an input the type declares in
  ``multi_inputs`` (the per-run module receives a list).

A batched module therefore never outputs NaN but to say "absent"; a run whose
value *goes* non-finite (a fault of kind ``nan``, a module that raises) is the
executor's business (:class:`archself.lanes.system.LaneSystem`).

A module type opts in by naming its batched class: ``lanes = MyTypeLanes`` on the
:class:`~archself.modules.base.RuntimeModule` subclass. Every other type runs lane
by lane through :class:`PerLane`, with the same results.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from archself.errors import SimulationError
from archself.modules.base import RuntimeModule
from archself.system.live import is_bad

__all__ = [
    "ALL", "LaneModule", "LaneNormals", "PerLane", "distinct", "lane_count", "row", "stack",
]

#: ``lanes`` of a call that steps every lane.
ALL = slice(None)


def lane_count(n: int, lanes: slice | np.ndarray) -> int:
    """How many of ``n`` lanes ``lanes`` selects.

    Examples
    --------
    >>> lane_count(5, ALL), lane_count(5, np.array([0, 3]))
    (5, 2)
    """
    return n if isinstance(lanes, slice) else len(lanes)


def row(value: Any, j: int) -> Any:
    """Lane ``j``'s value of a lane value (None where absent), as a per-run module sees it.

    Examples
    --------
    >>> row(np.array([1.0, np.nan]), 0), row(np.array([1.0, np.nan]), 1)
    (1.0, None)
    >>> row(np.array([[1.0, 2.0], [np.nan, np.nan]]), 0).tolist()
    [1.0, 2.0]
    """
    if value is None:
        return None
    if type(value) is list:
        return value[j]
    if type(value) is tuple:  # a multi-edge input: the per-run module's list
        return [row(v, j) for v in value]
    v = value[j]
    if value.ndim == 1:
        f = float(v)
        return None if f != f else f
    return None if math.isnan(float(v[0])) else v.copy()


def distinct(objs: Sequence[Any], clone: Callable[[Any], Any] = copy.deepcopy) -> list[Any]:
    """``objs`` with every object an earlier entry already names replaced by ``clone`` of it.

    Lanes replicated from one per-run system (the whole-loop check's probes,
    :func:`archself.lanes.view.lane_loops`) name its random streams and fault injectors
    once per lane; each lane must draw and hold on its own, from the same state.

    Examples
    --------
    >>> a = [1.0]
    >>> got = distinct([a, a, [2.0]])
    >>> got[0] is a, got[1] is a, got[1] == a
    (True, False, True)
    """
    seen: set[int] = set()
    out = []
    for obj in objs:
        if id(obj) in seen:
            obj = clone(obj)
        else:
            seen.add(id(obj))
        out.append(obj)
    return out


def _same_stream(rng: np.random.Generator) -> np.random.Generator:
    """A generator of its own at ``rng``'s state (8 against 23 µs for ``copy.deepcopy``)."""
    bg = type(rng.bit_generator)(0)
    bg.state = rng.bit_generator.state
    return np.random.Generator(bg)


def stack(values: Sequence[Any]) -> Any:
    """The lane value of per-lane values (None → NaN; all None → None).

    Examples
    --------
    >>> stack([1.0, None]).tolist()
    [1.0, nan]
    >>> stack([np.array([1.0, 2.0]), None]).tolist()
    [[1.0, 2.0], [nan, nan]]
    >>> stack([None, None]) is None
    True
    """
    first = next((v for v in values if v is not None), None)
    if first is None:
        return None
    if isinstance(first, np.ndarray) and first.dtype.kind in "fiub":
        out = np.full((len(values), first.size), math.nan)
        for j, v in enumerate(values):
            if v is not None:
                out[j] = np.asarray(v, dtype=float).ravel()
        return out
    if isinstance(first, (float, int, np.floating, np.integer)) and not isinstance(first, bool):
        return np.array([math.nan if v is None else float(v) for v in values])
    return list(values)


class ModelFields:
    """Float fields of a model input (one object per lane), re-read only when the objects change.

    A model node publishes an object per lane (a list of L objects, or None); a batched
    type that reads a few numbers from it keeps them as ``(L,)`` arrays here.

    Parameters
    ----------
    missing : dict of str to float
        Each field read, and its value in a lane without an object (the input None,
        or None in that lane): the per-run module's default model's.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> radius = ModelFields({"wheel_radius_m": 0.1})
    >>> radius([SimpleNamespace(wheel_radius_m=0.2), None], 2)[0].tolist()
    [0.2, 0.1]
    """

    def __init__(self, missing: dict[str, float]) -> None:
        self.missing = dict(missing)
        self._key: Any = None
        self._values: list[np.ndarray] = []

    def __call__(self, objs: list[Any] | None, n: int) -> list[np.ndarray]:
        """The fields, one ``(n,)`` array each, of the lane value ``objs`` (None or a list)."""
        key = n if objs is None else objs
        if type(key) is type(self._key) and key == self._key:
            return self._values
        lanes = [None] * n if objs is None else objs
        self._values = [
            np.array([fill if o is None else float(getattr(o, f)) for o in lanes])
            for f, fill in self.missing.items()
        ]
        self._key = key if objs is None else list(objs)
        return self._values


class LaneModule:
    """One module in N lanes: the batched counterpart of a ``RuntimeModule`` type.

    Subclasses read their parameters from the per-run instances in
    :meth:`load` (e.g. ``self.noise = self.lane_attr("noise")``, one entry per
    lane, so a sweep point's parameters hold in its own lane), keep their state
    as arrays with a leading lane axis, and implement :meth:`output` (modules
    without direct feedthrough), :meth:`step`, :meth:`local_signals` (types with
    residual signals) and :meth:`store`. Helpers for subclasses: ``_mods(lanes)``
    (the per-run instances), ``_read(lanes, name, values)`` (a per-lane parameter
    array), ``_masks(**masks)`` / ``_mask(name, lanes)`` (lane masks with their
    ``any``/``all``, to skip work no lane needs).

    Parameters
    ----------
    modules : sequence of RuntimeModule
        The per-run instances, one per lane, of the same type and name.

    Attributes
    ----------
    modules : list of RuntimeModule
    n : int
        Number of lanes.
    failed : dict of int to str
        Lanes (indices into ``0 … N−1``) that failed in the last call and why
        (``"raised KeyError"``): the executor marks them unavailable and holds
        their last outputs. Set by the module; cleared by the executor.
    """

    #: Whether the class steps what its per-run twin steps with ``smooth`` set (the
    #: whole-loop linearization, :mod:`archself.lanes.view`); a class whose twin
    #: reads ``smooth`` and that does not sets False, and runs lane by lane there.
    follows_smooth: bool = True

    def __init__(self, modules: Sequence[RuntimeModule]) -> None:
        self.modules = list(modules)
        self.n = len(self.modules)
        self.name = self.modules[0].name
        self.kind = type(self.modules[0])
        self.failed: dict[int, str] = {}
        self.load(ALL)

    def lane_attr(self, attr: str) -> np.ndarray:
        """``getattr(module, attr)`` of each lane's instance, stacked (float array)."""
        return np.array([getattr(m, attr) for m in self.modules], dtype=float)

    def indices(self, lanes: slice | np.ndarray) -> np.ndarray:
        """The lane indices ``lanes`` selects."""
        return np.arange(self.n)[lanes] if isinstance(lanes, slice) else np.asarray(lanes)

    # ------------------------------------------------------------------ helpers of subclasses
    def _mods(self, lanes: slice | np.ndarray) -> list[RuntimeModule]:
        """The per-run instances of ``lanes``."""
        return self.modules if isinstance(lanes, slice) else [self.modules[i] for i in lanes]

    def _read(self, lanes: slice | np.ndarray, name: str, values: Sequence[Any],
              dtype: Any = float) -> None:
        """Set ``self.<name>[lanes]`` to ``values`` (a new array when ``lanes`` is ALL)."""
        if isinstance(lanes, slice):
            setattr(self, name, np.array(values, dtype=dtype))
        else:
            getattr(self, name)[lanes] = values

    def _masks(self, **masks: np.ndarray) -> None:
        """Keep lane masks (e.g. the lanes whose noise is on) with their ``any``/``all``."""
        self._all_lanes = {k: (m, bool(m.any()), bool(m.all())) for k, m in masks.items()}

    def _mask(self, name: str, lanes: slice | np.ndarray) -> tuple[np.ndarray, bool, bool]:
        """Mask ``name`` of ``lanes`` and whether any / every lane of them is in it."""
        if isinstance(lanes, slice):
            return self._all_lanes[name]
        m = self._all_lanes[name][0][lanes]
        return m, bool(m.any()), bool(m.all())

    def _present(self, lanes: slice | np.ndarray, names: Sequence[str]) -> list[str] | None:
        """The per-lane scalar state arrays ``self.<name>`` present (not NaN: the per-run
        ``None``) in every lane of ``lanes``; None where one is present in some only."""
        out = []
        for k in names:
            absent = np.isnan(getattr(self, k)[lanes])
            if not absent.any():
                out.append(k)
            elif not absent.all():
                return None
        return out

    def _scalar_rows(self, lanes: slice | np.ndarray, *names: str) -> np.ndarray | None:
        """:meth:`state_rows` of per-lane scalar state arrays (``names`` in the per-run
        ``state_fields`` order, NaN for the per-run ``None``, left out of its state)."""
        present = self._present(lanes, names)
        if present is None:
            return None
        if not present:
            return np.zeros((lane_count(self.n, lanes), 0))
        return np.stack([getattr(self, k)[lanes] for k in present], axis=1)

    def _set_scalar_rows(self, x: np.ndarray, lanes: slice | np.ndarray, *names: str) -> bool:
        """:meth:`set_state_rows` of :meth:`_scalar_rows`' arrays: False where ``x`` does
        not fit those present in ``lanes``."""
        present = self._present(lanes, names)
        if present is None or len(present) != x.shape[1]:
            return False
        for j, k in enumerate(present):
            getattr(self, k)[lanes] = x[:, j]
        return True

    # ------------------------------------------------------------------ data flow
    def output(self, t: float, lanes: slice | np.ndarray) -> dict[str, Any]:
        """Outputs from the state at ``t`` in ``lanes`` (modules without direct feedthrough)."""
        return {}

    def step(
        self, t: float, dt: float, inputs: dict[str, Any], lanes: slice | np.ndarray
    ) -> dict[str, Any]:
        """Consume ``inputs`` (lane values) at ``t`` in ``lanes``; outputs or the next state."""
        return {}

    def local_signals(self, lanes: slice | np.ndarray) -> dict[str, np.ndarray]:
        """Residual signals (Eq. 12) per lane, NaN where unknown."""
        return {}

    # ------------------------------------------------------------------ the per-run bridge
    def store(self, lanes: slice | np.ndarray) -> None:
        """Write the state of ``lanes`` into their per-run instances."""

    def load(self, lanes: slice | np.ndarray) -> None:
        """Read the parameters and the state of ``lanes`` from their per-run instances."""

    # ------------------------------------------------------------------ state vector
    def state_rows(self, lanes: slice | np.ndarray) -> np.ndarray | None:
        """Optional: each lane's state vector read from the arrays the class holds.

        An ``(L, n)`` array (a copy) in the per-run class's
        :meth:`~archself.modules.base.RuntimeModule.state` layout, or None where the class
        does not declare its layout (the default) or cannot give it for these lanes (a
        state whose size differs between them): :meth:`state` then goes through the
        per-run bridge.
        """
        return None

    def set_state_rows(self, x: np.ndarray, lanes: slice | np.ndarray) -> bool:
        """Optional: write an ``(L, n)`` array of :meth:`state_rows`' layout into the arrays.

        True if written; False (the default) where the class does not declare its layout
        or ``x`` does not fit the per-run layout of these lanes: :meth:`set_state` then
        goes through the per-run bridge (whose ``set_state`` says what does not fit).
        """
        return False

    def state(self, lanes: slice | np.ndarray = ALL) -> np.ndarray:
        """Each lane's state vector, an ``(L, n)`` array: the per-run class's
        :meth:`~archself.modules.base.RuntimeModule.state` of every lane.

        One array read where the class declares its layout (:meth:`state_rows`), else
        derived through the per-run bridge (:meth:`bridged_state`);
        :func:`archself.testing.check_pack` checks that it equals the per-run twin's state.

        Raises
        ------
        SimulationError
            When the lanes' states differ in size (a state that is absent in some lanes).
        """
        rows = self.state_rows(lanes)
        return self.bridged_state(lanes) if rows is None else rows

    def set_state(self, x: Any, lanes: slice | np.ndarray = ALL) -> None:
        """Write an ``(L, n)`` array of :meth:`state`'s layout back into ``lanes``.

        One array write where the class declares its layout (:meth:`set_state_rows`),
        else through the per-run bridge (:meth:`bridged_set_state`).
        """
        x = np.asarray(x, dtype=float)
        x = x.reshape(lane_count(self.n, lanes), -1)
        if not self.set_state_rows(x, lanes):
            self.bridged_set_state(x, lanes)

    def bridged_state(self, lanes: slice | np.ndarray = ALL) -> np.ndarray:
        """:meth:`state` through the per-run bridge: lane by lane, :meth:`store`, then the
        instance's ``state()`` (the layout is the per-run class's, and lanes that share one
        per-run instance, replicated from one system, read right)."""
        rows = []
        for i, m in zip(self.indices(lanes).tolist(), self._mods(lanes), strict=True):
            self.store(np.array([i]))
            rows.append(type(m).state(m))  # on the class: a relay's ``state`` value
        if len({r.size for r in rows}) > 1:
            raise SimulationError(f"{self.name}: the lanes' states differ in size "
                                  f"({sorted({r.size for r in rows})})")
        return np.stack(rows) if rows else np.zeros((0, 0))

    def bridged_set_state(self, x: Any, lanes: slice | np.ndarray = ALL) -> None:
        """:meth:`set_state` through the per-run bridge: each row to its lane's per-run
        instance (``set_state``), then :meth:`load` of that lane, lane by lane."""
        mods = self._mods(lanes)
        rows = np.asarray(x, dtype=float).reshape(len(mods), -1)
        for i, m, xj in zip(self.indices(lanes).tolist(), mods, rows, strict=True):
            type(m).set_state(m, xj)
            self.load(np.array([i]))


class PerLane(LaneModule):
    """Any module type in N lanes, run lane by lane through its per-run instances.

    The results are the per-run path's by construction: each lane's instance
    steps with its own values (absent lanes as ``None``). A lane that raises is
    reported in :attr:`failed`; a non-finite value a lane publishes is reported
    as ``"non-finite output"`` and published as absent.
    """

    def output(self, t, lanes):
        return self._collect(lanes, lambda m, j: m.output(t))

    def step(self, t, dt, inputs, lanes):
        return self._collect(
            lanes, lambda m, j: m.step(t, dt, {k: row(v, j) for k, v in inputs.items()})
        )

    def _collect(self, lanes, call) -> dict[str, Any]:
        """``call(instance, j)`` for the ``j``-th lane of ``lanes``; the outputs stacked."""

        outs: list[dict[str, Any]] = []
        for j, i in enumerate(self.indices(lanes).tolist()):
            try:
                out = call(self.modules[i], j) or {}
            except Exception as exc:  # noqa: BLE001 - one lane's failure, the executor's to judge
                self.failed[i] = f"raised {type(exc).__name__}"
                out = {}
            if any(v is not None and is_bad(v) for v in out.values()):
                self.failed[i] = "non-finite output"
                out = {}
            outs.append(out)
        keys = dict.fromkeys(k for out in outs for k in out)
        return {k: stack([o.get(k) for o in outs]) for k in keys}

    def local_signals(self, lanes):
        sigs = [self.modules[i].local_signals() for i in self.indices(lanes)]
        keys = list(self.kind.residual_signals) or (list(sigs[0]) if sigs else [])
        return {
            k: np.array([float(s.get(k, math.nan)) for s in sigs], dtype=float) for k in keys
        }


class LaneNormals:
    """Standard normal draws of N per-lane generators, in the per-run order, in blocks.

    Lane ``i`` draws exactly the numbers ``rngs[i].standard_normal(k)`` would give
    call after call (a generator's normals are one stream however they are
    chunked), but from a buffer refilled ``block`` numbers at a time, so a step
    of N lanes is one slice instead of N calls.

    Parameters
    ----------
    rngs : sequence of numpy.random.Generator
        One generator per lane (the per-run instance's ``rng``). One named for several
        lanes (lanes that share a per-run system: the whole-loop check's probes) is one
        stream drawn once for them while they refill together at one position (those
        lanes then have the same numbers: 512 normals drawn once per check, not per
        probe lane, and no generator copied); a refill of some of them alone, a
        :meth:`direct` draw or a :meth:`pin` first gives each a generator of its own at
        the stream's state (:meth:`_part`).
    block : int
        Numbers drawn per refill.

    Examples
    --------
    >>> a, b = np.random.default_rng(1), np.random.default_rng(1)
    >>> z = LaneNormals([a], block=4)
    >>> draws = np.concatenate([z.take(ALL, 3)[0] for _ in range(3)])
    >>> bool((draws == b.standard_normal(9)).all())
    True
    """

    def __init__(self, rngs: Sequence[np.random.Generator], block: int = 512) -> None:
        self.rngs = list(rngs)
        self.block = int(block)
        n = len(self.rngs)
        first: dict[int, int] = {}
        #: per lane, the lane whose generator it draws from while they share a stream
        self.src = np.array([first.setdefault(id(r), i) for i, r in enumerate(self.rngs)],
                            dtype=np.intp)
        self._shares = len(first) < n
        self.buf = np.empty((n, self.block))
        self.pos = np.full(n, self.block)  # every lane starts with an empty buffer
        self._same = True  # every lane at the same position
        self.drawn = np.zeros(n, dtype=np.int64)  # normals drawn from each stream so far
        # per lane, the last refills' (stream state, normals drawn before it): replay points
        start = {i: (self.rngs[i].bit_generator.state, 0) for i in first.values()}
        self.marks: list[list[tuple[Any, int]]] = [[start[j]] for j in self.src.tolist()]
        self._pinned: dict[int, Any] = {}

    def take(self, lanes: slice | np.ndarray, k: int) -> np.ndarray:
        """The next ``k`` normals of each lane in ``lanes``: an ``(L, k)`` array."""
        if self._same and isinstance(lanes, slice) and lanes == ALL:
            p = int(self.pos[0])
            if p + k > self.block:
                self._refill(np.arange(len(self.rngs)), k)
                p = 0
            out = self.buf[:, p : p + k].copy()  # the buffer is refilled in place later
            self.pos += k
            return out
        self._same = False
        idx = np.arange(len(self.rngs))[lanes] if isinstance(lanes, slice) else lanes
        short = idx[self.pos[idx] + k > self.block]
        if len(short):
            self._refill(short, k)
        cols = self.pos[idx][:, None] + np.arange(k)
        out = self.buf[idx[:, None], cols]
        self.pos[idx] += k
        if (self.pos == self.pos[0]).all():
            self._same = True
        return out

    def _refill(self, idx: np.ndarray, k: int) -> None:
        """Keep what lanes ``idx`` have left, then draw; ``k`` at most one block.

        Lanes that name one generator (:attr:`src`) and are refilled together at one
        position (every lane, :meth:`take` of ``ALL``) draw once and copy the rows; any
        other refill gives each its own generator first (:meth:`_part`)."""
        if k > self.block:
            raise ValueError(f"{k} draws at once exceed the block of {self.block}")
        together = self._shares and self._same and len(idx) == len(self.rngs)
        if self._shares and not together:
            self._part()
        for i in (np.flatnonzero(self.src == np.arange(len(self.rngs))) if together else idx):
            p = int(self.pos[i])
            left = self.block - p
            rng = self.rngs[i]
            marks = self.marks[i]
            marks.append((rng.bit_generator.state, int(self.drawn[i])))
            del marks[:-3]
            self.buf[i, :left] = self.buf[i, p:]
            self.buf[i, left:] = rng.standard_normal(self.block - left)
            self.drawn[i] += self.block - left
            self.pos[i] = 0
        if together:  # the lanes at one stream's position: its rows, drawn once
            sharers = np.flatnonzero(self.src != np.arange(len(self.rngs)))
            self.buf[sharers] = self.buf[self.src[sharers]]
            self.drawn[sharers] = self.drawn[self.src[sharers]]
            self.pos[sharers] = 0
            for i in sharers.tolist():
                self.marks[i] = [*self.marks[self.src[i]]]

    def _part(self) -> None:
        """Each lane its own generator, at the state of the stream it shared (every
        lane of a shared stream has drawn what the stream has)."""
        for i, j in enumerate(self.src.tolist()):
            if i != j:
                self.rngs[i] = _same_stream(self.rngs[j])
        self.src = np.arange(len(self.rngs))
        self._shares = False

    # ------------------------------------------------------------------ the exact stream
    def exact_state(self, i: int) -> Any:
        """The state lane ``i``'s stream would have in the per-run run now.

        The stream itself is ahead (it filled the buffer); the state is replayed from
        the last refill point before the numbers the lane has used.
        """
        used = int(self.drawn[i]) - (self.block - int(self.pos[i]))
        state, count = next(m for m in reversed(self.marks[i]) if m[1] <= used)
        g = np.random.Generator(type(self.rngs[i].bit_generator)())
        g.bit_generator.state = state
        g.standard_normal(used - count)
        return g.bit_generator.state

    def direct(self, i: int) -> np.random.Generator:
        """Lane ``i``'s generator at its per-run position, for draws the buffer cannot give.

        A per-run module that draws other numbers than normals (a dropout's uniform
        after its normal) draws from the generator itself: the lane's buffered normals
        are dropped and the stream set back to where the per-run run stands
        (:meth:`exact_state`). Call :meth:`resume` after the draws.
        """
        if self._shares:
            self._part()
        rng = self.rngs[i]
        if self.pos[i] < self.block:
            rng.bit_generator.state = self.exact_state(i)
            self.drawn[i] -= self.block - int(self.pos[i])
            self.pos[i] = self.block
            self._same = False
        return rng

    def resume(self, i: int) -> None:
        """After :meth:`direct` draws: lane ``i``'s stream position is its replay point."""
        self.marks[i] = [(self.rngs[i].bit_generator.state, int(self.drawn[i]))]

    def pin(self, i: int) -> None:
        """Put lane ``i``'s stream at its per-run state (for the per-run API) until unpin."""
        if self._shares:
            self._part()
        if i not in self._pinned:
            bg = self.rngs[i].bit_generator
            self._pinned[i] = bg.state
            bg.state = self.exact_state(i)

    def unpin(self) -> None:
        """Give every pinned stream back its state (the buffer's)."""
        for i, state in self._pinned.items():
            self.rngs[i].bit_generator.state = state
        self._pinned.clear()
