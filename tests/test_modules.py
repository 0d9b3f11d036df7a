"""The built-in module library: declarations, LQR gain, EKF consistency, planner, faults."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.stats import chi2

from archself import registry
from archself.system.live import FAULT_KINDS, FaultInjector
from archself_diffdrive.controllers import AsymLqrController, LqrController, lqr_gain
from archself_diffdrive.estimators import Ekf, InnovationTrend, InnovationWindow, Odometry
from archself_diffdrive.kinematics import arc_step, error_dynamics
from archself_diffdrive.models import (
    Actuation,
    ActuatorModel,
    DiffDriveDynamicsModel,
    DiffDriveKinematicsModel,
    Dynamics,
    Kinematics,
)
from archself_diffdrive.physical import DiffDrivePlant, Gps, Imu, WheelActuator, WheelEncoders
from archself_diffdrive.planner import SplinePlanner

from conftest import DIFFDRIVE

KEYS = [
    "plant.diffdrive",
    "actuator.wheel",
    "sensor.encoders",
    "sensor.imu",
    "sensor.gps",
    "planner.spline",
    "estimator.odometry",
    "estimator.ekf",
    "controller.lqr",
    "controller.asym_lqr",
    "model.diffdrive_kinematics",
    "model.diffdrive_dynamics",
    "model.actuator",
]


def rng(seed=0):
    return np.random.default_rng(seed)


def test_import_is_light():
    code = (
        "import archself.modules, sys; "
        "heavy = [m for m in ('control', 'filterpy', 'matplotlib') if m in sys.modules]; "
        "assert not heavy, heavy"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("key", KEYS)
def test_declarations(key):
    cls = registry.get(key)
    assert cls.type_key == key
    assert cls.outputs, "every module publishes something"
    assert set(cls.fault_kinds) <= FAULT_KINDS
    assert not set(cls.inputs) & set(cls.optional_inputs)
    if cls.role == "model":
        assert cls.direct_feedthrough is False and not cls.inputs


@pytest.mark.parametrize("key", KEYS)
def test_parameters_declared_once(key):
    """Every type declares each parameter it reads (default, unit, doc); a module built
    from the required ones alone holds exactly the declared names, defaults filled in."""
    cls = registry.get(key)
    assert cls.parameters, key
    for name, p in cls.parameters.items():
        assert p.doc, (key, name)
        assert isinstance(p.unit, str)
    required = {k: [[0, 0], [10, 0]] for k, p in cls.parameters.items() if p.required}
    m = cls("m", required, rng())
    assert set(m.params) == set(cls.parameters)
    for name, p in cls.parameters.items():
        if not p.required:
            assert m.params[name] == p.default, (key, name)


@pytest.mark.parametrize(
    "node, model", [(DiffDriveKinematicsModel, Kinematics), (DiffDriveDynamicsModel, Dynamics),
                    (ActuatorModel, Actuation)]
)
def test_model_parameters_are_the_dataclass_fields(node, model):
    fields = dataclasses.fields(model)
    assert list(node.parameters) == [f.name for f in fields]
    assert all(node.parameters[f.name].default == f.default for f in fields)
    assert all(node.parameters[f.name].unit == f.metadata["unit"] for f in fields)
    m = node("m", {}, rng())
    (obj,) = m.output(0.0).values()
    assert obj == model()
    first = fields[0].name
    m.set_params({first: 7.0})
    (obj,) = m.output(0.0).values()
    assert getattr(obj, first) == 7.0 and obj == dataclasses.replace(model(), **{first: 7.0})


def test_set_params_reconfigures_sensors_and_estimators():
    gps = Gps("gps", {"rate_hz": 1.0, "noise_m": 0.0}, rng())
    pose = {"pose": np.array([1.0, 2.0, 0.0])}
    n1 = sum(gps.step(k * 0.05, 0.05, pose)["position"] is not None for k in range(200))
    gps.set_params({"rate_hz": 4.0, "noise_m": 0.2})
    n4 = sum(gps.step(10 + k * 0.05, 0.05, pose)["position"] is not None for k in range(200))
    assert (n1, n4) == (10, 40)
    assert gps.noise_levels == {"position": 0.2} and gps.max_silence_s == pytest.approx(0.625)
    enc = WheelEncoders("enc", {}, rng())
    enc.set_params({"noise_rad_s": 0.0})
    assert_allclose(enc.step(0.0, 0.05, {"wheel_speeds": np.array([1.0, 2.0])})["encoder_speeds"],
                    [1.0, 2.0], rtol=0, atol=0)
    imu = Imu("imu", {"noise_rad": 0.0}, rng())
    imu.set_params({"bias_rad": 0.1})
    assert imu.step(0.0, 0.05, {"pose": np.zeros(3)})["heading"] == pytest.approx(0.1)
    plant = DiffDrivePlant("c", {"wheel_time_constant_s": 0.0}, rng())
    plant.set_params({"wheel_radius_m": 0.2})
    plant.step(0.0, 1.0, {"wheel_speed_left": 5.0, "wheel_speed_right": 5.0})
    assert_allclose(plant.output(1.0)["pose"], [1.0, 0.0, 0.0], atol=1e-12)  # 0.2 m × 5 rad/s
    for est in (Odometry("o", {}, rng()), Ekf("e", {}, rng())):
        assert est.monitor.window_s == 20.0
        est.set_params({"innovation_window_s": 5.0})
        assert est.monitor.window_s == 5.0
    w = WheelActuator("w", {"side": "left"}, rng())
    w.set_params({"side": "right"})
    assert w.step(0.0, 0.05, {"wheel_cmd": np.array([1.0, 2.0])}) == {"wheel_speed_right": 2.0}


def test_residual_signals_are_published():
    # every declared residual signal appears in local_signals (NaN before data)
    mods = [
        WheelActuator("w", {"side": "left"}, rng()),
        Odometry("o", {}, rng()),
        Ekf("e", {}, rng()),
        LqrController("c", {}, rng()),
    ]
    for m in mods:
        assert set(m.residual_signals) <= set(m.local_signals())


# ---------------------------------------------------------------- LQR
@pytest.mark.parametrize("v", [0.3, 0.5, 1.2])
@pytest.mark.parametrize("q", [(1.0, 0.001, 0.05), (2.0, 0.5, 1.0)])
def test_lqr_gain_closed_form(v, q):
    """Along: scalar integrator, K = √(q/r). Lateral: ė_y = v e_θ, ė_θ = u, a scaled
    double integrator with K = [√(q_y/r), √(q_θ/r + 2 v √(q_y/r))]."""
    r = (1.5, 0.7)
    K = lqr_gain(v, q, r)
    ky = math.sqrt(q[1] / r[1])
    expected = np.array(
        [
            [math.sqrt(q[0] / r[0]), 0.0, 0.0],
            [0.0, ky, math.sqrt(q[2] / r[1] + 2 * v * ky)],
        ]
    )
    assert_allclose(K, expected, rtol=1e-6, atol=1e-9)


@pytest.fixture
def design_cache(tmp_path, monkeypatch):
    """A fresh, empty design cache and memo (archself.linear.designs)."""
    from archself.linear import designs

    monkeypatch.setenv("ARCHSELF_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("ARCHSELF_CACHE", raising=False)
    monkeypatch.setattr(designs, "_MEMO", {})
    return tmp_path / "designs"


def _design_inputs():
    A, B = error_dynamics(0.7)
    return A, B, np.diag([1.0, 0.3, 0.05]), np.diag([1.5, 0.7])


def test_lqr_design_cache_hit_and_miss_give_the_same_gain_to_the_bit(design_cache) -> None:
    import control

    from archself.linear import designs

    want = np.asarray(control.lqr(*_design_inputs())[0], dtype=float)
    miss = designs.lqr(*_design_inputs())
    (entry,) = design_cache.glob("*.json")  # one entry, named by its key
    assert miss.tobytes() == want.tobytes() and not miss.flags.writeable
    assert designs.lqr(*_design_inputs()) is miss  # the in-process memo
    designs._MEMO.clear()
    hit = designs.lqr(*_design_inputs())  # read back from the file
    assert hit is not miss and hit.tobytes() == want.tobytes()
    # other inputs (here R) are another design and another entry
    A, B, Q, R = _design_inputs()
    other = designs.lqr(A, B, Q, 2.0 * R)
    assert len(list(design_cache.glob("*.json"))) == 2
    assert np.abs(other - want).max() > 1e-3
    assert entry.read_text().startswith('{"key": ')


def _block_designs(designs):
    """The blocks pack's designs: observer poles (a complex pair), a ZOH, a realization."""
    A = np.array([[0.0, 1.0], [-2.0, -0.3]])
    return {"place": designs.place(A.T, np.array([[1.0, 0.0]]).T,
                                   [complex(-2.0, 1.0), complex(-2.0, -1.0)]),
            "zoh A": designs.zoh(A, [[0.0], [1.0]], [[1.0, 0.0]], [[0.0]], 0.05)[0],
            "zoh B": designs.zoh(A, [[0.0], [1.0]], [[1.0, 0.0]], [[0.0]], 0.05)[1],
            **{f"tf {k}": v for k, v in designs.tf2ss([2.0], [1.0, 0.5, 3.0], 0.0).items()}}


def test_place_zoh_and_tf2ss_hit_and_miss_equal_python_control_to_the_bit(design_cache) -> None:
    """The blocks pack's per-run designs (observer gain, discretization, realization): a
    miss, the memo and a read-back entry all equal python-control's own result."""
    import control

    from archself.linear import designs

    A = np.array([[0.0, 1.0], [-2.0, -0.3]])
    sysd = control.c2d(control.ss(A, [[0.0], [1.0]], [[1.0, 0.0]], [[0.0]]), 0.05, method="zoh")
    tf = control.ss(control.tf([2.0], [1.0, 0.5, 3.0], 0.0))
    want = {"place": control.place(A.T, np.array([[1.0, 0.0]]).T,
                                   [complex(-2.0, 1.0), complex(-2.0, -1.0)]),
            "zoh A": sysd.A, "zoh B": sysd.B,
            "tf A": tf.A, "tf B": tf.B, "tf C": tf.C, "tf D": tf.D}
    miss = _block_designs(designs)
    assert len(list(design_cache.glob("*.json"))) == 3
    designs._MEMO.clear()
    hit = _block_designs(designs)
    for name, w in want.items():
        w = np.asarray(w, dtype=float)
        assert miss[name].tobytes() == w.tobytes() == hit[name].tobytes(), name
        assert hit[name] is not miss[name] and not hit[name].flags.writeable
    eig = np.linalg.eigvals(A - want["place"].T @ np.array([[1.0, 0.0]]))
    assert_allclose(sorted(eig, key=lambda z: z.imag), [-2.0 - 1.0j, -2.0 + 1.0j], atol=1e-9)


@pytest.mark.parametrize("damage", ["corrupt", "truncated", "foreign", "wrong shape",
                                    "not base64"])
def test_a_damaged_or_foreign_design_entry_is_ignored_and_rewritten(design_cache,
                                                                   damage) -> None:
    import base64
    import json

    from archself.linear import designs

    want = designs.lqr(*_design_inputs())
    (entry,) = design_cache.glob("*.json")
    good = json.loads(entry.read_text())
    nines = {"shape": [2, 3], "data": base64.b64encode(np.full(6, 9.0).tobytes()).decode()}
    bad = {"corrupt": "not json {",
           "truncated": entry.read_text()[:40],
           "foreign": json.dumps({**good, "key": "0" * 64, "arrays": {"gain": nines}}),
           "wrong shape": json.dumps({**good, "arrays": {"gain": {**good["arrays"]["gain"],
                                                                   "shape": [3, 2]}}}),
           "not base64": json.dumps({**good, "arrays": {"gain": {**nines, "data": "?!"}}}),
           }[damage]
    entry.write_text(bad)
    designs._MEMO.clear()
    got = designs.lqr(*_design_inputs())
    assert got.tobytes() == want.tobytes()
    assert json.loads(entry.read_text()) == good  # designed again and rewritten


def test_the_design_cache_can_be_switched_off_or_unwritable(design_cache, monkeypatch) -> None:
    from archself.linear import designs

    monkeypatch.setenv("ARCHSELF_CACHE", "off")
    assert designs.cache_dir() is None
    off = designs.lqr(*_design_inputs())
    assert not design_cache.exists()
    monkeypatch.delenv("ARCHSELF_CACHE")
    design_cache.parent.joinpath("file").write_text("")
    monkeypatch.setenv("ARCHSELF_CACHE_DIR", str(design_cache.parent / "file"))
    designs._MEMO.clear()
    assert designs.lqr(*_design_inputs()).tobytes() == off.tobytes()  # no error either


def test_a_run_with_cached_designs_imports_no_python_control_and_is_the_same(
    tmp_path,
) -> None:
    """Two processes with one design cache: the first designs (python-control, the
    spline path with scipy.interpolate), the second reads the gains and the path and
    imports neither; the traces are equal."""
    import os

    code = (
        "import sys\n"
        "import numpy as np\n"
        "from archself.sim.run import simulate\n"
        f"res = simulate({str(DIFFDRIVE)!r}, 'imu_drift', seed=2)\n"
        "sys.stdout.write(np.asarray(res.series['J'], dtype=float).tobytes().hex()\n"
        "                 + ' ' + str('control' in sys.modules)\n"
        "                 + ' ' + str('scipy.interpolate' in sys.modules))\n"
    )
    env = {**os.environ, "ARCHSELF_CACHE_DIR": str(tmp_path)}
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           env=env) for _ in range(2)]
    (j1, *imported1), (j2, *imported2) = (r.stdout.split() for r in runs)
    assert imported1 == ["True", "True"], runs[0].stderr[-2000:]
    assert imported2 == ["False", "False"], runs[1].stderr[-2000:]
    assert j1 == j2 and len(j1) > 1000


def test_a_fixed_run_with_cached_designs_imports_no_scipy(tmp_path) -> None:
    """A warm fixed diff-drive run needs no scipy: the gain and the spline path come from
    the design cache, the whole-loop A of a small loop is dense (numpy), and no sparse
    matrix is made (the first, cold process imports scipy to design them)."""
    import os

    code = (
        "import sys\n"
        "from archself.sim.run import simulate\n"
        f"simulate({str(DIFFDRIVE)!r}, 'nominal', seed=1)\n"
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'scipy', 'control'}))\n"
    )
    env = {**os.environ, "ARCHSELF_CACHE_DIR": str(tmp_path)}
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           env=env) for _ in range(2)]
    assert runs[0].stdout.split("\n")[-2] == "['control', 'scipy']", runs[0].stderr[-2000:]
    assert runs[1].stdout.split("\n")[-2] == "[]", runs[1].stderr[-2000:]


def test_the_spline_path_cache_gives_the_computed_table_to_the_bit(design_cache) -> None:
    """spline_path's miss (scipy), memo and file hit are the same arrays, bit for bit;
    another resolution is another entry; an entry of the wrong shape is made again."""
    import json

    from archself.linear import designs
    from archself_diffdrive.planner import _spline_table, path_points, spline_path

    wp = [[0, 0], [10, 5], [20, 0], [30, -5], [40, 0]]
    want = _spline_table(path_points(wp), 0.05)
    miss = spline_path(wp, 0.05)
    (entry,) = design_cache.glob("*.json")
    designs._MEMO.clear()
    hit = spline_path(wp, 0.05)
    for k in ("s", "x", "y", "theta", "kappa"):
        assert miss[k].tobytes() == want[k].tobytes() == hit[k].tobytes(), k
        assert not hit[k].flags.writeable
    assert miss["length"] == hit["length"] == float(want["length"]) > 40.0
    assert len(hit["s"]) == len(want["s"]) > 800
    spline_path(wp, 0.1)
    assert len(list(design_cache.glob("*.json"))) == 2
    good = json.loads(entry.read_text())
    short = {**good["arrays"]["x"], "shape": [3]}  # rows of unequal length
    entry.write_text(json.dumps({**good, "arrays": {**good["arrays"], "x": short}}))
    designs._MEMO.clear()
    assert spline_path(wp, 0.05)["x"].tobytes() == want["x"].tobytes()
    assert json.loads(entry.read_text()) == good


def test_lqr_linearization_is_stable_and_updates():
    c = LqrController(
        "lqr",
        {"q_along": 1.0, "q_lateral": 0.001, "q_heading": 0.05, "r_speed": 1.0, "r_turn": 1.0},
        rng(),
    )
    A = c.linearization()
    A0, B0 = error_dynamics(0.5)
    assert_allclose(A, A0 - B0 @ c.K)
    assert np.linalg.eigvals(A).real.max() < -0.001  # Eq. 21 with the file's margin
    k_before = c.K[1, 1]
    c.set_params({"q_lateral": 0.01})
    assert c.K[1, 1] == pytest.approx(math.sqrt(0.01))
    assert c.K[1, 1] > k_before


def test_lqr_linearization_includes_the_wheel_lag_of_the_dynamic_model():
    weights = {"q_along": 1.0, "q_lateral": 0.001, "q_heading": 0.05}
    c = LqrController("lqr", weights, rng())
    A0, B0 = error_dynamics(0.5)
    ref = np.array([0.0, 0.0, 0.0, 0.5, 0.0])
    c.step(
        0.0,
        0.05,
        {
            "reference": ref,
            "pose_estimate": ref[:3],
            "dynamics": Dynamics(wheel_time_constant_s=0.2),
        },
    )
    A = c.linearization()
    assert A.shape == (5, 5)
    assert_allclose(A[:3, :3], A0)
    assert_allclose(A[:3, 3:], B0)
    assert_allclose(A[3:, :3], -c.K / 0.2)
    assert_allclose(A[3:, 3:], -np.eye(2) / 0.2)
    assert np.linalg.eigvals(A).real.max() < -0.001
    # a fast actuator leaves the slow closed-loop poles of A − B K (singular perturbation)
    c.dynamics = Dynamics(wheel_time_constant_s=1e-4)
    slow = np.sort_complex(np.linalg.eigvals(c.linearization()))[-3:]
    assert_allclose(slow, np.sort_complex(np.linalg.eigvals(A0 - B0 @ c.K)), rtol=1e-2)
    # a lag far slower than the loop destabilizes it: the filter must see that
    c.dynamics = Dynamics(wheel_time_constant_s=50.0)
    assert np.linalg.eigvals(c.linearization()).real.max() > 0
    # the hand-over carries the model to the successor controller
    a = AsymLqrController("asym", weights, rng())
    a.import_state(c.export_state())
    assert a.linearization().shape == (5, 5)


def test_lqr_command_feedforward_on_the_reference():
    c = LqrController("lqr", {}, rng())
    ref = np.array([1.0, 2.0, 0.3, 0.5, 0.1])
    out = c.step(
        0.0, 0.05, {"reference": ref, "pose_estimate": ref[:3], "kinematics": Kinematics(0.5, 0.1)}
    )
    # on the reference: pure feed-forward v = 0.5, ω = 0.1
    assert_allclose(out["wheel_cmd"], [(0.5 - 0.025) / 0.1, (0.5 + 0.025) / 0.1])
    assert c.local_signals()["tracking_error"] == 0.0


def test_lqr_set_params_keeps_the_reference_speed():
    c = AsymLqrController("a", {"design_speed_mps": 0.3}, rng())
    assert c.v_ref == 0.3
    assert_allclose(c.K, lqr_gain(0.3, (1.0, 1.0, 1.0), (1.0, 1.0)))
    ref = np.array([0.0, 0.0, 0.0, 1.2, 0.0])
    enc = None
    for k in range(100):
        out = c.step(0.05 * k, 0.05, {"reference": ref, "pose_estimate": ref[:3],
                                      "encoder_speeds": enc})
        enc = 0.2 * out["wheel_cmd"]
        if k == 0:
            assert c.v_ref == 1.2
            c.set_params({"q_lateral": 0.5, "min_effectiveness": 0.6})
    assert c.v_ref == 1.2  # the speed of the reference, not the design speed
    assert_allclose(c.K, lqr_gain(1.2, (1.0, 0.5, 1.0), (1.0, 1.0)))
    assert_allclose(c.effectiveness, [0.6, 0.6])  # the new lower clip


def test_asym_lqr_learns_effectiveness():
    c = AsymLqrController("a", {"adaptation_time_s": 1.0, "min_effectiveness": 0.3}, rng())
    ref = np.array([0.0, 0.0, 0.0, 0.5, 0.0])
    enc = None
    for k in range(200):
        out = c.step(
            0.05 * k,
            0.05,
            {
                "reference": ref,
                "pose_estimate": ref[:3],
                "kinematics": Kinematics(),
                "encoder_speeds": enc,
            },
        )
        enc = out["wheel_cmd"] * np.array([0.8, 1.0])
    assert_allclose(c.effectiveness, [0.8, 1.0], atol=1e-6)
    assert_allclose(out["wheel_cmd"], [5.0 / 0.8, 5.0], atol=1e-6)


# ---------------------------------------------------------------- EKF consistency
def test_ekf_nees_consistency():
    """Normalized estimation error squared inside its χ² band over Monte Carlo runs."""
    n_runs, n_steps, dt = 60, 600, 0.05  # 25 runs left ±20 % of sampling spread in ANEES
    sig_enc, r_head, r_gps, q_b, q_r = 0.05, 0.005, 0.2, 0.002, 1e-4
    params = {
        "q_position_m": 0.0,
        "q_heading_rad": 0.0,
        "q_bias_rad": q_b,
        "r_gps_m": r_gps,
        "r_heading_rad": r_head,
        "encoder_noise_rad_s": sig_enc,
        "initial_position_std_m": 0.3,
        "initial_heading_std_rad": 0.02,
        "initial_bias_std_rad": 0.02,
        "q_bias_rate_rad_s": q_r,
        "initial_bias_rate_std_rad_s": 0.001,
    }
    kin = Kinematics(0.5, 0.1)
    nees = np.zeros((n_runs, n_steps))
    for run in range(n_runs):
        g = np.random.default_rng(100 + run)
        f = Ekf("ekf", params, g)
        x0 = np.array(
            [
                0.3 * g.standard_normal(),
                0.3 * g.standard_normal(),
                0.02 * g.standard_normal(),
                0.02 * g.standard_normal(),
                0.001 * g.standard_normal(),
            ]
        )
        truth = x0.copy()
        f.x = np.zeros(5)
        f.started = True
        for k in range(n_steps):
            t = k * dt
            wl, wr = 5.0 + 1.5 * math.sin(0.2 * t), 5.0 + 1.5 * math.cos(0.13 * t)
            v, w = (
                kin.wheel_radius_m * (wl + wr) / 2,
                kin.wheel_radius_m * (wr - wl) / kin.wheel_base_m,
            )
            mid = truth[2] + 0.5 * w * dt
            truth = truth + np.array(
                [v * dt * math.cos(mid), v * dt * math.sin(mid), w * dt, truth[4] * dt, 0.0]
            )
            truth[3] += q_b * math.sqrt(dt) * g.standard_normal()
            truth[4] += q_r * math.sqrt(dt) * g.standard_normal()
            enc = np.array([wl, wr]) + sig_enc * g.standard_normal(2)
            f.predict(dt, enc, kin)
            f.update_heading(truth[2] + truth[3] + r_head * g.standard_normal())
            if k % 20 == 0:
                f.update_position(truth[:2] + r_gps * g.standard_normal(2))
            e = truth - f.x
            e[2] = (e[2] + math.pi) % (2 * math.pi) - math.pi
            nees[run, k] = e @ np.linalg.solve(f.P, e)
    anees = nees.mean(axis=0)  # average over runs at each step
    lo, hi = chi2.ppf([0.005, 0.995], 5 * n_runs) / n_runs
    inside = np.mean((anees >= lo) & (anees <= hi))
    assert inside > 0.9, f"ANEES inside [{lo:.2f}, {hi:.2f}] only {inside:.0%} of the time"
    assert 4.2 < anees.mean() < 5.8


@pytest.mark.parametrize("seed", range(5))
def test_ekf_closed_form_matches_filterpy_matrix_form(seed: int) -> None:
    """The per-step predict and heading update in closed form (``predict_rows``,
    ``update_heading_rows``, shared with the lanes) are filterpy's own
    ``predict`` (P ← F P Fᵀ + Q) and ``update`` (Joseph form) with explicit matrices."""
    from filterpy.kalman import ExtendedKalmanFilter

    g = np.random.default_rng(seed)
    kin = Kinematics()
    f = Ekf("ekf", {"r_heading_rad": 0.01, "encoder_noise_rad_s": 0.07}, g)
    L = g.normal(size=(5, 5))
    P0 = L @ L.T + 0.1 * np.eye(5)  # a dense covariance
    x0 = g.normal(size=5)
    f.x, f.P = x0, P0
    dt, enc = 0.05, np.array([4.0, 5.5]) + g.normal(size=2)
    f.predict(dt, enc, kin)

    r, b = kin.wheel_radius_m, kin.wheel_base_m
    v, w = r * (enc[0] + enc[1]) / 2, r * (enc[1] - enc[0]) / b
    mid = x0[2] + 0.5 * w * dt
    F = np.eye(5)
    F[0, 2], F[1, 2] = -v * dt * math.sin(mid), v * dt * math.cos(mid)
    F[3, 4] = dt  # the bias follows its rate
    G = np.array(  # motion's Jacobian with respect to the two wheel speeds
        [
            [0.5 * r * dt * math.cos(mid)] * 2,
            [0.5 * r * dt * math.sin(mid)] * 2,
            [-r * dt / b, r * dt / b],
            [0.0, 0.0],
            [0.0, 0.0],
        ]
    )
    ref = ExtendedKalmanFilter(dim_x=5, dim_z=1)
    ref.x, ref.P, ref.F = x0.copy(), P0.copy(), F
    ref.Q = 0.07**2 * G @ G.T + np.diag(f._q2) * dt
    ref.predict()
    assert_allclose(f.P, ref.P, rtol=1e-12, atol=1e-14)
    assert_allclose(f.P, f.P.T, rtol=0, atol=0)  # exactly symmetric
    assert_allclose(
        f.x,
        [
            x0[0] + v * dt * math.cos(mid),
            x0[1] + v * dt * math.sin(mid),
            x0[2] + w * dt,
            x0[3] + x0[4] * dt,
            x0[4],
        ],
        rtol=1e-13,
    )

    heading = float(f.x[2] + f.x[3] + 0.02)
    ref.x = f.x.reshape(5, 1)
    ref.P = f.P
    ref.update(
        np.array([heading]),
        lambda x: np.array([[0.0, 0.0, 1.0, 1.0, 0.0]]),
        lambda x: np.array([x[2] + x[3]]).reshape(1, 1),
        R=np.array([[0.01**2]]),
    )
    f.update_heading(heading)
    assert_allclose(f.P, ref.P, rtol=1e-10, atol=1e-14)
    assert_allclose(f.P, f.P.T, rtol=0, atol=0)
    assert_allclose(f.x, ref.x.ravel(), rtol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_ekf_gps_update_is_filterpys_and_the_state_is_kept_once(seed: int) -> None:
    """The closed-form GPS update (``update_position_rows``, shared with the lanes) is
    filterpy's ``ExtendedKalmanFilter.update`` with ``H = [I₂ 0]`` on random states,
    one row per run and many rows at once."""
    from filterpy.kalman import ExtendedKalmanFilter

    from archself_diffdrive.estimators import update_position_rows

    g = np.random.default_rng(seed)
    r_gps = float(g.uniform(0.05, 2.0))
    f = Ekf("ekf", {"r_gps_m": r_gps}, g)
    rows_x, rows_P, rows_z, want_x, want_P = [], [], [], [], []
    for _ in range(8):
        L = g.normal(size=(5, 5)) * g.uniform(0.01, 3.0, size=5)
        P0 = L @ L.T + 0.01 * np.eye(5)  # a dense covariance
        x0 = g.normal(size=5)
        z = x0[:2] + g.normal(scale=r_gps, size=2)
        ref = ExtendedKalmanFilter(dim_x=5, dim_z=2)
        ref.x, ref.P = x0.copy(), P0.copy()
        ref.update(z, lambda _x: np.eye(2, 5), lambda x: x[:2], R=r_gps**2 * np.eye(2))
        f.x, f.P = x0.copy(), P0.copy()
        innovation = f.update_position(z)
        assert_allclose(innovation, z - x0[:2], rtol=1e-15)
        scale = np.abs(ref.P).max()
        assert_allclose(f.x, ref.x, rtol=1e-12, atol=1e-12 * np.abs(ref.x).max())
        assert_allclose(f.P, ref.P, rtol=1e-12, atol=1e-12 * scale)
        assert_allclose(f.P, f.P.T, rtol=0, atol=0)  # exactly symmetric
        rows_x.append(x0)
        rows_P.append(P0)
        rows_z.append(z)
        want_x.append(f.x)
        want_P.append(f.P)
    x, P = update_position_rows(np.array(rows_x), np.array(rows_P), np.array(rows_z),
                                r_gps**2)
    assert_allclose(x, want_x, rtol=0, atol=0)  # a lane is its run, bit for bit
    assert_allclose(P, want_P, rtol=0, atol=0)
    # one copy of the state: no filterpy filter is kept between GPS updates
    assert not any(isinstance(v, ExtendedKalmanFilter) for v in vars(f).values())
    f.predict(0.05, np.array([5.0, 5.0]))
    assert f.export_state()["pose"][0] == pytest.approx(f.x[0])


def test_ekf_gps_update_of_a_non_finite_covariance_raises() -> None:
    f = Ekf("ekf", {}, rng())
    f.P[0, 1] = f.P[1, 0] = math.inf
    with pytest.raises(ValueError, match="infs or NaNs"):
        f.update_position(np.array([1.0, 2.0]))


def test_a_diffdrive_run_imports_no_filterpy() -> None:
    code = (
        "import sys\n"
        "from archself.sim.run import simulate\n"
        f"simulate({str(DIFFDRIVE)!r}, 'imu_drift', seed=1)\n"
        "print('filterpy' in sys.modules)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split()[-1] == "False"


def test_ekf_handover_from_odometry():
    odo = Odometry("odo", {}, rng())
    odo.import_state({"pose": [3.0, -1.0, 0.4], "covariance": np.diag([0.2, 0.2, 0.01])})
    ekf = Ekf("ekf", {}, rng())
    ekf.import_state(odo.export_state())
    assert_allclose(ekf.x, [3.0, -1.0, 0.4, 0.0, 0.0])
    assert ekf.P[0, 0] > 0.2 and ekf.P[3, 3] > 0
    st = ekf.export_state()
    assert set(st) >= {"pose", "covariance"}


def test_ekf_estimates_a_drifting_imu_bias():
    kin = Kinematics()
    f = Ekf("ekf", {"q_bias_rad": 0.002, "r_gps_m": 0.2}, rng(3))
    g = rng(4)
    truth = np.zeros(3)
    dt = 0.05
    for k in range(6000):
        t = k * dt
        wl, wr = 5.0, 5.0 + 0.5 * math.sin(0.05 * t)
        v, w = 0.1 * (wl + wr) / 2, 0.1 * (wr - wl) / 0.5
        mid = truth[2] + 0.5 * w * dt
        truth = truth + [v * dt * math.cos(mid), v * dt * math.sin(mid), w * dt]
        bias = 7e-4 * t
        out = f.step(
            t,
            dt,
            {
                "encoder_speeds": np.array([wl, wr]) + 0.05 * g.standard_normal(2),
                "heading": truth[2] + bias + 0.005 * g.standard_normal(),
                "kinematics": kin,
                "position": truth[:2] + 0.2 * g.standard_normal(2) if k % 20 == 0 else None,
            },
        )
    assert f.x[3] == pytest.approx(bias, abs=0.03)
    assert np.hypot(*(out["pose_estimate"][:2] - truth[:2])) < 0.5


# ---------------------------------------------------------------- estimators, sensors
def test_odometry_exact_without_noise():
    o = Odometry("o", {}, rng())
    kin = Kinematics(0.5, 0.1)
    wl, wr = 4.0, 6.0
    w = 0.1 * (wr - wl) / 0.5
    pose = np.zeros(3)
    dt = 0.05
    for k in range(400):
        out = o.step(
            k * dt,
            dt,
            {"encoder_speeds": np.array([wl, wr]), "heading": w * k * dt, "kinematics": kin},
        )
    # circle of radius v / ω = 0.5 / 0.4 after 19.95 s
    t = 399 * dt
    pose = [1.25 * math.sin(w * t), 1.25 * (1 - math.cos(w * t))]
    assert_allclose(out["pose_estimate"][:2], pose, atol=1e-3)


def test_innovation_window_vector_mean():
    w = InnovationWindow(10.0)
    g = rng(5)
    for k in range(200):
        e = 0.3 * g.standard_normal(2)
        w.add(float(k) * 0.5, *e)
    assert w.value() < 0.15  # noise averages out
    w.clear()
    for k in range(30):
        w.add(float(k), 0.5, 0.0)
    assert w.value() == pytest.approx(0.5)


def _trend_of(t, e, window_s=60.0):
    w = InnovationTrend(window_s)
    for tk, (ex, ey) in zip(t, e, strict=True):
        w.add(float(tk), float(ex), float(ey))
    return w


def test_innovation_trend_is_the_ols_slope_over_its_first_difference_noise():
    """Slope: scipy's least squares per axis; noise: first differences; window honoured."""
    from scipy.stats import linregress

    g = rng(11)
    t = np.arange(0.0, 100.0)
    e = np.column_stack([0.02 * t, -0.01 * t]) + 0.3 * g.standard_normal((t.size, 2))
    w = _trend_of(t, e, 60.0)
    keep = t > t[-1] - 60.0  # the window: the last 60 s
    slopes = [linregress(t[keep], e[keep, j]).slope for j in range(2)]
    d = np.diff(e[keep], axis=0)
    se = math.sqrt(np.mean(d * d) / 2.0 / np.sum((t[keep] - t[keep].mean()) ** 2))
    assert_allclose(w.value(), math.hypot(*slopes) / se, rtol=1e-12)


def test_innovation_trend_does_not_depend_on_the_noise_scale():
    """The fault-free statistic is the same at any GPS noise: one band for every level."""
    g = rng(3)
    t = np.arange(0.0, 60.0)
    e = g.standard_normal((t.size, 2))
    assert_allclose(_trend_of(t, 0.2 * e).value(), _trend_of(t, 0.4 * e).value(), rtol=1e-12)
    # white noise gives an O(1) statistic; a 2 cm/s run-away under the same noise does not
    assert _trend_of(t, 0.2 * e).value() < 4.0
    assert _trend_of(t, 0.2 * e + 0.02 * t[:, None]).value() > 10.0


def test_innovation_trend_waits_for_half_a_window_and_forgets():
    w = InnovationTrend(60.0)
    for k in range(29):
        w.add(float(k), 0.1 * (-1) ** k, 0.0)
    assert math.isnan(w.value())
    w.add(30.0, 0.0, 0.0)
    assert math.isfinite(w.value())
    w.clear()
    assert math.isnan(w.value())


def test_odometry_trend_sees_a_heading_bias_the_gps_does_not_share():
    """Straight run at 0.5 m/s, GPS at the truth with 0.2 m noise: a 0.05 rad IMU bias
    makes dead reckoning run away from the fixes at about v·b = 2.5 cm/s."""

    def run(bias):
        o = Odometry("o", {}, rng())
        g = rng(7)
        kin = Kinematics(0.5, 0.1)
        dt = 0.05
        for k in range(1200):  # 60 s
            t = k * dt
            gps = None
            if k % 20 == 0:
                gps = np.array([0.5 * t, 0.0]) + 0.2 * g.standard_normal(2)
            o.step(t, dt, {"encoder_speeds": np.array([5.0, 5.0]), "heading": bias,
                           "kinematics": kin, "position": gps})
        return o.local_signals()["innovation_trend"]

    assert run(0.0) < 4.0
    assert run(0.05) > 8.0


def test_odometry_takes_a_handed_over_imu_bias_off_the_heading():
    """The EKF's bias estimate survives a fall-back to dead reckoning (and comes back)."""
    o = Odometry("o", {}, rng())
    o.import_state({"pose": np.zeros(3), "imu_bias": 0.05})
    kin = Kinematics(0.5, 0.1)
    for k in range(200):  # 10 s straight ahead at 0.5 m/s; the IMU reads true heading + 0.05
        out = o.step(k * 0.05, 0.05, {"encoder_speeds": np.array([5.0, 5.0]),
                                       "heading": 0.05, "kinematics": kin})
    assert_allclose(out["pose_estimate"], [200 * 0.025, 0.0, 0.0], atol=1e-9)
    assert o.export_state()["imu_bias"] == 0.05
    o.import_state({"pose": np.zeros(3)})  # a state without a bias: none assumed
    assert o.bias == 0.0
    # a bias within 3 standard deviations of zero is noise: not applied
    o.import_state({"pose": np.zeros(3), "imu_bias": -0.017, "imu_bias_std": 0.012})
    assert o.bias == 0.0
    o.import_state({"pose": np.zeros(3), "imu_bias": 0.07, "imu_bias_std": 0.012})
    assert o.bias == 0.07


def test_odometry_carries_a_handed_over_bias_rate_forward():
    """A drifting gyro handed over with its rate stays corrected: the pose runs straight."""
    o = Odometry("o", {}, rng())
    o.import_state({"pose": np.zeros(3), "imu_bias": 0.02, "imu_bias_std": 0.002,
                    "imu_bias_rate": 1e-3, "imu_bias_rate_std": 1e-4})
    kin = Kinematics(0.5, 0.1)
    for k in range(400):  # 20 s straight ahead; the IMU reads 0.02 + 1e-3·t too much
        t = k * 0.05
        out = o.step(t, 0.05, {"encoder_speeds": np.array([5.0, 5.0]),
                               "heading": 0.02 + 1e-3 * (t + 0.05), "kinematics": kin})
    assert_allclose(out["pose_estimate"][1:], [0.0, 0.0], atol=1e-9)
    assert_allclose(o.export_state()["imu_bias"], 0.02 + 1e-3 * 20.0, rtol=1e-9)
    # an insignificant rate (within 2 standard deviations) is not extrapolated
    o.import_state({"pose": np.zeros(3), "imu_bias_rate": 1.5e-4, "imu_bias_rate_std": 1e-4})
    assert o.bias_rate == 0.0


def test_gps_rate_and_gaps():
    gps = Gps("gps", {"rate_hz": 2.0, "noise_m": 0.0}, rng())
    fixes = [
        gps.step(k * 0.05, 0.05, {"pose": np.array([1.0, 2.0, 0.0])})["position"]
        for k in range(200)
    ]
    got = [p for p in fixes if p is not None]
    assert len(got) == 20
    assert_allclose(got[0], [1.0, 2.0])


def test_wheel_actuator_picks_side_and_measures_error():
    w = WheelActuator("wr", {"side": "right"}, rng())
    assert w.step(0.0, 0.05, {"wheel_cmd": np.array([1.0, 2.0])}) == {"wheel_speed_right": 2.0}
    w.step(0.05, 0.05, {"wheel_cmd": np.array([1.0, 2.0]), "encoder_speeds": np.array([1, 1.5])})
    assert w.local_signals()["command_error"] == pytest.approx(0.5)
    with pytest.raises(ValueError):
        WheelActuator("x", {"side": "middle"}, rng())


def test_plant_lag_and_limit():
    p = DiffDrivePlant("c", {"wheel_time_constant_s": 0.1, "max_wheel_speed_rad_s": 6.0}, rng())
    for k in range(100):
        p.step(k * 0.05, 0.05, {"wheel_speed_left": 10.0, "wheel_speed_right": None})
    ws = p.output(5.0)["wheel_speeds"]
    assert_allclose(ws, [6.0, 0.0], atol=1e-6)
    assert p.output(5.0)["pose"][2] < 0  # only the left wheel drives: turns right


def test_plant_draws_its_disturbances_in_the_stream_order() -> None:
    """One draw a step (slip's two normals, then the pose noise's two) is the per-call
    order: the pose equals the step written out on the stream's first four normals, and
    the stream is left where four draws leave it (lanes draw the same numbers)."""
    params = {"wheel_time_constant_s": 0.0, "slip_variance_m": 0.01,
              "lateral_noise_m_sqrt_s": 0.02, "yaw_noise_rad_sqrt_s": 0.03}
    p = DiffDrivePlant("c", params, np.random.default_rng(7))
    p.step(0.0, 0.05, {"wheel_speed_left": 4.0, "wheel_speed_right": 6.0})
    ref = np.random.default_rng(7)
    z = ref.standard_normal(4).tolist()
    r, b, dt = p.radius, p._base, 0.05
    wl = 4.0 + math.sqrt(0.01 * abs(r * 4.0 * dt)) * z[0] / (r * dt)
    wr = 6.0 + math.sqrt(0.01 * abs(r * 6.0 * dt)) * z[1] / (r * dt)
    x, y, th = arc_step(0.0, 0.0, 0.0, r, b, wl, wr, dt)
    lat = 0.02 * (z[2] * math.sqrt(dt))
    want = [x - math.sin(th) * lat, y + math.cos(th) * lat, th + 0.03 * (z[3] * math.sqrt(dt))]
    assert_allclose(p.pose, want, rtol=0, atol=0)
    assert p.rng.standard_normal() == ref.standard_normal()


def test_encoders_on_floats_are_the_array_formula_to_the_bit() -> None:
    enc = WheelEncoders("enc", {"noise_rad_s": 0.07}, np.random.default_rng(3))
    ref = np.random.default_rng(3)
    for ws in (np.array([4.25, -1.5]), np.array([1e-3, 7.0])):
        got = enc.step(0.0, 0.05, {"wheel_speeds": ws})["encoder_speeds"]
        assert type(got) is np.ndarray
        assert_allclose(got, ws + 0.07 * ref.standard_normal(2), rtol=0, atol=0)


def test_planner_arc_length_and_curvature():
    pl = SplinePlanner(
        "p", {"waypoints": [[0, 0], [10, 5], [20, 0], [30, -5], [40, 0]], "speed_mps": 0.5}, rng()
    )
    dt = 0.05
    refs = np.array([pl.reference(k * dt) for k in range(1, int(pl.duration_s / dt))])
    step = np.hypot(*np.diff(refs[:, :2], axis=0).T)
    assert_allclose(step, 0.5 * dt, rtol=2e-3)  # constant speed along the path
    heading = np.arctan2(*np.diff(refs[:, :2], axis=0).T[::-1])
    assert_allclose(np.unwrap(heading), refs[:-1, 2] + 0.5 * np.diff(refs[:, 2]), atol=2e-3)
    dth = np.diff(refs[:, 2]) / dt
    assert_allclose(dth, refs[:-1, 4], atol=2e-3)  # ω = κ v
    end = pl.reference(pl.duration_s + 10)
    assert_allclose(end[3:], [0.0, 0.0])


def test_diffdrive_path_lasts_400_s():
    from ruamel.yaml import YAML

    from archself.resources import data_dir

    raw = YAML(typ="safe").load(data_dir("architectures") / "diffdrive.yaml")
    p = raw["modules"]["planner"]["params"]
    pl = SplinePlanner("p", {k: v["value"] for k, v in p.items()}, rng())
    assert pl.duration_s >= 400


# ---------------------------------------------------------------- faults
def test_fault_kinds():
    arr = np.array([1.0, 2.0])
    assert FaultInjector("bias", 1.0, 0.5).apply(0.5, 1.0) == 1.0  # before onset
    assert_allclose(FaultInjector("bias", 1.0, 0.5).apply(2.0, arr), [1.5, 2.5])
    assert FaultInjector("bias_drift", 10.0, 0.1).apply(30.0, 0.0) == pytest.approx(2.0)
    assert_allclose(FaultInjector("effectiveness_loss", 0.0, 0.2).apply(1.0, arr), [0.8, 1.6])
    assert FaultInjector("dropout", 0.0).apply(1.0, arr) is None
    stuck = FaultInjector("stuck", 1.0, end_s=3.0)
    assert stuck.apply(1.0, 5.0) == 5.0
    assert stuck.apply(2.0, 7.0) == 5.0
    assert stuck.apply(2.5, None) is None
    assert stuck.apply(3.0, 9.0) == 9.0  # cleared at end_s
    noisy = FaultInjector("noise_increase", 0.0, 3.0, rng=rng(1), base_noise=0.1)
    draws = np.array([noisy.apply(1.0, 0.0) for _ in range(20000)])
    assert draws.std() == pytest.approx(0.1 * math.sqrt(8), rel=0.03)
    with pytest.raises(ValueError):
        FaultInjector("melt", 0.0)
