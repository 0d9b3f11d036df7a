"""Semantic rules added after an audit: declared parameters, complete configurations, ρ(W)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from archself import registry
from archself.check import check, spectrum_summary
from archself.errors import RegistryError
from archself.model.loader import load_text
from archself.modules.base import Param, RuntimeModule
from archself_diffdrive.physical import Imu
from archself_process.control import LevelObserver

from conftest import DIFFDRIVE, FIXTURES

MINIMAL = (FIXTURES / "valid" / "minimal.yaml").read_text(encoding="utf-8")
MOTOR = (DIFFDRIVE.parent / "motor_drive.yaml").read_text(encoding="utf-8")


def _findings(text: str, code: str | None = None) -> list[str]:
    return [str(f) for f in check(load_text(text, "t.yaml")) if code in (None, f.code)]


# --------------------------------------------------------------------------- parameters
def test_misspelt_parameter_is_an_error_with_a_suggestion() -> None:
    text = DIFFDRIVE.read_text(encoding="utf-8").replace("noise_rad_s:", "noise_rads:", 1)
    (msg,) = _findings(text, "parameter")
    assert "modules.encoders.params.noise_rads" in msg and ": error: " in msg
    assert "has no parameter 'noise_rads'; did you mean 'noise_rad_s'?" in msg


def test_unknown_parameter_without_a_close_match_lists_what_the_type_takes() -> None:
    text = MINIMAL.replace("type: sensor.imu}", "type: sensor.imu, params: {zz: {value: 1}}}")
    (msg,) = _findings(text, "parameter")
    assert msg.startswith("t.yaml:10:") and "it takes: noise_rad, bias_rad" in msg


def test_every_built_in_type_declares_its_parameters() -> None:
    shipped = [key for key in registry.known_types()
               if registry.get(key).__module__.startswith("archself_")]
    assert {"generic.relay", "plant.tank", "sensor.imu"} <= set(shipped)
    undeclared = [key for key in shipped if registry.get(key).parameters is None]
    assert undeclared == []


def test_a_missing_required_parameter_is_a_located_error() -> None:
    class NeedyImu(Imu):
        parameters = {"noise_rad": Param(unit="rad", doc="noise"), "bias_rad": Param(0.0)}

    registry.add("test.needy_imu", NeedyImu)
    try:
        text = MINIMAL.replace("type: sensor.imu}", "type: test.needy_imu}")
        (msg,) = _findings(text, "parameter")
        assert msg.startswith("t.yaml:10:") and ": error: modules.compass" in msg
        assert "type 'test.needy_imu' needs parameter 'noise_rad'" in msg
        given = text.replace("type: test.needy_imu}",
                             "type: test.needy_imu, params: {noise_rad: {value: 0.01}}}")
        assert _findings(given, "parameter") == []
    finally:
        registry.unregister("test.needy_imu")


def test_set_params_re_runs_configure() -> None:
    obs = LevelObserver("o", {"correction_gain": 0.02}, np.random.default_rng(0))
    assert (obs.handover_gain, obs.monitor.window_s) == (pytest.approx(0.1), 20.0)
    obs.set_params({"correction_gain": 0.04, "innovation_window_s": 30.0})
    assert obs.params["correction_gain"] == 0.04
    assert (obs.handover_gain, obs.monitor.window_s) == (pytest.approx(0.2), 30.0)


def test_a_type_that_declares_nothing_is_not_checked() -> None:
    class Undeclared(Imu):
        parameters = None

    registry.add("test.undeclared_imu", Undeclared)
    try:
        text = MINIMAL.replace(
            "type: sensor.imu}", "type: test.undeclared_imu, params: {anything: {value: 1}}}"
        )
        assert _findings(text, "parameter") == []
    finally:
        registry.unregister("test.undeclared_imu")


# --------------------------------------------------------------------------- configurations
def test_configuration_without_the_objective_modules_is_an_error() -> None:
    text = DIFFDRIVE.read_text(encoding="utf-8").replace(
        "configurations:\n", "configurations:\n  a0: {modules: [planner, kinematic_model]}\n", 1
    )
    msgs = _findings(text, "incomplete")
    assert any("configuration 'a0' lacks 'chassis', which runtime.objective.actual reads" in m
               and ": error: " in m for m in msgs), msgs
    assert any("'a0' has no module of role 'actuator', 'controller', 'estimator', 'plant', "
               "'sensor'" in m and ": warning: " in m for m in msgs), msgs


def test_an_empty_objective_component_list_is_a_located_error() -> None:
    # components: [] validated and J was 0 at every step (max_error 0.0 whatever happened)
    text = MINIMAL.replace("components: [0, 1]", "components: []")
    (msg,) = _findings(text, "objective")
    assert msg.startswith("t.yaml:42:73:") and ": error: runtime.objective.components:" in msg
    assert "expected at least one component" in msg


def test_a_parameter_of_the_wrong_kind_is_a_located_error() -> None:
    # a string for a number validated; simulate failed building the module, unlocated
    text = MINIMAL.replace("{value: 0.5, min: 0.1, max: 2.0, unit: m/s}",
                           "{value: fast, unit: m/s}")
    (msg,) = _findings(text, "parameter")
    assert msg.startswith("t.yaml:15:26:") and "modules.path.params.speed_mps.value" in msg
    assert 'expected a number (or a list of numbers), got string "fast"' in msg
    text = MINIMAL.replace("{value: left, choices: [left, right]}", "{value: 1}")
    (msg,) = _findings(text, "parameter")
    assert "modules.left.params.side.value: expected a string, got number" in msg


def test_an_action_setting_a_value_of_the_wrong_kind_is_a_located_error() -> None:
    text = MOTOR.replace("set: {kp: 1.6, ki: 1.6}", "set: {kp: high, ki: 1.6}")
    (msg,) = _findings(text, "action")
    assert ": error: actions[6].set.kp: new value: expected a number" in msg
    assert 'got string "high"' in msg


def test_action_on_a_module_inactive_where_it_applies_is_a_warning() -> None:
    text = MINIMAL.replace(
        "scenarios:",
        "  spare:\n    modules: [body, left, right, encoders, path, dead_reckoning, control,"
        " kinematics]\nactions:\n  - {id: tune, module: compass, kind: parameter_update,"
        " set: {noise_rad: 0.01}, applies_in: [spare], cost: 0.1,"
        " improvement: {method: sensitivity, delta_theta: -0.5}}\nscenarios:",
    )
    text = text.replace("compass: {kind: physical, type: sensor.imu}",
                        "compass: {kind: physical, type: sensor.imu,"
                        " params: {noise_rad: {value: 0.005}}}")
    msgs = _findings(text, "action")
    assert len(msgs) == 1 and ": warning: actions[0].applies_in[0]: " in msgs[0]
    assert "'compass' is not active in configuration 'spare'" in msgs[0]


# --------------------------------------------------------------------------- ρ(W)
@pytest.mark.parametrize("n", [2, 3, 5, 8, 16])
def test_spectrum_matches_numpy_eigenvalues(n: int) -> None:
    rng = np.random.default_rng(n)
    names = [f"m{i}" for i in range(n)]
    for _ in range(50):
        w = rng.random((n, n)) * (rng.random((n, n)) < 0.5) * rng.random()
        np.fill_diagonal(w, 0.0)  # self-loops are the self-loop rule's
        if rng.random() < 0.2:
            w[0, 1] = -w[0, 1]  # a negative weight (reported by the weight rule) still counts
        edges = [(names[j], names[i], w[j, i]) for j, i in zip(*np.nonzero(w), strict=True)]
        lam = np.linalg.eigvals(w)
        rho, singular = spectrum_summary(names, edges)
        assert rho == pytest.approx(float(np.max(np.abs(lam))), rel=1e-9, abs=1e-9)
        assert singular == bool(np.any(np.abs(lam - 1.0) < 1e-9))


def test_spectrum_of_a_large_graph_by_components() -> None:
    """Above 400 modules ρ comes per strong component; a chain with one 3-cycle of gain 0.576."""
    n = 1000
    names = [f"m{i}" for i in range(n)]
    edges = [(names[i], names[i + 1], 0.9) for i in range(n - 1)]
    edges += [(names[502], names[500], 0.8 * 0.8 / 0.9)]  # 500 -> 501 -> 502 -> 500
    rho, singular = spectrum_summary(names, edges)
    assert rho == pytest.approx((0.9 * 0.9 * 0.8 * 0.8 / 0.9) ** (1 / 3), rel=1e-9)
    assert not singular


def test_spectrum_near_one_still_detects_a_singular_block() -> None:
    rho, singular = spectrum_summary(["a", "b"], [("a", "b", 1.0), ("b", "a", 1.0)])
    assert rho == pytest.approx(1.0) and singular


def _weights(n: int, edges: list[tuple[int, int, float]]) -> np.ndarray:
    W = np.zeros((n, n))
    for j, i, w in edges:
        W[j, i] += w
    return W


@pytest.mark.parametrize(("edges", "singular"), [
    ([(0, 1, 0.5), (1, 2, 0.4), (2, 0, 0.3)], False),
    ([(0, 1, 1.0), (1, 0, 1.0)], True),  # W has the eigenvalue 1
    ([(0, 1, 1.0), (1, 0, 1.0 - 1e-14)], True),  # near-singular: a pivot ~1e-14
    ([(0, 1, 1.0), (1, 0, 1.0 - 1e-9)], False),  # close, but a pivot 1e-9 is no rounding
    ([(0, 1, 1e9), (1, 2, 0.2)], True),  # ρ = 0, a pivot 5e-9 of 1e9: singular in floats
])
def test_singular_verdict_is_the_same_dense_in_numpy_and_sparse_in_scipy(
    edges: list[tuple[int, int, float]], singular: bool
) -> None:
    """One rule (singular_pivots), two solvers by size: numpy's LU up to DENSE_MAX
    modules, SuperLU above; the runtime's LAPACK LU refuses the same matrices."""
    import scipy.linalg
    import scipy.sparse

    from archself.runtime.influence import InfluenceSolver, is_singular, lu_pivots

    W = _weights(3, edges)
    assert is_singular(W) is singular
    assert is_singular(scipy.sparse.csr_matrix(W), dense_max=0) is singular
    refused = False
    try:
        InfluenceSolver().set_matrix(W)
    except np.linalg.LinAlgError:
        refused = True
    assert refused is singular
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
        lu, _ = scipy.linalg.lu_factor(np.eye(3) - W.T)
    np.testing.assert_allclose(lu_pivots(np.eye(3) - W.T), np.abs(np.diag(lu)),
                               rtol=1e-12, atol=1e-300)


def test_numpy_lu_pivots_are_lapacks_on_random_matrices() -> None:
    import scipy.linalg

    from archself.runtime.influence import lu_pivots

    rng = np.random.default_rng(7)
    for n in (1, 2, 5, 17, 60):
        M = np.eye(n) - rng.random((n, n)) * (rng.random((n, n)) < 0.3)
        lu, _ = scipy.linalg.lu_factor(M)
        np.testing.assert_allclose(lu_pivots(M), np.abs(np.diag(lu)), rtol=1e-9)


def test_spectrum_of_a_small_graph_imports_no_scipy() -> None:
    import subprocess
    import sys

    code = ("import sys\n"
            "from archself.check.rules import spectrum_summary\n"
            "print(spectrum_summary(['a', 'b'], [('a', 'b', 1.0), ('b', 'a', 1.0)]),\n"
            "      any(m.startswith('scipy') for m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.stdout.split() == ["(1.0,", "True)", "False"], out.stderr[-2000:]


def test_the_data_flow_checks_find_what_scipy_finds() -> None:
    """Connected components (validate's ``incomplete``) and strong components (the
    algebraic loop) in plain Python, against scipy.sparse.csgraph on random graphs."""
    import scipy.sparse
    import scipy.sparse.csgraph

    from archself.check.rules import _components
    from archself.system.dataflow import strong_components

    rng = np.random.default_rng(3)
    for _ in range(100):
        n = int(rng.integers(1, 25))
        pairs = [(int(a), int(b)) for a, b in rng.integers(0, n, (int(rng.integers(0, 2 * n)), 2))]
        names = [f"m{i:02d}" for i in range(n)]
        links = [(names[a], names[b]) for a, b in pairs]
        g = scipy.sparse.coo_matrix(([1.0] * len(pairs), ([a for a, _ in pairs],
                                     [b for _, b in pairs])), shape=(n, n))
        for strong in (False, True):
            _, want = scipy.sparse.csgraph.connected_components(
                g, directed=strong, connection="strong")
            if strong:
                label = strong_components(names, links)
                got = [label[m] for m in names]
            else:
                parts = _components(names, links)
                got = [next(k for k, p in enumerate(parts) if m in p) for m in names]
            same = np.equal.outer(got, got)
            np.testing.assert_array_equal(same, np.equal.outer(want, want))


# --------------------------------------------------------------------------- registry
def test_registering_a_type_twice_is_an_error() -> None:
    class First(RuntimeModule):
        pass

    class Second(RuntimeModule):
        pass

    registry.add("test.twice", First)
    try:
        with pytest.raises(RegistryError, match="registered twice"):
            registry.add("test.twice", Second)
        with pytest.raises(RegistryError, match="registered twice"):
            registry.register("test.twice")(Second)
        assert registry.get("test.twice") is First
    finally:
        registry.unregister("test.twice")


def test_a_plugin_cannot_take_a_built_in_type_key() -> None:
    class Impostor(RuntimeModule):
        pass

    with pytest.raises(RegistryError, match="'sensor.imu' is registered twice"):
        registry.add("sensor.imu", Impostor)
    assert registry.get("sensor.imu") is Imu


def test_unknown_type_message_does_not_depend_on_other_plugins() -> None:
    text = MINIMAL.replace("type: sensor.imu}", "type: sensor.imu_v2}")
    before = _findings(text, "unknown-type")

    class Other(RuntimeModule):
        pass

    registry.add("zz_thirdparty.other", Other)
    try:
        assert _findings(text, "unknown-type") == before
    finally:
        registry.unregister("zz_thirdparty.other")
    assert "sensor.* types: sensor.encoders" in before[0] and "zz_thirdparty" not in before[0]


def test_an_i_minus_w_singular_in_floating_point_is_refused_as_the_runtime_refuses_it() -> None:
    # ρ(W) < 1, so validate said ok; the runtime's LU of I − Wᵀ (condition ~1e18) refused it
    # and simulate stopped with `internal error: LinAlgError`, exit 3
    from archself.runtime.mapek import MapeK
    from archself.sim.run import simulate

    edge = "{from: speed_ref.reference, to: pi.reference, weight: 0.2}"
    text = MOTOR.replace(edge, edge.replace("0.2}", "1e9}"))
    (msg,) = _findings(text, "singular")
    assert ": error: edges: I − Wᵀ is singular in floating point" in msg and "1e+09" in msg
    arch = load_text(text, "t.yaml").arch
    with pytest.raises(np.linalg.LinAlgError):
        simulate(arch, "drive_loss", seed=1, adapt=MapeK(arch))
