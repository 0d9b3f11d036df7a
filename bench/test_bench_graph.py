"""Influence z = (I − Wᵀ)⁻¹ r on generated DAGs (n = 10^2 … 10^5), one MAPE-K cycle at 10^4."""

from __future__ import annotations

import pytest

from conftest import generated_w

SIZES = [100, 1_000, 10_000, 100_000]


@pytest.mark.parametrize("n", SIZES)
def test_z_reused_factorization(benchmark, n: int, rng) -> None:
    from archself.runtime.influence import InfluenceSolver

    W = generated_w(n)
    solver = InfluenceSolver()
    solver.set_matrix(W, key="w")
    r = rng.random(n)

    def step():
        solver.set_matrix(W, key="w")  # what the loop does each cycle: a no-op while W is unchanged
        return solver.solve(r)

    benchmark.pedantic(step, rounds=20, iterations=1, warmup_rounds=1)
    assert solver.factorizations == 1


@pytest.mark.parametrize("n", SIZES)
def test_z_including_factorization(benchmark, n: int, rng) -> None:
    from archself.runtime.influence import InfluenceSolver

    W = generated_w(n)
    r = rng.random(n)

    def step():
        solver = InfluenceSolver()
        solver.set_matrix(W, key="w")
        return solver.solve(r)

    benchmark.pedantic(step, rounds=5 if n >= 100_000 else 10, iterations=1)


@pytest.fixture(scope="module")
def big_system():
    from archself.model.generate import generate_architecture
    from archself.model.loader import load_text
    from archself.runtime import MapeK
    from archself.system.live import compile_system

    arch = load_text(generate_architecture(10_000, seed=1)).arch
    system = compile_system(arch, arch.initial_configuration(), seed=0)
    system.step()
    loop = MapeK(arch)
    loop(system)  # first cycle factorizes
    return system, loop


def test_mapek_cycle_10k(benchmark, big_system) -> None:
    system, loop = big_system
    benchmark.pedantic(loop, args=(system,), rounds=10, iterations=1)
    assert loop.knowledge.solver.factorizations == 1


def test_mapek_cycle_10k_profile(big_system) -> None:
    """Where one cycle's time goes (printed with -s; not a benchmark): best of 10 each."""
    import time

    system, loop = big_system
    k = loop.knowledge

    def best(fn) -> float:
        times = []
        for _ in range(10):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return 1e3 * min(times)

    obs = loop.monitor.observe(system, k.active)
    parts = {
        "cycle": best(lambda: loop(system)),
        "monitor": best(lambda: loop.monitor.observe(system, k.active)),
        "  of which system.local_signals()": best(system.local_signals),
        "  of which system.available()": best(system.available),
        "analyze (z)": best(lambda: k.influence(obs.r)),
        "knowledge sync": best(lambda: k.sync(system)),
    }
    print("\n" + "\n".join(f"{name:36s} {ms:7.2f} ms" for name, ms in parts.items()))
