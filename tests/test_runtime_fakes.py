"""A small fake LiveSystem (docs/develop.md contract) and a generic test architecture.

The runtime tests import :class:`FakeSystem` and :func:`make_arch` from here, so
they exercise the MAPE-K loop without the simulator. The names are deliberately
abstract (a source, two estimators, controllers, an actuator).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from archself.model.architecture import Architecture

BASE_MODULES = ["src", "est_a", "ctl_a", "act"]


def make_arch(**runtime_overrides: Any) -> Architecture:
    """A generic architecture: source → estimator → controller → actuator, with alternatives.

    Configurations: ``base`` (initial), ``alt_est`` (estimator b), ``alt_ctl``
    (controller b), ``bad`` (controller c, destabilizing), ``heavy`` (over the
    power budget). Actions: ``swap_est`` (est_a → alt_est), ``back_est`` (est_b →
    base), ``unsafe`` (est_a → bad, scores best), ``heavy_est`` (est_a → heavy),
    ``swap_ctl`` (act → alt_ctl), ``tune`` (parameter update of ctl_a).
    """
    rt: dict[str, Any] = {
        "step_s": 0.1,
        "period_s": 1.0,
        "objective": {"actual": "src.pos", "reference": "src.ref", "acceptable": 0.5},
        "threshold": 0.55,
        "warmup_steps": 0,
        "dwell_s": 10.0,
        "cost_weight": 0.5,
        "stability": {"margin": 0.001, "lyapunov_alpha": 0.01, "horizon_steps": 10},
    }
    rt.update(runtime_overrides)
    if "hysteresis" in runtime_overrides or "top_k" in runtime_overrides:
        rt.pop("threshold", None)

    def res(signal: str) -> dict[str, Any]:
        return {"signal": signal, "sensitivity": 1.0, "nominal": 0.1, "smoothing_s": 0.0}

    data = {
        "archself": 1,
        "name": "fake",
        "modules": {
            "src": {
                "kind": "physical",
                "type": "t.src",
                "residual": res("err"),
                "resources": {"power_w": 1.0},
            },
            "est_a": {
                "kind": "functional",
                "type": "t.est",
                "residual": res("innov"),
                "resources": {"power_w": 1.0},
            },
            "est_b": {
                "kind": "functional",
                "type": "t.est",
                "residual": res("innov"),
                "resources": {"power_w": 2.0},
            },
            "est_h": {"kind": "functional", "type": "t.est", "resources": {"power_w": 50.0}},
            "ctl_a": {
                "kind": "functional",
                "type": "t.ctl",
                "residual": res("track"),
                "params": {"gain": {"value": 1.0, "min": 0.0, "max": 10.0}},
            },
            "ctl_b": {"kind": "functional", "type": "t.ctl", "residual": res("track")},
            "ctl_c": {"kind": "functional", "type": "t.ctl"},
            "act": {
                "kind": "physical",
                "type": "t.act",
                "residual": res("cmd_err"),
                "resources": {"power_w": 3.0},
            },
            "model": {"kind": "model", "type": "t.model"},
        },
        "edges": [
            {"from": "src", "to": "est_a", "weight": 0.5, "carries": "y"},
            {"from": "src", "to": "est_b", "weight": 0.5, "carries": "y"},
            {"from": "src", "to": "est_h", "weight": 0.5, "carries": "y"},
            {"from": "est_a", "to": "ctl_a", "weight": 0.5, "carries": "xhat"},
            {"from": "est_b", "to": "ctl_a", "weight": 0.5, "carries": "xhat"},
            {"from": "est_h", "to": "ctl_a", "weight": 0.5, "carries": "xhat"},
            {"from": "est_a", "to": "ctl_b", "weight": 0.5, "carries": "xhat"},
            {"from": "est_a", "to": "ctl_c", "weight": 0.5, "carries": "xhat"},
            {"from": "ctl_a", "to": "act", "weight": 0.4, "carries": "u"},
            {"from": "ctl_b", "to": "act", "weight": 0.4, "carries": "u"},
            {"from": "ctl_c", "to": "act", "weight": 0.4, "carries": "u"},
            {"from": "act", "to": "src", "weight": 0.3, "carries": "force"},
            {"from": "model", "to": "ctl_a", "weight": 0.1, "carries": "m"},
        ],
        "configurations": {
            "base": {"modules": BASE_MODULES + ["model"], "initial": True},
            "alt_est": {"modules": ["src", "est_b", "ctl_a", "act", "model"]},
            "alt_ctl": {"modules": ["src", "est_a", "ctl_b", "act"]},
            "bad": {"modules": ["src", "est_a", "ctl_c", "act"]},
            "heavy": {"modules": ["src", "est_h", "ctl_a", "act"]},
        },
        "actions": [
            {
                "id": "swap_est",
                "module": "est_a",
                "kind": "substitute",
                "to": "alt_est",
                "cost": 0.2,
                "improvement": {"method": "sensitivity", "delta_theta": -0.9},
            },
            {
                "id": "back_est",
                "module": "est_b",
                "kind": "substitute",
                "to": "base",
                "applies_in": ["alt_est"],
                "cost": 0.2,
                "improvement": {"method": "sensitivity", "delta_theta": -0.9},
            },
            {
                "id": "unsafe",
                "module": "est_a",
                "kind": "substitute",
                "to": "bad",
                "cost": 0.0,
                "improvement": {"method": "sensitivity", "delta_theta": -1.0},
            },
            {
                "id": "heavy_est",
                "module": "est_a",
                "kind": "substitute",
                "to": "heavy",
                "cost": 0.0,
                "improvement": {"method": "table", "values": {"est_a": 100.0}},
            },
            {
                "id": "swap_ctl",
                "module": "act",
                "kind": "substitute",
                "to": "alt_ctl",
                "applies_in": ["base"],
                "cost": 0.3,
                "improvement": {"method": "sensitivity", "delta_theta": -0.9},
            },
            {
                "id": "tune",
                "module": "ctl_a",
                "kind": "parameter_update",
                "set": {"gain": 2.0},
                "cost": 0.05,
                "improvement": {"method": "sensitivity", "delta_theta": -0.5},
            },
        ],
        "constraints": [{"resource": "power_w", "max": 20.0}],
        "scenarios": {"s": {"duration_s": 10.0}},
        "runtime": rt,
    }
    return Architecture.model_validate(data)


Signals = Callable[[float, str], dict[str, dict[str, float]]]


class FakeSystem:
    """A programmable stand-in for :class:`archself.system.live.LiveSystem`.

    Parameters
    ----------
    arch : Architecture
    signals : callable
        ``signals(t, configuration) -> {module: {signal: value}}``: the local
        signals (only active modules are reported).
    linearizations : dict, optional
        configuration -> closed-loop A (or None for "no model").
    dynamics : dict, optional
        configuration -> continuous A_c of the error dynamics ``ẋ = A_c x`` used
        by ``state_error`` (default −0.5 I).
    unavailable : set, optional
        Modules reported unavailable.
    """

    def __init__(
        self,
        arch: Architecture,
        signals: Signals | None = None,
        *,
        linearizations: dict[str, Any] | None = None,
        dynamics: dict[str, Any] | None = None,
        unavailable: set[str] | None = None,
        x0: Any = (1.0, 0.0),
        objective: Callable[[FakeSystem], float] | None = None,
    ) -> None:
        self.arch = arch
        self.dt = arch.runtime.step_s
        self.t = 0.0
        self.configuration = arch.initial_configuration()
        self.signals = signals or (lambda t, c: {})
        self.linearizations = linearizations if linearizations is not None else {}
        self.dynamics = dynamics or {}
        self.unavailable = set(unavailable or ())
        self.x = np.asarray(x0, dtype=float)
        self.params: dict[str, dict[str, Any]] = {}
        self.applied: list[tuple[float, str]] = []
        self.param_log: list[tuple[float, str, dict]] = []
        self.is_snapshot = False
        self._objective = objective
        self.outputs: dict[str, dict[str, Any]] = {}

    # -- contract
    @property
    def active(self) -> set[str]:
        return set(self.arch.configurations[self.configuration].modules)

    @property
    def modules(self) -> dict[str, Any]:
        return {n: object() for n in self.active}

    def step(self) -> None:
        A = np.asarray(self.dynamics.get(self.configuration, -0.5 * np.eye(self.x.size)))
        self.x = self.x + self.dt * (A @ self.x)
        self.t = round(self.t + self.dt, 10)

    def run(self, seconds: float) -> None:
        for _ in range(int(round(seconds / self.dt))):
            self.step()

    def local_signals(self) -> dict[str, dict[str, float]]:
        sig = self.signals(self.t, self.configuration)
        return {n: dict(sig.get(n, {})) for n in self.active}

    def available(self) -> dict[str, bool]:
        return {n: n not in self.unavailable for n in self.active}

    def objective_error(self) -> float:
        if self._objective is not None:
            return float(self._objective(self))
        return float(np.linalg.norm(self.x))

    def state_error(self) -> np.ndarray:
        return self.x.copy()

    def apply_configuration(self, name: str) -> None:
        if name not in self.arch.configurations:
            raise KeyError(name)
        self.applied.append((self.t, name))
        self.configuration = name

    def set_params(self, module: str, values: dict[str, Any]) -> None:
        self.params.setdefault(module, {}).update(values)
        self.param_log.append((self.t, module, dict(values)))

    def snapshot(self) -> FakeSystem:
        snap = copy.deepcopy(self)
        snap.is_snapshot = True
        snap.applied = []
        snap.param_log = []
        return snap

    def linearization(self, configuration: str | None = None) -> Any:
        conf = configuration or self.configuration
        A = self.linearizations.get(conf)
        if callable(A):
            return A(self)
        return A


def run_loop(loop: Any, system: FakeSystem, seconds: float) -> list[dict[str, Any]]:
    """Step ``system`` and call ``loop`` every ``runtime.period_s``; return all switches."""
    per = int(round(system.arch.runtime.period_s / system.dt))
    n = int(round(seconds / system.dt))
    switches: list[dict[str, Any]] = []
    for i in range(n):
        system.step()
        if (i + 1) % per == 0:
            switches.extend(loop(system))
    return switches


def high(module: str, signal: str, value: float = 1.0) -> Signals:
    """Signals: ``module.signal`` at ``value`` (10× nominal by default), all else healthy."""

    def f(t: float, conf: str) -> dict[str, dict[str, float]]:
        return {module: {signal: value}}

    return f


def test_fake_system_contract():
    arch = make_arch()
    sys_ = FakeSystem(arch, high("est_a", "innov"))
    assert sys_.active == set(BASE_MODULES + ["model"])
    snap = sys_.snapshot()
    snap.apply_configuration("alt_est")
    snap.run(1.0)
    assert sys_.configuration == "base" and sys_.t == 0.0
    assert snap.t == 1.0
    assert math.isclose(sys_.objective_error(), 1.0)
    assert sys_.local_signals()["est_a"] == {"innov": 1.0}
