"""The generic block library (packs/archself_blocks): each block against an independent oracle.

Plants against scipy's ``lsim``/``dlsim`` and python-control's ``forced_response``; the
PID's closed-loop linearization against ``control.feedback``; the Kalman filter against
filterpy driven with explicit matrices (discretized with scipy's ``expm``) and a step
computed by hand; the observer against ``dlsim`` of its discretized equations.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
from numpy.testing import assert_allclose

from archself import registry
from archself.system.live import FAULT_KINDS
from archself_blocks.actuators import Actuator
from archself_blocks.estimators import AugmentedEkf, KalmanFilter, Luenberger, observer_gain
from archself_blocks.lti import LtiModel, LtiModelNode, StateSpacePlant, TransferFunctionPlant
from archself_blocks.pid import Pid, pid_closed_loop
from archself_blocks.sensors import Sensor
from archself_blocks.signals import Gain, Reference, Select, Sum

KEYS = [
    "generic.state_space", "generic.transfer_function", "generic.lti_model", "generic.pid",
    "generic.kalman", "generic.ekf", "generic.luenberger", "generic.sensor", "generic.actuator",
    "generic.reference", "generic.gain", "generic.sum", "generic.select", "generic.expression",
]
A2 = [[-1.0, 2.0], [-3.0, -0.5]]
B2 = [[0.0], [1.0]]
C2 = [[1.0, 0.0], [0.0, 1.0]]


def rng(seed=0):
    return np.random.default_rng(seed)


def zoh(A, B, dt):
    """Zero-order-hold discretization with scipy's matrix exponential (not python-control)."""
    A, B = np.asarray(A, float), np.asarray(B, float)
    n, m = A.shape[0], B.shape[1]
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = scipy.linalg.expm(M * dt)
    return E[:n, :n], E[:n, n:]


def run_plant(plant, u, dt):
    ys = []
    for k, uk in enumerate(u):
        ys.append(plant.output(k * dt)["y"])
        plant.step(k * dt, dt, {"u": [uk]})
    return np.array(ys)


# --------------------------------------------------------------------------- declarations
@pytest.mark.parametrize("key", KEYS)
def test_declarations(key):
    cls = registry.get(key)
    assert cls.__module__.startswith("archself_blocks.")
    assert cls.outputs and set(cls.fault_kinds) <= FAULT_KINDS
    assert cls.parameters and all(p.doc for p in cls.parameters.values())
    assert not set(cls.inputs) & set(cls.optional_inputs)


REQUIRED = {
    "generic.state_space": {"A": A2, "B": B2},
    "generic.transfer_function": {"num": [1.0], "den": [1.0, 1.0]},
    "generic.lti_model": {"A": A2, "B": B2},
    "generic.luenberger": {"poles": [-1.0, -2.0]},
    "generic.expression": {"expression": "2 * x"},
}


@pytest.mark.parametrize("key", KEYS)
def test_parameters_declared_once(key):
    """Built from the required parameters alone, a block holds exactly the declared names."""
    cls = registry.get(key)
    m = cls("m", dict(REQUIRED.get(key, {})), rng())
    assert set(m.params) == set(cls.parameters)
    for name, p in cls.parameters.items():
        if not p.required and name not in REQUIRED.get(key, {}):
            assert m.params[name] == p.default, (key, name)


def test_import_is_light():
    code = (
        "import sys, archself_blocks.lti, archself_blocks.pid, archself_blocks.estimators, "
        "archself_blocks.sensors, archself_blocks.actuators, archself_blocks.signals; "
        "heavy = [m for m in ('control', 'filterpy', 'matplotlib') if m in sys.modules]; "
        "assert not heavy, heavy"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# --------------------------------------------------------------------------- plants
def test_continuous_state_space_matches_lsim():
    dt = 0.05
    u = np.sin(0.7 * np.arange(200) * dt) + (np.arange(200) > 50)
    plant = StateSpacePlant("p", {"A": A2, "B": B2, "C": C2, "x0": [1.0, -0.5]}, rng())
    ys = run_plant(plant, u, dt)
    t = np.arange(200) * dt
    _, y_ref, _ = scipy.signal.lsim((A2, B2, C2, [[0.0], [0.0]]), u, t, X0=[1.0, -0.5],
                                    interp=False)
    assert_allclose(ys, y_ref, rtol=1e-8, atol=1e-10)


def test_state_space_step_matches_forced_response():
    control = pytest.importorskip("control")
    dt = 0.1
    plant = StateSpacePlant("p", {"A": A2, "B": B2, "C": [[1.0, 1.0]]}, rng())
    ys = run_plant(plant, np.full(100, 2.0), dt)
    t = np.arange(100) * dt
    resp = control.forced_response(control.ss(A2, B2, [[1.0, 1.0]], 0), t, np.full(100, 2.0))
    assert_allclose(ys[:, 0], resp.outputs, rtol=1e-7, atol=1e-9)


def test_discrete_state_space_matches_dlsim_and_holds_between_samples():
    Ad, Bd = [[0.9, 0.1], [0.0, 0.8]], [[0.0], [0.5]]
    u = rng(3).standard_normal(60)
    plant = StateSpacePlant("p", {"A": Ad, "B": Bd, "sample_time_s": 0.1}, rng())
    ys = run_plant(plant, u, 0.1)
    _, y_ref, _ = scipy.signal.dlsim((Ad, Bd, np.eye(2), np.zeros((2, 1)), 0.1), u)
    assert_allclose(ys, y_ref, rtol=1e-12, atol=1e-12)
    slow = StateSpacePlant("p", {"A": Ad, "B": Bd, "sample_time_s": 0.2}, rng())
    ys2 = run_plant(slow, np.repeat(u[:30], 2), 0.1)
    assert_allclose(ys2[::2], y_ref[:30], atol=1e-12)  # one update per period...
    assert_allclose(ys2[1::2], y_ref[:30], atol=1e-12)  # ...held in between


def test_transfer_function_matches_forced_response_and_dc_gain():
    control = pytest.importorskip("control")
    num, den = [2.0, 1.0], [1.0, 3.0, 2.0]
    plant = TransferFunctionPlant("p", {"num": num, "den": den}, rng())
    ys = run_plant(plant, np.ones(300), 0.05)
    t = np.arange(300) * 0.05
    resp = control.forced_response(control.tf(num, den), t, np.ones(300))
    assert_allclose(ys[:, 0], resp.outputs, rtol=1e-7, atol=1e-9)
    assert ys[-1, 0] == pytest.approx(0.5, abs=1e-3)  # num(0)/den(0)


def test_plant_sums_its_inputs_and_publishes_what_it_applied():
    plant = StateSpacePlant("p", {"A": [[-1.0]], "B": [[1.0, 2.0]]}, rng())
    plant.step(0.0, 0.1, {"u": [np.array([1.0, 0.0]), np.array([0.0, 3.0]), None]})
    out = plant.output(0.1)
    assert_allclose(out["u"], [1.0, 3.0])
    assert_allclose(out["y"], zoh([[-1.0]], [[1.0, 2.0]], 0.1)[1] @ [1.0, 3.0])


def test_plant_process_noise_has_the_declared_intensity():
    plant = StateSpacePlant("p", {"A": [[0.0]], "B": [[0.0]], "process_noise": 0.5}, rng(1))
    path = []
    for k in range(10000):
        plant.step(0.01 * k, 0.01, {})
        path.append(plant.x[0])
    increments = np.diff([0.0, *path])  # a Wiener process: σ = 0.5·√dt per step
    assert np.std(increments) == pytest.approx(0.5 * math.sqrt(0.01), rel=0.03)
    assert abs(np.mean(increments)) < 4 * 0.05 / math.sqrt(10000)


def test_model_node_publishes_the_model():
    node = LtiModelNode("m", {"A": A2, "B": B2}, rng())
    m = node.output(0.0)["model"]
    assert isinstance(m, LtiModel) and (m.n, m.m, m.p) == (2, 1, 2)
    assert_allclose(m.discrete(0.1)[0], zoh(A2, B2, 0.1)[0], atol=1e-12)


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="shapes"):
        StateSpacePlant("p", {"A": A2, "B": [[1.0, 2.0, 3.0]]}, rng())


# --------------------------------------------------------------------------- PID
def test_pid_terms_by_hand():
    c = Pid("c", {"kp": 2.0, "ki": 0.5, "kd": 0.3, "derivative_filter_rad_s": 20.0,
                  "ff_gain": 0.1, "ff_rate_gain": 2.0, "ff_offset": 1.0}, rng())
    dt = 0.1
    u0 = c.step(0.0, dt, {"reference": [1.0, 0.2], "measurement": 0.0})["command"]
    assert u0 == pytest.approx(1.0 + 0.1 + 0.4 + 2.0 * 1.0)  # no derivative kick
    yf = 0.0
    u1 = c.step(dt, dt, {"reference": [1.0, 0.0], "estimate": np.array([0.4, 9.0])})["command"]
    d = -0.3 * 20.0 * (0.4 - yf)
    assert u1 == pytest.approx(1.0 + 0.1 + 2.0 * 0.6 + 0.5 * 1.0 * dt + d)
    assert c.local_signals()["tracking_error"] == pytest.approx(0.6)


def _saturated_run(mode):
    """Integrator plant ẏ = u, u ∈ [−1, 1], a reference step from 0 to 10 and back to 0."""
    c = Pid("c", {"kp": 0.5, "ki": 0.2, "u_min": -1.0, "u_max": 1.0, "anti_windup": mode,
                  "tracking_time_s": 0.5}, rng())
    y, dt, ys, integrals = 0.0, 0.1, [], []
    for k in range(600):
        r = 10.0 if k < 200 else 0.0
        u = c.step(k * dt, dt, {"reference": r, "measurement": y})["command"]
        assert -1.0 <= u <= 1.0
        y += dt * u
        ys.append(y)
        integrals.append(c.integral)
    return np.array(ys), np.array(integrals)


def test_pid_anti_windup():
    clamp, i_clamp = _saturated_run("clamp")
    back, i_back = _saturated_run("back_calculation")
    none, i_none = _saturated_run("none")
    # while saturated from the start the clamped integral stays 0, back-calculation bounds it,
    # and without anti-windup it winds up...
    assert i_clamp[50] == 0.0 and abs(i_back[50]) < 2.0 and i_none[50] > 5.0
    # ...which overshoots the reference by 70 %; with anti-windup by about 5 %
    assert none.max() > 15.0
    assert clamp.max() < 11.0 and back.max() < 11.0
    assert clamp[-1] == pytest.approx(0.0, abs=0.05) and back[-1] == pytest.approx(0.0, abs=0.05)


def test_pid_closed_loop_matches_control_feedback():
    control = pytest.importorskip("control")
    m = LtiModel(A2, B2, [[1.0, 0.0]])
    kp, ki, kd, n = 1.5, 0.8, 0.2, 15.0
    A = pid_closed_loop(m, kp, ki, kd, n)
    g = control.ss(A2, B2, [[1.0, 0.0]], 0)
    c = control.tf([kp], [1]) + control.tf([ki], [1, 0]) + control.tf([kd * n, 0], [1, n])
    ref = control.poles(control.feedback(g * c, 1))
    got = np.linalg.eigvals(A)
    assert_allclose(np.sort_complex(got), np.sort_complex(ref), rtol=1e-6, atol=1e-8)
    pid = Pid("c", {"kp": kp, "ki": ki, "kd": kd, "derivative_filter_rad_s": n}, rng())
    assert pid.linearization() is None
    pid.step(0.0, 0.1, {"reference": 0.0, "measurement": 0.0, "model": m})
    assert_allclose(pid.linearization(), A)


def test_pid_closed_loop_drives_the_plant_to_the_reference():
    m = LtiModel(A2, B2, [[1.0, 0.0]])
    plant = StateSpacePlant("p", {"A": A2, "B": B2, "C": [[1.0, 0.0]]}, rng())
    c = Pid("c", {"kp": 1.0, "ki": 2.0}, rng())
    assert np.linalg.eigvals(pid_closed_loop(m, 1.0, 2.0, 0.0, 10.0)).real.max() < 0
    for k in range(1000):
        y = plant.output(k * 0.02)["y"]
        u = c.step(k * 0.02, 0.02, {"reference": [1.0, 0.0], "measurement": y[0]})
        plant.step(k * 0.02, 0.02, {"u": [u["command"]]})
    assert plant.output(20.0)["y"][0] == pytest.approx(1.0, abs=1e-3)


# --------------------------------------------------------------------------- estimators
def _simulated(seed=4, steps=300, dt=0.1, noise=0.2, w=0.05):
    r = rng(seed)
    Ad, Bd = zoh(A2, B2, dt)
    x, xs, zs, us = np.array([1.0, 0.0]), [], [], []
    for _ in range(steps):
        u = np.array([math.sin(0.1 * len(us))])
        x = Ad @ x + Bd @ u + w * r.standard_normal(2)
        us.append(u)
        xs.append(x)
        zs.append(x[0] + noise * r.standard_normal())
    return np.array(xs), np.array(zs), np.array(us)


def test_kalman_filter_matches_filterpy_with_explicit_matrices():
    from filterpy.kalman import KalmanFilter as FpKalman

    dt, q, rr = 0.1, 0.02, 0.04
    xs, zs, us = _simulated(dt=dt)
    model = LtiModel(A2, B2, C2)
    kf = KalmanFilter("kf", {"Q": q, "R": rr, "P0": 0.5, "x0": [0.0, 0.0],
                             "measured_outputs": [0]}, rng())
    ref = FpKalman(dim_x=2, dim_z=1, dim_u=1)
    ref.F, ref.B = zoh(A2, B2, dt)
    ref.H, ref.Q = np.array([[1.0, 0.0]]), q * dt * np.eye(2)
    ref.R, ref.P = np.array([[rr]]), 0.5 * np.eye(2)
    ref.x = np.zeros(2)
    ours, theirs = [], []
    kf.step(0.0, dt, {"measurement": zs[0], "model": model})  # initializes at x0
    for k in range(1, len(zs)):
        out = kf.step(k * dt, dt, {"measurement": zs[k], "u": us[k], "model": model})
        ref.predict(u=us[k])
        ref.update(np.array([zs[k]]))
        ours.append(out["state"])
        theirs.append(np.asarray(ref.x, float).ravel())
        assert_allclose(kf.P, ref.P, rtol=1e-12, atol=1e-15)
    assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)
    assert np.sqrt(np.mean((np.array(ours)[:, 0] - xs[1:, 0]) ** 2)) < 0.2  # filters the noise


def test_kalman_filter_one_step_by_hand():
    model = LtiModel([[0.5]], [[1.0]], [[1.0]], dt=1.0)
    kf = KalmanFilter("kf", {"Q": 0.1, "R": 0.2, "P0": 1.0, "x0": [2.0]}, rng())
    kf.step(0.0, 1.0, {"measurement": 0.0, "model": model})
    out = kf.step(1.0, 1.0, {"measurement": 3.0, "u": [1.0], "model": model})
    x_pred, p_pred = 0.5 * 2.0 + 1.0, 0.25 * 1.0 + 0.1
    k = p_pred / (p_pred + 0.2)
    assert_allclose(out["state"], [x_pred + k * (3.0 - x_pred)], rtol=1e-12)
    assert_allclose(kf.P, [[(1 - k) * p_pred]], rtol=1e-12)
    err = kf.linearization()  # (1 − K)·F as a continuous equivalent
    k_ss = kf.P @ np.linalg.inv(kf.P + 0.2)
    assert_allclose(err, [[math.log(abs((1 - k_ss[0, 0]) * 0.5))]], rtol=1e-12)


def test_kalman_innovation_monitor_sees_a_bias_not_the_noise():
    xs, zs, us = _simulated(steps=600)
    model = LtiModel(A2, B2, C2)

    def monitor(bias):
        kf = KalmanFilter("kf", {"Q": 0.03, "R": 0.04, "measured_outputs": [0],
                                 "settle_s": 5.0, "innovation_window_s": 10.0}, rng())
        for k in range(len(zs)):
            z = zs[k] + (bias if k > 300 else 0.0)
            kf.step(k * 0.1, 0.1, {"measurement": z, "u": us[k],
                                   "model": model})
        return kf.local_signals()

    healthy, biased = monitor(0.0), monitor(1.0)
    assert healthy["innovation"] < 0.15 < biased["innovation"]
    assert 0.3 < healthy["nis"] < 3.0


def _plant_run(steps, dt, effectiveness=lambda k: 1.0, bias=0.0, seed=5, noise=0.05):
    """The 2-state plant driven by a varying input; (z, u) as the filters receive them."""
    r = rng(seed)
    plant = StateSpacePlant("p", {"A": A2, "B": B2, "C": C2}, rng())
    zs, us = [], []
    for k in range(steps):
        u = 1.0 + math.sin(0.05 * k) + 0.5 * math.sin(0.31 * k)
        plant.step(k * dt, dt, {"u": [effectiveness(k) * u]})
        zs.append(plant.output((k + 1) * dt)["y"][0] + bias + noise * r.standard_normal())
        us.append(np.array([u]))
    return np.array(zs), us


def test_ekf_matches_the_equations_written_out():
    dt = 0.1
    zs, us = _plant_run(30, dt)
    model = LtiModel(A2, B2, C2)
    ekf = AugmentedEkf("e", {"Q": 0.01, "R": 0.0025, "P0": 0.5, "x0": [0.0, 0.0],
                             "measured_outputs": [0], "effectiveness_noise": 0.01,
                             "effectiveness_p0": 0.04}, rng())
    ekf.step(0.0, dt, {"measurement": zs[0], "model": model})
    Ad, Bd = zoh(A2, B2, dt)
    x, P = np.array([0.0, 0.0, 1.0]), np.diag([0.5, 0.5, 0.04])
    Q, H, R = np.diag([0.01 * dt, 0.01 * dt, 0.01 * dt]), np.array([[1.0, 0.0, 0.0]]), 0.0025
    for k in range(1, 30):
        out = ekf.step(k * dt, dt, {"measurement": zs[k], "u": us[k], "model": model})
        F = np.eye(3)
        F[:2, :2], F[:2, 2] = Ad, Bd[:, 0] * us[k][0]
        x = np.concatenate([Ad @ x[:2] + Bd[:, 0] * x[2] * us[k][0], [x[2]]])
        P = F @ P @ F.T + Q
        S = H @ P @ H.T + R
        K = P @ H.T / S
        x = x + (K * (zs[k] - H @ x)).ravel()
        IKH = np.eye(3) - K @ H
        P = IKH @ P @ IKH.T + R * K @ K.T
        assert_allclose(out["state"], x[:2], rtol=1e-9, atol=1e-12)
        assert_allclose(out["parameters"], x[2:], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("parts", [{}, {"estimate_bias": True},
                                   {"estimate_effectiveness": False, "estimate_bias": True}])
def test_ekf_matches_filterpys_extended_kalman_filter(parts):
    """filterpy's ``ExtendedKalmanFilter`` (the oracle; a run uses the maths written in
    archself_blocks.estimators) fed the same Jacobian and ``h``: state, parameters and
    covariance within 1e-12."""
    from filterpy.kalman import ExtendedKalmanFilter

    dt = 0.1
    zs, us = _plant_run(60, dt, bias=0.2)
    model = LtiModel(A2, B2, C2)
    params = {"Q": 0.01, "R": 0.0025, "P0": 0.5, "x0": [0.0, 0.0], "measured_outputs": [0],
              "effectiveness_noise": 0.01, "effectiveness_p0": 0.04, **parts}
    ekf = AugmentedEkf("e", params, rng())
    ekf.step(0.0, dt, {"measurement": zs[0], "model": model})
    ne, nb = (1 if ekf.params["estimate_effectiveness"] else 0), (1 if parts else 0)
    na = 2 + ne + nb
    ref = ExtendedKalmanFilter(dim_x=na, dim_z=1)
    ref.x = np.concatenate([[0.0, 0.0], np.ones(ne), np.zeros(nb)])
    ref.P = np.diag([0.5, 0.5] + [0.04] * ne + [ekf.params["bias_p0"]] * nb)
    ref.Q = np.diag([0.01 * dt] * 2 + [0.01 * dt] * ne + [ekf.params["bias_noise"] * dt] * nb)
    ref.R = np.array([[0.0025]])
    h = np.zeros((1, na))
    h[0, 0] = 1.0
    h[0, na - nb:] = 1.0
    Ad, Bd = model.discrete(dt)
    for k in range(1, len(zs)):
        out = ekf.step(k * dt, dt, {"measurement": zs[k], "u": us[k], "model": model})
        F = np.eye(na)
        F[:2, :2] = Ad
        if ne:
            F[:2, 2] = Bd[:, 0] * us[k][0]
            ref.B = 0
        else:
            ref.B = np.vstack([Bd, np.zeros((nb, 1))])
        ref.F = F
        ref.predict(u=0 if ne else us[k])
        ref.update(np.array([zs[k]]), HJacobian=lambda _x: h, Hx=lambda x: h @ x)
        xa = np.asarray(ref.x, float).ravel()
        assert_allclose(out["state"], xa[:2], rtol=1e-12, atol=1e-12)
        assert_allclose(out["parameters"], xa[2:], rtol=1e-12, atol=1e-12)
        assert_allclose(ekf.P, ref.P, rtol=1e-12, atol=1e-15)


def test_a_blocks_run_imports_no_filterpy():
    """generic.kalman runs archself_blocks.kalman: a run of motor_drive imports no filterpy."""
    from archself.resources import data_dir

    arch = data_dir("architectures") / "motor_drive.yaml"
    code = ("import sys\nfrom archself.sim.run import simulate\n"
            f"simulate({str(arch)!r}, 'nominal', seed=1)\n"
            "print('filterpy' in sys.modules)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split()[-1] == "False"


def test_ekf_estimates_an_actuator_effectiveness_loss():
    dt = 0.1
    zs, us = _plant_run(1500, dt, effectiveness=lambda k: 1.0 if k < 500 else 0.6)
    model = LtiModel(A2, B2, C2)
    ekf = AugmentedEkf("e", {"Q": 0.001, "R": 0.0025, "measured_outputs": [0],
                             "effectiveness_noise": 0.001}, rng())
    seen = []
    for k in range(len(zs)):
        ekf.step(k * dt, dt, {"measurement": zs[k], "u": us[k], "model": model})
        seen.append(ekf.local_signals()["effectiveness_loss"])
    assert seen[490] < 0.1 < 0.3 < seen[-1]
    assert ekf.aug[0] == pytest.approx(0.6, abs=0.05)


def test_ekf_estimates_a_sensor_bias():
    dt = 0.1
    zs, us = _plant_run(1500, dt, bias=0.5)
    model = LtiModel(A2, B2, C2)
    ekf = AugmentedEkf("e", {"Q": 0.001, "R": 0.0025, "measured_outputs": [0],
                             "estimate_effectiveness": False, "estimate_bias": True}, rng())
    for k in range(len(zs)):
        ekf.step(k * dt, dt, {"measurement": zs[k], "u": us[k], "model": model})
    assert ekf.aug.tolist() == pytest.approx([0.5], abs=0.05)
    assert ekf.local_signals()["bias"] == pytest.approx(0.5, abs=0.05)


def test_luenberger_matches_dlsim_of_its_equations_and_places_its_poles():
    dt = 0.1
    xs, zs, us = _simulated(dt=dt, noise=0.0, w=0.0)
    model = LtiModel(A2, B2, [[1.0, 0.0]])
    poles = [-4.0, -5.0]
    L = observer_gain(model, poles)
    assert_allclose(np.sort(np.linalg.eigvals(model.A - L @ model.C).real), [-5.0, -4.0])
    obs = Luenberger("o", {"poles": poles, "x0": [0.0, 0.0]}, rng())
    outs = [obs.step(0.0, dt, {"measurement": zs[0], "model": model})["state"]]
    for k in range(1, len(zs)):
        outs.append(obs.step(k * dt, dt, {"measurement": zs[k], "u": us[k],
                                          "model": model})["state"])
    Ao = model.A - L @ model.C
    Ad, Bd = zoh(Ao, np.hstack([model.B, L]), dt)
    drive = np.column_stack([np.append(us[1:, 0], 0.0), zs])  # step k: u_k, y_(k−1)
    _, _, x_ref = scipy.signal.dlsim((Ad, Bd, np.eye(2), np.zeros((2, 2)), dt), drive,
                                     x0=[0.0, 0.0])
    assert_allclose(np.array(outs), x_ref, atol=1e-9)
    assert_allclose(obs.linearization(), Ao)
    assert np.abs(np.array(outs)[-50:] - xs[-50:]).max() < 0.05  # converged to the state


def test_luenberger_with_a_given_gain_on_a_discrete_model():
    model = LtiModel([[0.9]], [[1.0]], [[1.0]], dt=0.1)
    obs = Luenberger("o", {"gain": [[0.5]], "x0": [0.0]}, rng())
    obs.step(0.0, 0.1, {"measurement": 1.0, "model": model})
    out = obs.step(0.1, 0.1, {"measurement": 2.0, "u": [0.2], "model": model})
    assert_allclose(out["state"], [0.9 * 0.0 + 0.2 + 0.5 * (1.0 - 0.0)])
    assert_allclose(obs.linearization(), [[math.log(0.4) / 0.1]])


# --------------------------------------------------------------------------- sensor
def test_sensor_gain_bias_drift_range():
    s = Sensor("s", {"index": 1, "gain": 2.0, "bias": 0.5, "drift_per_s": 0.1, "max": 8.0}, rng())
    assert s.step(10.0, 0.1, {"y": [0.0, 3.0]})["measurement"] == pytest.approx(7.5)
    assert s.step(30.0, 0.1, {"y": [0.0, 3.0]})["measurement"] == 8.0
    assert s.step(0.0, 0.1, {"u": [1.0, 2.0]})["measurement"] == pytest.approx(4.5)
    assert s.step(0.0, 0.1, {})["measurement"] is None


def test_sensor_quantization():
    s = Sensor("s", {"resolution": 0.25}, rng())
    x = np.linspace(-2.0, 2.0, 401)
    got = np.array([s.step(0.0, 0.1, {"y": [v]})["measurement"] for v in x])
    assert_allclose(got, 0.25 * np.round(x / 0.25))
    assert np.abs(got - x).max() <= 0.125 + 1e-12
    assert s.noise_levels is None  # quantized values repeat: not a stale sensor


def test_sensor_noise_and_dropout_rates():
    s = Sensor("s", {"noise": 0.3, "dropout_probability": 0.2}, rng(7))
    vals = [s.step(0.0, 0.1, {"y": [1.0]})["measurement"] for _ in range(20000)]
    lost = sum(v is None for v in vals)
    assert abs(lost - 4000) < 4 * math.sqrt(20000 * 0.2 * 0.8)  # binomial, 4σ
    kept = np.array([v for v in vals if v is not None])
    assert kept.mean() == pytest.approx(1.0, abs=0.02)
    assert kept.std() == pytest.approx(0.3, rel=0.03)
    assert Sensor("s", {"noise": 0.3}, rng()).noise_levels == {"measurement": 0.3}


# --------------------------------------------------------------------------- actuator
def test_actuator_saturation_rate_limit_and_lag():
    sat = Actuator("a", {"u_min": -1.0, "u_max": 2.0}, rng())
    assert [sat.step(0, 0.1, {"command": c})["u"] for c in (5.0, -5.0, 0.5)] == [2.0, -1.0, 0.5]
    lag = Actuator("a", {"time_constant_s": 0.5}, rng())
    out = [lag.step(k * 0.01, 0.01, {"command": 1.0})["u"] for k in range(100)]
    assert_allclose(out, 1.0 - np.exp(-np.arange(1, 101) * 0.01 / 0.5), rtol=1e-12)
    A, B, C, D = lag.state_space()
    assert_allclose(A, [[-2.0]]) and assert_allclose(B, [[2.0]])
    vec = Actuator("a", {"width": 3, "channel": 2, "gain": 0.5}, rng())
    assert_allclose(vec.step(0.0, 0.1, {"command": 4.0})["u"], [0.0, 0.0, 2.0])


def test_actuator_command_error_sees_an_effectiveness_loss():
    from archself.system.live import FaultInjector

    fault = FaultInjector("effectiveness_loss", onset_s=1.0, magnitude=0.4)
    for gain, expect in ((1.0, 0.4 * 3.0), (1.0 / 0.6, 0.0)):
        a = Actuator("a", {"gain": gain}, rng())
        delivered = None
        for k in range(20):
            t = 0.1 * k
            inputs = {"command": 3.0}
            if delivered is not None:
                inputs["measurement"] = delivered
            u = a.step(t, 0.1, inputs)["u"]
            delivered = fault.apply(t, u)
        # the last step's command against what arrived; a raised gain compensates the loss
        assert a.local_signals()["command_error"] == pytest.approx(expect, abs=1e-12)


# --------------------------------------------------------------------------- signals
def test_reference_steps_ramps_and_rate_limit():
    steps = Reference("r", {"table": [[0, 1.0], [5, 2.0]]}, rng())
    assert steps.step(4.9, 0.1, {})["reference"].tolist() == [1.0, 0.0]
    assert steps.step(5.0, 0.1, {})["reference"].tolist() == [2.0, 0.0]
    ramp = Reference("r", {"table": [[0, 0.0], [10, 5.0], [20, 5.0]],
                           "interpolation": "linear"}, rng())
    assert_allclose(ramp.step(4.0, 0.1, {})["reference"], [2.0, 0.5])
    assert_allclose(ramp.step(15.0, 0.1, {})["reference"], [5.0, 0.0])
    limited = Reference("r", {"table": [[0, 0.0], [1, 1.0]], "max_rate": 0.5}, rng())
    out = [limited.step(0.1 * k, 0.1, {})["reference"] for k in range(40)]
    assert_allclose(out[10], [0.05, 0.5]) and assert_allclose(out[-1], [1.0, 0.0])
    assert np.all(np.diff([o[0] for o in out]) <= 0.05 + 1e-12)


def test_static_blocks():
    g = Gain("g", {"gain": [[1.0, 2.0], [0.0, 1.0]], "offset": [1.0, 0.0]}, rng())
    out = g.step(0.0, 0.1, {"y": [np.array([1.0, 1.0])]})
    assert_allclose(out["estimate"], [4.0, 1.0]) and assert_allclose(out["signal"], [4.0, 1.0])
    s = Sum("s", {"weights": [1.0, -1.0, 2.0]}, rng())
    assert s.step(0.0, 0.1, {"measurement": [3.0, None], "reference": [1.0]})["u"] == 5.0
    sel = Select("s", {"index": [2, 0]}, rng())
    assert_allclose(sel.step(0.0, 0.1, {"state": [None, [1.0, 2.0, 3.0]]})["y"], [3.0, 1.0])
    assert sel.step(0.0, 0.1, {})["y"] is None
