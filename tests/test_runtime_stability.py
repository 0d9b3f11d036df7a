"""The Lyapunov fallback (Eq. 22–24) judges the whole rollout, not its two ends."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from archself.runtime.stability import check_action_stability, lyapunov_decrease


class _Rollout:
    """A system without linearization whose state error follows ``err(t)`` step by step."""

    def __init__(self, err, t: int = 0) -> None:
        self.err, self.t, self.configuration = err, t, "c0"

    def linearization(self, configuration):
        return None

    def snapshot(self):
        return _Rollout(self.err, self.t)

    def apply_configuration(self, name):
        self.configuration = name

    def step(self):
        self.t += 1

    def state_error(self):
        return np.array([self.err(self.t)])


def _period_two(t: int) -> float:
    """Diverging period-2 loop: 0 on even steps, growing on odd ones (‖x_0‖ = 1)."""
    return 1.0 if t == 0 else (0.0 if t % 2 == 0 else 1.2 ** t)


def _late(t: int) -> float:
    """Converges for 12 steps, then turns back up (still below the start at step 20)."""
    return 0.9 ** t if t <= 12 else 0.9 ** 12 * 1.15 ** (t - 12)


def _verdict(err, horizon: int):
    action = SimpleNamespace(kind="substitute", to="c1", module="m", set=None)
    return check_action_stability(_Rollout(err), action, margin=1e-3, alpha=0.01,
                                  horizon_steps=horizon, floor=1e-6)


@pytest.mark.parametrize("horizon", [20, 21])
def test_a_diverging_period_two_loop_is_rejected_whatever_the_horizon(horizon: int) -> None:
    # the two-point estimate (V_H − V_0)/H is −0.05 at H = 20: the old test accepted it
    assert (_period_two(20) ** 2 - 1.0) / 20 < -0.01
    verdict = _verdict(_period_two, horizon)
    assert not verdict.ok and verdict.method == "lyapunov"
    assert "second half" in verdict.reason or "E[ΔV" in verdict.reason


def test_a_trajectory_that_turns_back_up_late_is_rejected() -> None:
    v = np.array([_late(t) ** 2 for t in range(21)])
    assert v[-1] < v[0] and (v[-1] - v[0]) / 20 < -0.01 * v[0]  # fools the two-point test
    verdict = _verdict(_late, 20)
    assert not verdict.ok
    assert verdict.reason.startswith("V grows in the second half")


def test_a_decaying_oscillation_is_accepted() -> None:
    verdict = _verdict(lambda t: 0.85 ** t * math.cos(0.6 * t), 20)
    assert verdict.ok and verdict.method == "lyapunov"
    # E[ΔV] is the least-squares slope of V over every step
    v = np.array([(0.85 ** t * math.cos(0.6 * t)) ** 2 for t in range(21)])
    np.testing.assert_allclose(verdict.value, np.polyfit(np.arange(21), v, 1)[0], rtol=1e-12)


def test_the_floor_still_accepts_noise_near_the_reference() -> None:
    rng = np.random.default_rng(0)
    v = 1e-4 * rng.random(21)
    assert lyapunov_decrease(v, 0.01, floor=0.0025).method == "lyapunov-floor"
