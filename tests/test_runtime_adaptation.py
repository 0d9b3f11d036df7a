"""Warm-up in seconds, per-module trust, compensated modules and ablation switches.

The MAPE-K loop against the fake live system of test_runtime_fakes: each test
checks one runtime setting by what the loop logs and does.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_runtime_fakes import FakeSystem, high, make_arch, run_loop

from archself.runtime import MapeK, explain

STABLE = [[-1.0, 0.0], [0.0, -2.0]]
UNSTABLE = [[0.5, 0.0], [0.0, -2.0]]
LIN = {"base": STABLE, "alt_est": STABLE, "alt_ctl": STABLE, "bad": UNSTABLE, "heavy": STABLE}


def test_warmup_is_declared_in_seconds():
    arch = make_arch(warmup_s=4.5)
    loop = MapeK(arch)
    switches = run_loop(loop, FakeSystem(arch, high("est_a", "innov"), linearizations=LIN), 10.0)
    assert [d.phase for d in loop.decisions[:6]] == ["warmup"] * 5 + ["adapt"]
    assert [s["t_s"] for s in switches] == [pytest.approx(6.0)]  # first cycle at 1 s + 4.5 s


def test_deprecated_warmup_steps_still_counts_cycles():
    arch = make_arch(warmup_steps=3)
    assert arch.runtime.warmup_time_s == pytest.approx(3.0)
    loop = MapeK(arch)
    switches = run_loop(loop, FakeSystem(arch, high("est_a", "innov"), linearizations=LIN), 6.0)
    assert [s["t_s"] for s in switches] == [pytest.approx(4.0)]


def test_a_residual_counts_only_once_its_filter_is_trusted():
    arch = make_arch(min_confidence=0.5, trust_at_start=False)
    arch.modules["est_a"].residual.smoothing_s = 2.0  # trusted after 2·ln 2 = 1.39 s of samples
    loop = MapeK(arch)
    run_loop(loop, FakeSystem(arch, high("est_a", "innov", 5.0), linearizations=LIN), 3.0)
    r = [d.r["est_a"] for d in loop.decisions[:2]]
    assert r[0] == 0.0 and r[1] > 0.0  # 1 s of samples: not trusted; 2 s: trusted
    assert loop.decisions[0].candidates == [] and "est_a" in loop.decisions[1].candidates
    # min_confidence 0: every sample counts at once (the paper's loop)
    arch0 = make_arch(min_confidence=0.0)
    arch0.modules["est_a"].residual.smoothing_s = 2.0
    loop0 = MapeK(arch0)
    run_loop(loop0, FakeSystem(arch0, high("est_a", "innov", 5.0), linearizations=LIN), 1.0)
    assert loop0.decisions[0].r["est_a"] > 0.0


def test_filters_running_since_the_start_count_at_once_restarted_ones_wait():
    arch = make_arch(min_confidence=0.5, trust_at_start=True)
    for m in ("est_a", "est_b"):
        arch.modules[m].residual.smoothing_s = 2.0  # settled after 2·ln 2 = 1.39 s

    def both_high(t, configuration):
        return {"est_a": {"innov": 5.0}, "est_b": {"innov": 5.0}}

    loop = MapeK(arch)
    switches = run_loop(loop, FakeSystem(arch, both_high, linearizations=LIN), 4.0)
    d = loop.decisions
    # est_a's filter started with the run: one sample (gain 1 − e^−0.5) already counts,
    # r = (5·0.393 − 0.1)/0.1 = 18.7, and the loop acts in the first cycle
    np.testing.assert_allclose(d[0].r["est_a"], (5.0 * (1 - np.exp(-0.5)) - 0.1) / 0.1,
                               rtol=1e-9)
    assert [(s["t_s"], s["to"]) for s in switches][:1] == [(pytest.approx(1.0), "alt_est")]
    # est_b's filter starts at the switch (a hand-over): 1 s of samples is not trusted, 2 s is
    assert d[1].configuration == "alt_est" and d[1].r["est_b"] == 0.0
    assert d[2].r["est_b"] > 0.0


def _act_fault(arch):
    loop = MapeK(arch)
    system = FakeSystem(arch, high("act", "cmd_err"), linearizations=LIN)
    switches = run_loop(loop, system, 4.0)
    return loop, system, switches


def test_a_compensated_module_keeps_its_own_z_but_stops_propagating():
    loop, system, switches = _act_fault(make_arch())
    assert [(s["to"], s["module"]) for s in switches] == [("alt_ctl", "act")]
    before, after = loop.decisions[0], loop.decisions[-1]
    assert before.configuration == "base" and after.configuration == "alt_ctl"
    r_act = after.r["act"]
    assert r_act > 0
    # before: act's residual reaches src through act -> src (weight 0.3)
    assert before.z["src"] > 0.25 * before.r["act"]
    # after: act is compensated (swap_ctl applies only in base): own z, nothing downstream
    assert after.compensated == ["act"]
    np.testing.assert_allclose(after.z["act"], r_act, rtol=1e-12)
    assert after.z["src"] == pytest.approx(after.r["src"], abs=1e-12)
    assert "compensated (own z only" in explain(loop.decisions)
    # the compensation is gone when an action keyed to act applies again (back in base)
    system.apply_configuration("base")
    loop(system)
    assert loop.decisions[-1].compensated == [] and loop.decisions[-1].z["src"] > 0


def test_isolation_can_be_switched_off():
    loop, _, _ = _act_fault(make_arch(isolate_compensated=False))
    after = loop.decisions[-1]
    assert after.compensated == [] and after.z["src"] > 0.25 * after.r["act"]


def test_ablation_without_propagation_gives_z_equal_r():
    arch = make_arch(ablation={"propagation": False})
    loop = MapeK(arch)
    run_loop(loop, FakeSystem(arch, high("act", "cmd_err"), linearizations=LIN), 3.0)
    for d in loop.decisions:
        assert dict(d.z.items()) == dict(d.r.items())


def test_ablation_without_stability_filter_takes_the_unstable_action():
    for on, chosen in ((True, "swap_est"), (False, "unsafe")):
        arch = make_arch(ablation={"stability": on})
        loop = MapeK(arch)
        run_loop(loop, FakeSystem(arch, high("est_a", "innov"), linearizations=LIN), 1.0)
        assert loop.decisions[0].chosen["action"] == chosen
        ev = {e.action: e for e in loop.decisions[0].evaluations}
        assert (ev["unsafe"].rejected == "unstable") is on
        if not on:
            assert ev["unsafe"].stability["method"] == "off"


def test_ablation_without_dwell_allows_back_to_back_switches():
    def signals(t, conf):  # est_a bad in base, est_b bad in alt_est: ping-pong
        return {"est_a": {"innov": 1.0}, "est_b": {"innov": 1.0}}

    for dwell, n in ((True, 1), (False, 3)):
        arch = make_arch(ablation={"dwell": dwell}, dwell_s=10.0)
        arch.actions = [a for a in arch.actions if a.id in ("swap_est", "back_est")]
        loop = MapeK(arch)
        switches = run_loop(loop, FakeSystem(arch, signals, linearizations=LIN), 3.0)
        assert len(switches) == n
