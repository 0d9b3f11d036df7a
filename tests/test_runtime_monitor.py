"""The Monitor's two update paths (module by module, numpy arrays) against a reference.

The reference below is the Monitor as first written: one :class:`ResidualFilter`
and one :class:`ModuleStatus` per module, :func:`module_residual` per module. The
Monitor must give the same numbers bit for bit on both of its paths, whatever the
system reports (NaN, ``None``, strings, missing modules, unavailable modules with
and without a reason, a changing active set).
"""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np
import pytest

from archself.model.generate import generate_architecture
from archself.model.loader import load_text
from archself.runtime.monitor import (
    ModuleStatus,
    Monitor,
    filter_confidence,
    filter_gain,
    is_own_failure,
    module_residual,
    unavailable_residual,
)

N = 60


class ResidualFilter:
    """First-order low-pass filter ``y ← y + g·(s − y)`` holding on missing samples.

    Starts at 0 (a healthy module's nominal residual) so that one noisy first
    sample cannot raise an alarm.

    Parameters
    ----------
    time_constant : float
        T in seconds; 0 passes the signal through.
    """

    def __init__(self, time_constant: float) -> None:
        self.time_constant = float(time_constant)
        self.reset()

    def reset(self) -> None:
        """Start again from 0, with no sample."""
        self.value = 0.0
        self.valid_time = 0.0
        self.samples = 0

    def update(self, sample: float, dt: float) -> float:
        """Feed one sample taken ``dt`` seconds after the previous one."""
        if math.isfinite(sample):
            if self.samples == 0 and self.time_constant <= 0:
                self.value = sample
            else:
                self.value += filter_gain(dt, self.time_constant) * (sample - self.value)
            self.samples += 1
            self.valid_time += max(dt, 0.0)
        return self.value

    @property
    def confidence(self) -> float:
        """How settled the filter is: ``1 − exp(−t_valid/T)`` (1 without smoothing)."""
        return filter_confidence(self.samples, self.valid_time, self.time_constant)


def test_reference_filter_settles_and_holds() -> None:
    f = ResidualFilter(2.0)
    assert f.confidence == 0.0
    for _ in range(50):
        f.update(1.0, 1.0)
    assert f.value == pytest.approx(1.0, abs=1e-6)
    assert f.confidence == pytest.approx(1.0, abs=1e-6)
    held = f.update(math.nan, 1.0)  # a missing sample holds the value
    assert held == f.value


def _arch(normalization: str = "nominal") -> Any:
    """A generated graph with varied residual blocks, some modules without one, constraints."""
    text = generate_architecture(N, seed=3)
    lines = text.splitlines()
    out = []
    for line in lines:
        m = re.match(r"  (m(\d+)): \{kind: (\w+), type: ([\w.]+), residual: .*\}$", line)
        if m is None:
            out.append(line)
            continue
        name, i, kind, typ = m.group(1), int(m.group(2)), m.group(3), m.group(4)
        parts = [f"kind: {kind}", f"type: {typ}"]
        if i % 7 != 3:
            smoothing = (0.0, 0.5, 2.0, 5.0)[i % 4]
            parts.append(
                f"residual: {{signal: deviation, sensitivity: {0.5 + (i % 3) * 0.75}, "
                f"nominal: {0.05 + 0.01 * (i % 5)}, smoothing_s: {smoothing}}}"
            )
        if i % 11 == 5:
            parts.append(
                f"constraints: {{requires: [m{(i + 1) % N}], limits: {{max_deviation: 0.3}}}}"
            )
        elif i % 13 == 6:
            parts.append(
                f"constraints: {{excludes: [m{(i + 2) % N}], limits: {{min_deviation: -1.0}}}}"
            )
        out.append(f"  {name}: {{{', '.join(parts)}}}")
    text = "\n".join(out) + "\n"
    text = text.replace("runtime:\n", f"runtime:\n  normalization: {normalization}\n", 1)
    return load_text(text).arch


class _Reference:
    """The Monitor's original per-module loop (the specification of its numbers)."""

    def __init__(self, arch: Any, names: list[str]) -> None:
        self.arch = arch
        self.names = names
        self.filters = {
            n: ResidualFilter(m.residual.smoothing_s)
            for n, m in arch.modules.items()
            if m.residual is not None
        }
        self.t_prev: float | None = None
        self.r_sat = unavailable_residual(arch.runtime)

    def observe(self, s: Any, active: frozenset[str]) -> tuple[Any, ...]:
        t = float(s.t)
        dt = self.arch.runtime.period_s if self.t_prev is None else t - self.t_prev
        self.t_prev = t
        local, avail, why = s.local_signals(), s.available(), s.health()
        r = np.zeros(len(self.names))
        signals: dict[str, Any] = {}
        kappa: dict[str, ModuleStatus] = {}
        for k, name in enumerate(self.names):
            mod = self.arch.modules[name]
            on = name in active
            st = ModuleStatus(active=on, available=bool(avail.get(name, True)))
            kappa[name] = st
            if on:
                cons = mod.constraints
                st.violations = [
                    f"requires {m} (inactive)" for m in cons.requires if m not in active
                ]
                st.violations += [f"excludes {m} (active)" for m in cons.excludes if m in active]
                for key, limit in cons.limits.items():
                    v = _num((local.get(name) or {}).get(key[4:], math.nan))
                    if math.isfinite(v) and (
                        (key.startswith("max_") and v > limit)
                        or (key.startswith("min_") and v < limit)
                    ):
                        st.violations.append(f"{key} {limit:g} violated ({v:g})")
                if not st.available:
                    st.reason = why.get(name)
                    if st.reason is not None and is_own_failure(st.reason):
                        r[k] = self.r_sat
            filt = self.filters.get(name)
            if filt is None:
                continue
            if not on:
                filt.reset()
                st.confidence = 0.0
                continue
            sample = _num((local.get(name) or {}).get(mod.residual.signal, math.nan))
            ok = math.isfinite(sample) and st.available
            st.residual_ok = ok
            value = filt.update(sample if ok else math.nan, dt)
            st.confidence = filt.confidence
            if ok:
                signals[name] = float(value)
                if filt.confidence < self.arch.runtime.min_confidence:
                    continue  # not trusted yet: r_i = 0
                r[k] = module_residual(
                    value,
                    mod.residual.sensitivity,
                    mod.residual.nominal,
                    self.arch.runtime.normalization,
                )
            else:
                signals[name] = None
        return r, signals, kappa


def _num(x: Any) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


class _Tape:
    """One cycle of what a system reports, replayed identically to every monitor."""

    def __init__(self, t: float, local: dict, avail: dict, why: dict) -> None:
        self.t, self._local, self._avail, self._why = t, local, avail, why

    def objective_error(self) -> float:
        return 0.7

    def local_signals(self) -> dict:
        return self._local

    def available(self) -> dict:
        return self._avail

    def health(self) -> dict:
        return self._why


def _tapes(names: list[str], cycles: int, seed: int) -> list[tuple[_Tape, frozenset[str]]]:
    rng = np.random.default_rng(seed)
    out = []
    active = frozenset(names)
    for c in range(cycles):
        if c % 9 == 4:  # the active set changes now and then (filters reset and resume)
            active = frozenset(n for n in names if rng.random() > 0.25)
        local: dict[str, Any] = {}
        for n in sorted(active):
            u = rng.random()
            if u < 0.04:
                continue  # module missing from local_signals
            if u < 0.07:
                local[n] = {}
            elif u < 0.09:
                local[n] = None
            else:
                v: Any = float(rng.normal(0.0, 0.2 if u < 0.8 else 3.0))
                w = rng.random()
                if w < 0.05:
                    v = math.nan
                elif w < 0.07:
                    v = None
                elif w < 0.08:
                    v = "garbage"
                elif w < 0.09:
                    v = "0.25"
                elif w < 0.10:
                    v = math.inf
                elif w < 0.11:
                    v = 2  # an int
                local[n] = {"deviation": v}
        avail = {n: bool(rng.random() > 0.08) for n in active}
        reasons = ["raised RuntimeError", "lost input signal", "non-finite output", None]
        why = {n: reasons[int(rng.integers(4))] for n, ok in avail.items() if not ok}
        t = 1.0 + c * 1.0 + (1e-12 if c % 5 == 0 else 0.0)  # dt not always the same float
        out.append((_Tape(t, local, avail, why), active))
    return out


@pytest.mark.parametrize("normalization", ["nominal", "none"])
def test_monitor_matches_reference(normalization: str) -> None:
    arch = _arch(normalization)
    names = list(arch.modules)
    ref = _Reference(arch, names)
    mon = Monitor(arch, names)
    kept = []
    for tape, active in _tapes(names, 60, seed=11):
        r_ref, sig_ref, kappa_ref = ref.observe(tape, active)
        obs = mon.observe(tape, active)
        assert obs.r.tobytes() == r_ref.tobytes()
        assert obs.signals == sig_ref
        assert list(obs.kappa) == list(kappa_ref)
        found = {
            n: s.to_dict()
            for n, s in kappa_ref.items()
            if s.active and (not s.available or not s.residual_ok or s.violations)
        }
        assert {n: s.to_dict() for n, s in obs.kappa.findings()} == found
        assert list(dict(obs.kappa.findings())) == list(found)  # index order
        kept.append((obs, {n: s.to_dict() for n, s in kappa_ref.items()}, dict(sig_ref)))
    # every κ (not only the findings) and the signals stay as they were observed
    for obs, kappa_ref, sig_ref in kept:
        assert {n: obs.kappa[n].to_dict() for n in obs.kappa} == kappa_ref
        assert obs.signals == sig_ref


def test_statusmap_is_a_mapping() -> None:
    arch = _arch()
    names = list(arch.modules)
    mon = Monitor(arch, names)
    tape, active = _tapes(names, 1, seed=2)[0]
    kappa = mon.observe(tape, active).kappa
    assert len(kappa) == N and "m0" in kappa and "nope" not in kappa
    assert kappa["m0"] is kappa["m0"]
    with pytest.raises(KeyError):
        kappa["nope"]
    assert kappa.unavailable() == {n for n, ok in tape.available().items() if not ok}
