"""The static blocks and the relay in N lanes: ``generic.gain``, ``sum``, ``select``, ``relay``.

The static blocks (:mod:`archself_blocks.signals`) read their inputs in the per-run
order (:data:`~archself_blocks.signals.PORTS`, then the edges) and take, lane by
lane, the first value there (gain, select) or the weighted sum of those there (sum),
with each lane's own gain, offset, weights or indices. Inputs the arrays cannot
hold as the per-run block reads them — values of different widths (numpy would
broadcast them per run), lanes with a different shape of gain or offset, numbers
inside object lists — go lane by lane through the per-run instances
(:class:`~archself.lanes.PerLane`): the same results, not faster.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from archself.lanes.module import ALL, LaneNormals, PerLane, lane_count
from archself_blocks.lanes_base import BlockLanes, as_rows, present
from archself_blocks.lti import matvec
from archself_blocks.signals import PORTS

__all__ = ["ExpressionLanes", "GainLanes", "RelayLanes", "SelectLanes", "SumLanes"]

_NUMBERS = (int, float, list, np.ndarray)


class _Unbatched(Exception):
    """Inputs the batched block does not take: the step goes lane by lane."""


def _values(inputs: dict[str, Any]) -> list[np.ndarray | None]:
    """Every input as rows, in the per-run order (:data:`PORTS`, then the edges)."""
    out: list[np.ndarray | None] = []
    for name in PORTS:
        value = inputs.get(name)
        for v in value if type(value) is tuple else (() if value is None else (value,)):
            if type(v) is list and any(isinstance(o, _NUMBERS) for o in v):
                raise _Unbatched
            out.append(as_rows(v))
    return out


def _first(values: list[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray] | None:
    """Per lane the first value there, and the lanes with one (None: no lane has one)."""
    given = [v for v in values if v is not None]
    if not given:
        return None
    if len({v.shape[1] for v in given}) > 1:
        raise _Unbatched
    x = given[0].copy()
    has = present(x)
    for v in given[1:]:
        if has.all():
            break
        take = ~has & present(v)
        x[take] = v[take]
        has |= take
    return x, has


class _StaticLanes(BlockLanes):
    """A static block in N lanes, with the per-run instances as the fallback."""

    def __init__(self, modules) -> None:
        self.one_by_one = PerLane(modules)
        super().__init__(modules)

    def _fallback(self, t, dt, inputs, lanes) -> dict[str, Any]:
        out = self.one_by_one.step(t, dt, inputs, lanes)
        self.failed.update(self.one_by_one.failed)
        self.one_by_one.failed.clear()
        return out

    def _publish(self, y: np.ndarray | None, has: np.ndarray, lanes, scalar: bool) -> dict:
        """The result under every library signal name (a 1-wide result as a number)."""
        if y is None or not has.any():
            return dict.fromkeys(PORTS)
        if not has.all():
            y[~has] = math.nan
        self._screen(lanes, has, y)
        return dict.fromkeys(PORTS, y[:, 0] if y.shape[1] == 1 and scalar else y)

    def _raised(self, lanes, where: np.ndarray, kind: str) -> None:
        for i in self.indices(lanes)[where]:
            self.failed[int(i)] = f"raised {kind}"

    def step(self, t, dt, inputs, lanes):
        if self.mixed:
            return self._fallback(t, dt, inputs, lanes)
        try:
            values = _values(inputs)
            return self._compute(values, lanes)
        except _Unbatched:
            return self._fallback(t, dt, inputs, lanes)

    mixed = False

    def _compute(self, values: list[np.ndarray | None], lanes) -> dict[str, Any]:
        raise NotImplementedError


class GainLanes(_StaticLanes):
    """:class:`~archself_blocks.signals.Gain` in N lanes: ``K·in + offset`` per lane."""

    def load(self, lanes):
        ks = [m.k for m in self.modules]
        offsets = [m.offset for m in self.modules]
        self.mixed = (len({k.shape for k in ks}) > 1 or len({o.shape for o in offsets}) > 1)
        if self.mixed:
            return
        self.scalar_k = ks[0].ndim == 0
        self.k = np.array([k if k.ndim != 1 else k.reshape(1, -1) for k in ks], dtype=float)
        self.offset = np.array(offsets, dtype=float)

    def _compute(self, values, lanes):
        got = _first(values)
        if got is None:
            return dict.fromkeys(PORTS)
        x, has = got
        if self.scalar_k:
            y = self.k[lanes][:, None] * x
        elif self.k.shape[2] != x.shape[1]:  # K @ x raises per run where x is there
            self._raised(lanes, has, "ValueError")
            return dict.fromkeys(PORTS)
        else:
            y = matvec(self.k[lanes], x)
        off = self.offset[lanes]
        y = y + (off[:, None] if off.ndim == 1 else off)
        return self._publish(y, has, lanes, True)


class SumLanes(_StaticLanes):
    """:class:`~archself_blocks.signals.Sum` in N lanes: ``Σ w_k·in_k`` over the values there."""

    def load(self, lanes):
        weights = [m.params["weights"] for m in self.modules]
        self.counts = np.array([-1 if w is None else len(w) for w in weights])
        width = max((len(w) for w in weights if w is not None), default=0)
        self.weights = np.ones((self.n, width))
        for i, w in enumerate(weights):
            if w is not None:
                self.weights[i, : len(w)] = [float(x) for x in w]

    def _compute(self, values, lanes):
        given = [v for v in values if v is not None]
        if len({v.shape[1] for v in given}) > 1:
            raise _Unbatched
        L = lane_count(self.n, lanes)
        counts = self.counts[lanes]
        short = (counts >= 0) & (counts < len(values))  # too few weights: raises per run
        if short.any():
            self._raised(lanes, short, "ValueError")
        if not given:
            return dict.fromkeys(PORTS)
        total = np.full((L, given[0].shape[1]), math.nan)
        has = np.zeros(L, dtype=bool)
        w = np.ones((L, len(values)))
        cols = min(len(values), self.weights.shape[1])
        w[:, :cols] = self.weights[lanes][:, :cols]
        for j, v in enumerate(values):
            if v is None:
                continue
            here = present(v)
            term = w[:, j][:, None] * v
            total = np.where((has & here)[:, None], total + term,
                             np.where(here[:, None], term, total))
            has |= here
        return self._publish(total, has & ~short, lanes, True)


class SelectLanes(_StaticLanes):
    """:class:`~archself_blocks.signals.Select` in N lanes: components ``index`` per lane."""

    def load(self, lanes):
        idx = [m.idx for m in self.modules]
        scalar = {m.scalar for m in self.modules}
        self.mixed = len({len(i) for i in idx}) > 1 or len(scalar) > 1
        if not self.mixed:
            self.idx = np.array(idx, dtype=np.intp)
            self.scalar = scalar.pop()

    def _compute(self, values, lanes):
        got = _first(values)
        if got is None:
            return dict.fromkeys(PORTS)
        x, has = got
        idx = self.idx[lanes]
        outside = has & (idx >= x.shape[1]).any(axis=1)
        if outside.any():
            self._raised(lanes, outside, "IndexError")
            has = has & ~outside
        y = np.take_along_axis(x, np.minimum(idx, x.shape[1] - 1), axis=1)
        return self._publish(y, has, lanes, self.scalar)


class ExpressionLanes(_StaticLanes):
    """:class:`~archself_blocks.signals.Expression` in N lanes: ``f(inputs)`` on rows.

    The expression's operations are elementwise, so the per-run callable runs on the
    ``(L, w)`` rows as it does on one run's vectors; a lane missing an input gives no
    output. Lanes with different expressions step one by one.
    """

    def load(self, lanes):
        texts = {(m.params["expression"], m.width, m.channel) for m in self.modules}
        self.mixed = len(texts) > 1
        first = self.modules[0]
        self.names, self.evaluate = first.names, first.evaluate
        self.points: dict[str, np.ndarray] = {}  # each lane's last inputs (its linear model)

    def store(self, lanes):
        for i in self.indices(lanes).tolist():
            if self.points and not np.isnan(self.points[self.names[0]][i, 0]):
                self.modules[i].point = {n: self.points[n][i].copy() for n in self.names}

    def _remember(self, env: dict[str, np.ndarray], has: np.ndarray, lanes) -> None:
        idx = self.indices(lanes)[has]
        for name, rows in env.items():
            kept = self.points.get(name)
            if kept is None or kept.shape[1] != rows.shape[1]:
                kept = self.points[name] = np.full((self.n, rows.shape[1]), math.nan)
            kept[idx] = rows[has]

    def step(self, t, dt, inputs, lanes):
        if self.mixed:
            return self._fallback(t, dt, inputs, lanes)
        env, has = {}, None
        for name in self.names:
            value = inputs.get(name)
            if type(value) is list or type(value) is tuple:
                return self._fallback(t, dt, inputs, lanes)
            rows = as_rows(value)
            if rows is None:
                return dict.fromkeys(PORTS)
            env[name] = rows
            has = present(rows) if has is None else has & present(rows)
        if has is None or not has.any():
            return dict.fromkeys(PORTS)
        try:
            y = self.evaluate(env)
        except ValueError:  # shapes the per-run blocks refuse: lane by lane, as they do
            return self._fallback(t, dt, inputs, lanes)
        self._remember(env, has, lanes)
        y = np.broadcast_to(y, (len(has), y.shape[-1])).copy()
        return self._publish(y, has, lanes, True)


class RelayLanes(BlockLanes):
    """:class:`~archself_blocks.relay.Relay` in N lanes: a unit delay of the inputs' mean.

    Per lane: the mean of the values there (their sum in edge order), times the
    lane's gain, plus its noise (a normal from its stream where ``noise`` ≠ 0); a
    lane with a value that is not a number holds its state.
    """

    def __init__(self, modules) -> None:
        self.normals = LaneNormals([m.rng for m in modules])
        super().__init__(modules)

    def load(self, lanes):
        mods = self._mods(lanes)
        self._read(lanes, "gain", [float(m.params["gain"]) for m in mods])
        self._read(lanes, "noise", [float(m.params["noise"]) for m in mods])
        self._read(lanes, "state", [m.value for m in mods])
        self._read(lanes, "deviation", [m.signals.get("deviation", math.nan) for m in mods])
        self.noisy = self.noise != 0

    def store(self, lanes):
        for i, m in zip(self.indices(lanes).tolist(), self._mods(lanes), strict=True):
            m.value = float(self.state[i])
            if not math.isnan(self.deviation[i]):
                m.signals["deviation"] = float(self.deviation[i])

    def local_signals(self, lanes):
        return {"deviation": self.deviation[lanes].copy()}

    def output(self, t, lanes):
        state = self.state[lanes].copy()
        self._screen(lanes, np.ones(len(state), dtype=bool), state)
        return {"signal": state}

    def step(self, t, dt, inputs, lanes):
        L = lane_count(self.n, lanes)
        value = inputs.get("signal")
        total, count = np.zeros(L), np.zeros(L, dtype=int)
        junk = np.zeros(L, dtype=bool)
        for v in value if type(value) is tuple else (() if value is None else (value,)):
            if v is None:
                continue
            if type(v) is list:  # objects: a number is one, anything else is junk
                here = np.array([o is not None for o in v])
                col = np.array([float(o) if isinstance(o, (int, float)) else math.nan for o in v])
                junk |= here & np.isnan(col)
                here &= ~np.isnan(col)
            else:
                rows = as_rows(v)
                here = present(rows)
                if rows.shape[1] != 1:
                    junk |= here
                    continue
                col = rows[:, 0]
            total = np.where(here, total + col, total)
            count += here
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = np.where(count > 0, total / count, 0.0)
        state = self.state[lanes]
        base = np.where(junk, state, self.gain[lanes] * mean)
        noisy = self.noisy[lanes]
        new = base + 0.0
        if noisy.any():
            sel = ALL if isinstance(lanes, slice) and noisy.all() else self.indices(lanes)[noisy]
            z = self.normals.take(sel, 1)[:, 0]
            new[noisy] = base[noisy] + self.noise[lanes][noisy] * z
        self.state[lanes] = new
        self.deviation[lanes] = np.abs(new - base)
        return {}
