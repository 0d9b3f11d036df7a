"""Closed-loop A of a configuration from its modules' linear models, wired by the edges."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from archself.linear.wiring import ClosedLoop, Wire, interconnect, loop_modules, modal_form
from archself.model.loader import load_architecture
from archself.modules.base import LinearModel
from archself.runtime import MapeK
from archself.runtime.stability import eigenvalue_margin
from archself.sim.run import simulate
from archself.system.live import compile_system

from conftest import FIXTURES, ROOT

SWAP = FIXTURES / "valid" / "actuator_swap.yaml"


def _arch(noise: float | None = None):
    arch = load_architecture(SWAP).arch
    if noise is not None:
        for name in ("meter", "probe"):
            arch.modules[name].params["noise"].value = noise
    return arch


def _states(system, actuator: str) -> np.ndarray:
    """The loop's state in the order of ``closed_loop().loop.labels``."""
    mods = system.modules
    return np.array([mods["plant"].x[0], mods["plant"].u[0], mods["pi"].integral, mods[actuator].x])


@pytest.mark.parametrize("conf, actuator", [("normal", "main"), ("hot", "backup_hot")])
def test_wired_model_reproduces_the_executor_step_by_step(conf: str, actuator: str) -> None:
    # with a constant reference the increments of the state follow δx⁺ = A δx exactly
    system = compile_system(_arch(noise=0.0), conf, seed=1)
    for _ in range(3):
        system.step()
    cl = system.closed_loop()
    assert cl.blocks == []
    assert cl.loop is not None
    assert cl.loop.labels == ["plant.x0", "plant.u_prev0", "pi.I", f"{actuator}.lag"]
    x = [_states(system, actuator)]
    for _ in range(6):
        system.step()
        x.append(_states(system, actuator))
    d = np.diff(np.array(x), axis=0)
    assert_allclose(d[1:], d[:-1] @ cl.loop.A.T, rtol=1e-9, atol=1e-12)


def test_swapping_in_a_destabilizing_actuator_changes_the_verdict() -> None:
    system = compile_system(_arch(), "normal", seed=1)
    system.step()
    margin = 0.001
    ok = eigenvalue_margin(system.linearization("normal"), margin)
    hot = eigenvalue_margin(system.linearization("hot"), margin)
    assert ok.ok and ok.value is not None and ok.value < -0.5
    assert not hot.ok and hot.value is not None and hot.value > 10.0
    # the discrete eigenvalue behind it: |λ| > 1 per 0.1 s step
    worst = system.closed_loop("hot").worst_mode()
    assert worst is not None
    assert_allclose(worst[0], np.log(worst[1]) / 0.1)
    assert worst[1] > 4.0
    assert {m for m, _ in worst[2]} == {"plant", "pi", "backup_hot"}
    # the same configuration with a right scale on that actuator is stable again
    system.set_params("backup_hot", {"scale": 1.0})
    assert eigenvalue_margin(system.linearization("hot"), margin).ok


def test_run_rejects_the_unstable_swap_and_takes_the_stable_one() -> None:
    arch = _arch()
    loop = MapeK(arch)
    res = simulate(arch, "main_loss", seed=1, adapt=loop)
    assert [(s["from"], s["to"], s["action"]) for s in res.switches] == [
        ("normal", "slow", "use_spare")
    ]
    evals = [e for d in loop.decisions for e in d.evaluations or []]
    hot = [e for e in evals if e.action == "use_hot"]
    assert hot and all(e.rejected == "unstable" for e in hot)
    assert hot[0].stability["method"] == "eigenvalue" and hot[0].stability["value"] > 10.0


def test_modules_without_models_keep_the_block_diagonal() -> None:
    # the process plant's types give only linearization(): A is their block diagonal
    arch = load_architecture(ROOT / "architectures" / "process_plant.yaml").arch
    system = compile_system(arch, seed=0)
    for _ in range(5):
        system.step()
    blocks = [m.linearization() for m in system.modules.values()]
    blocks = [np.atleast_2d(b) for b in blocks if b is not None]
    assert blocks
    A = system.linearization()
    k = 0
    for b in blocks:
        n = b.shape[0]
        assert_allclose(A[k : k + n, k : k + n], b)
        k += n
    assert A.shape == (k, k)
    assert system.closed_loop().loop is None


def test_a_latency_becomes_delay_states() -> None:
    # x⁺ = 0.9 x + u, u = −k·y delayed one step: z² − 0.9 z + k = 0
    plant = LinearModel([[0.9]], [[1.0]], [[1.0]], [[0.0]], [("u", 1)], [("y", 1)], dt=0.1)
    k = 0.5
    gain = LinearModel([], [], [], [[-k]], [("y", 1)], [("u", 1)], dt=0.1)
    cl = interconnect(
        {"p": plant, "k": gain}, [Wire("p", "k", "y", delay=1), Wire("k", "p", "u")], 0.1
    )
    assert cl.labels == ["p.x0", "p→k.y[t-1]"]
    lam = np.sort_complex(np.linalg.eigvals(cl.A))
    assert_allclose(lam, np.sort_complex(np.roots([1.0, -0.9, k])))


def test_a_continuous_model_is_held_over_the_step() -> None:
    plant = LinearModel([[-1.0]], [[1.0]], [[1.0]], [[0.0]], [("u", 1)], [("y", 1)])
    gain = LinearModel([], [], [], [[-2.0]], [("y", 1)], [("u", 1)], dt=0.1)
    cl = interconnect({"p": plant, "k": gain}, [Wire("p", "k", "y"), Wire("k", "p", "u")], 0.1)
    ad, bd = np.exp(-0.1), 1.0 - np.exp(-0.1)
    assert_allclose(cl.A, [[ad - 2.0 * bd]])


def test_modal_form_keeps_the_continuous_equivalent_eigenvalues() -> None:
    rot = 0.95 * np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]])
    Ad = np.block([[rot, np.zeros((2, 1))], [np.zeros((1, 2)), np.array([[1.1]])]])
    lam = np.linalg.eigvals(modal_form(Ad, 0.1))
    assert_allclose(np.sort(lam.real), np.sort(np.log(np.abs(np.linalg.eigvals(Ad))) / 0.1))
    assert_allclose(np.sort(np.abs(lam.imag))[-1], 3.0)


def test_a_model_in_no_loop_gives_way_to_its_linearization() -> None:
    m = LinearModel([[1.0]], [[0.1]], [[1.0]], [[0.0]], [("y", 1)], [("u", 1)], dt=0.1)
    assert loop_modules({"pid": m}, []) == set()
    cl = ClosedLoop(None, [("pid", np.array([[-2.0]]))])
    assert_allclose(cl.matrix(), [[-2.0]])
    assert cl.worst_mode() == (-2.0, None, [("pid", 1.0)])


@pytest.mark.parametrize(
    "conf, actuator, kf", [("m1", "drive_a", "kf_tacho"), ("m4", "drive_b", "kf_encoder")]
)
def test_motor_drive_model_with_kalman_filter_reproduces_the_executor(
    conf: str, actuator: str, kf: str
) -> None:
    # motor, drive, voltage meter -> gain -> Kalman filter, speed sensor -> filter -> PI:
    # after a kick, the noise-free run follows δx⁺ = A δx (filter gain converged)
    arch = load_architecture(ROOT / "architectures" / "motor_drive.yaml").arch
    for name in ("tacho", "encoder", "volt_meter"):
        arch.modules[name].params["noise"].value = 0.0
    arch.modules["encoder"].params["resolution"].value = 0.0
    arch.modules["motor"].params["process_noise"].value = [0.0, 0.0]
    system = compile_system(arch, conf, seed=1)
    for _ in range(300):
        system.step()
    cl = system.closed_loop()
    assert cl.loop is not None and not cl.blocks
    assert cl.loop.labels == [
        "motor.x0",
        "motor.x1",
        "motor.u_prev0",
        f"{kf}.x_hat0",
        f"{kf}.x_hat1",
        "pi.I",
        f"{actuator}.lag",
    ]
    mods = system.modules
    mods["motor"].x[1] += 1.0

    def state() -> np.ndarray:
        return np.r_[
            mods["motor"].x, mods["motor"].u, mods[kf].x, mods["pi"].integral, mods[actuator].x
        ]

    x = [state()]
    for _ in range(8):
        system.step()
        x.append(state())
    d = np.diff(np.array(x), axis=0)
    assert np.abs(d).max() > 0.1
    assert_allclose(d[1:], d[:-1] @ cl.loop.A.T, rtol=1e-9, atol=1e-12)


def _chain_models(n: int, seed: int):
    """n one-state models in a ring of delays plus static (feed-through) gains between them."""
    rng = np.random.default_rng(seed)
    models, wires = {}, []
    for i in range(n):
        models[f"x{i}"] = LinearModel(
            [[rng.uniform(-0.9, 0.9)]], [[rng.uniform(0.1, 0.5)]], [[1.0]], [[0.0]],
            [("u", 1)], [("y", 1)], dt=0.1,
        )
        models[f"g{i}"] = LinearModel(  # a gain that passes y on at once (D ≠ 0)
            np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[rng.uniform(-1, 1)]],
            [("y", 1)], [("u", 1)], dt=0.1,
        )
        wires += [Wire(f"x{i}", f"g{i}", "y"), Wire(f"g{i}", f"x{(i + 1) % n}", "u")]
        if i % 7 == 3:  # a chord: strong components larger than one state
            wires.append(Wire(f"g{i}", f"x{(i + 5) % n}", "u"))
    return models, wires


@pytest.mark.parametrize("seed", [0, 1])
def test_a_large_loop_is_sparse_and_has_the_dense_eigenvalues(seed: int, monkeypatch) -> None:
    """Above DENSE_STATES states: sparse A, the same A and eigenvalues as the dense path."""
    import scipy.sparse

    import archself.linear.wiring as linear

    models, wires = _chain_models(450, seed)
    big = interconnect(models, wires, 0.1)
    assert scipy.sparse.issparse(big.A)
    monkeypatch.setattr(linear, "DENSE_STATES", 10**6)
    dense = interconnect(models, wires, 0.1)
    assert_allclose(big.A.toarray(), dense.A, atol=1e-12)
    lam_sparse = np.sort_complex(linear.eigenvalues(big.A))
    assert_allclose(lam_sparse, np.sort_complex(np.linalg.eigvals(dense.A)), atol=1e-9)
    worst_dense = eigenvalue_margin(modal_form(dense.A, 0.1), 0.01).value
    worst_sparse = eigenvalue_margin(modal_form(big.A, 0.1), 0.01).value
    assert worst_sparse == pytest.approx(worst_dense, abs=1e-9)
    assert scipy.sparse.issparse(ClosedLoop(big, []).matrix())
    mode_s, mode_d = ClosedLoop(big, []).worst_mode(), ClosedLoop(dense, []).worst_mode()
    assert mode_s is not None and mode_d is not None
    assert mode_s[0] == pytest.approx(mode_d[0], abs=1e-9)


def test_a_large_cascade_without_feedthrough_loops_is_triangular() -> None:
    """A 600-state cascade: every strong component is one state; λ = the diagonal."""
    import archself.linear.wiring as linear

    models = {
        f"x{i}": LinearModel([[0.5]], [[1.0]], [[1.0]], [[0.0]], [("y", 1)], [("y", 1)], dt=0.1)
        for i in range(600)
    }
    wires = [Wire(f"x{i}", f"x{i + 1}", "y") for i in range(599)]
    big = interconnect(models, wires, 0.1)
    assert_allclose(linear.eigenvalues(big.A), np.full(600, 0.5))
