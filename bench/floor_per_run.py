"""Per-run same-work floors beside the framework's per-run step (issue 38 item 2).

Two hand-written runs of ``architectures/diffdrive.yaml``, one seed each, on Python floats,
to measure the framework's per-run step against (the done-when: ≤ 1.5× per run):

- fixed a1, ``nominal``: :func:`floor_diffdrive.run_floor_same_work` (imported: the
  GPS, every residual signal, the odometry's covariance, the run's recorded series);
- adaptive ``imu_drift``: :func:`run_floor_adaptive` below. The MAPE-K loop's
  *decision* is replayed, not taken: the switch time and target are read from one
  framework run (:func:`framework_switches`) and the hand-over is done at that step.
  The *monitoring work* is done by hand every ``runtime.period_s``: each active
  residual module's first-order filter, its r_i (Eq. 12, nominal normalization, trusted
  from confidence 0.5), the influence z = (I − Wᵀ)⁻¹ r (Eq. 14, the inverse made once
  per configuration) and the comparison of z with the band τ. The candidates'
  evaluation (Δ, the rollouts), the stability check and the decision log are not in
  the floor: a lower bound of the loop's cost.

``python bench/floor_per_run.py`` prints the framework (``simulate``) and the floor
side by side, CPU per run, interleaved, with the machine's load, and the executor's
own cost with the modules stubbed (:func:`plumbing_cpu`); and checks that the
adaptive floor's J equals the framework's bit for bit (tests/test_floor_per_run.py
checks every series, seeds 1–2).
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # as the archself command and bench/conftest.py: before numpy
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import copy  # noqa: E402
import importlib.util  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections import deque  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from functools import cache  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

if "floor_diffdrive" not in sys.modules:  # its sibling, without putting bench/ on sys.path
    # (a test importing this file would otherwise make `conftest` bench's in every
    # worker process the test suite starts afterwards)
    _spec = importlib.util.spec_from_file_location(
        "floor_diffdrive", Path(__file__).resolve().with_name("floor_diffdrive.py"))
    assert _spec is not None and _spec.loader is not None
    _sibling = importlib.util.module_from_spec(_spec)
    sys.modules["floor_diffdrive"] = _sibling
    _spec.loader.exec_module(_sibling)
from floor_diffdrive import (  # noqa: E402
    DIFFDRIVE,
    PI,
    TWO_PI,
    Setup,
    Work,
    _cached_gain,
    _gain,
    _metrics,
    load_setup,
    load_work,
    run_floor_same_work,
    stream,
)

SCENARIO = "imu_drift"


@dataclass(frozen=True)
class Adaptive:
    """What the adaptive imu_drift run needs besides :class:`Setup` and :class:`Work`
    (:func:`load_adaptive`): the fault, the EKF, the fused LQR, the monitoring."""

    onset: float  # the IMU's bias drift: heading + magnitude · (t − onset) from onset
    magnitude: float
    ekf: Any  # the pack's Ekf as the file builds it (copied per run; its maths are the work)
    kin: Any  # the kinematic model node's Kinematics (the EKF's input)
    fused_q: tuple[float, float, float]
    fused_r: tuple[float, float]
    handover_z: float  # odometry's drift_handover_z
    latency: int  # steps of the GPS → EKF edge
    period: int  # steps of a MAPE-K cycle
    tau: float  # runtime.threshold
    # (series index, sensitivity, nominal, filter gain per cycle, smoothing T) by module
    residuals: dict[str, tuple[int, float, float, float, float]]
    res_names: tuple[str, ...]  # the recorded residual columns, file order
    # (I − Wᵀ)⁻¹ of a1 and a2 (Eq. 14) over the residual modules' rows, file order
    influence: dict[str, np.ndarray]


@cache
def load_adaptive(path: str | Path = DIFFDRIVE) -> Adaptive:
    """The parameters of the adaptive imu_drift run, as the compiled modules hold them."""
    import archself
    from archself.system.live import compile_system

    arch = archself.load(path)
    sc = arch.scenarios[SCENARIO]
    nominal = arch.scenarios["nominal"]
    if sc.duration_s != nominal.duration_s or len(sc.faults) != 1:
        raise ValueError("imu_drift is not the run the floor implements")
    fault = sc.faults[0]
    if (fault.module, fault.kind) != ("imu", "bias_drift") or fault.end_s is not None:
        raise ValueError("imu_drift's fault is not the IMU bias drift the floor implements")
    system = compile_system(arch, "a2", seed=1, scenario=nominal)
    rt = arch.runtime
    period = max(1, int(round(rt.period_s / rt.step_s)))
    edge = next(e for e in arch.edges if (e.source, e.target) == ("gps", "ekf"))
    names = tuple(m for m, spec in arch.modules.items() if spec.residual)
    residuals = {}
    for j, m in enumerate(names):
        res = arch.modules[m].residual
        T = float(res.smoothing_s)
        gain = 1.0 - math.exp(-period * rt.step_s / T) if T > 0 else 1.0
        residuals[m] = (j, float(res.sensitivity), float(res.nominal), gain, T)
    fused = system._module("lqr_fused")
    index = {m: i for i, m in enumerate(arch.modules)}
    influence = {}
    for conf in ("a1", "a2"):
        on = set(arch.configurations[conf].modules)
        Wm = np.zeros((len(index), len(index)))
        for e in arch.edges:
            if e.source in on and e.target in on:
                Wm[index[e.source], index[e.target]] = float(e.weight)
        rows = [index[m] for m in names]
        influence[conf] = np.linalg.inv(np.eye(len(index)) - Wm.T)[np.ix_(rows, rows)]
    return Adaptive(
        onset=float(fault.onset_s),
        magnitude=float(fault.magnitude),
        ekf=system._module("ekf"),
        kin=system._module("kinematic_model").output(0.0)["kinematics"],
        fused_q=fused._weights()[0],
        fused_r=fused._weights()[1],
        handover_z=float(system._module("odometry").params["drift_handover_z"]),
        latency=int(round(edge.latency_s / rt.step_s)),
        period=period,
        tau=float(rt.threshold),
        residuals=residuals,
        res_names=names,
        influence=influence,
    )


def framework_switches(seed: int) -> list[tuple[float, str]]:
    """``(t_s, to)`` of the switches of one framework run of imu_drift (MAPE-K)."""
    import archself
    from archself.runtime import MapeK

    arch = archself.load(DIFFDRIVE)
    res = archself.simulate(arch, SCENARIO, seed=seed, adapt=MapeK(arch), keep=())
    return [(float(s["t_s"]), str(s["to"])) for s in res.switches]


def _odometry_state(W: Work, A: Adaptive, pose: tuple[float, float, float], var_pos: float,
                    drift: Any) -> dict[str, Any]:
    """The odometry's ``export_state`` (its hand-over to the EKF), written out."""
    ox, oy, oth = pose
    cov = np.diag([var_pos, var_pos, W.odo_var_th])
    state = {"pose": np.array([ox, oy, oth]), "covariance": cov, "imu_bias": 0.0,
             "imu_bias_rate": 0.0}
    z, rate, rate_std, _, error, extra, extra_std = drift.estimate()
    if abs(z) >= A.handover_z:
        cov = cov.copy()
        cov[2, 2] += extra_std**2
        state.update({"pose": np.array([ox + error[0], oy + error[1],
                                        (oth - extra + PI) % (2 * PI) - PI]),
                      "covariance": cov, "imu_bias": 0.0 + extra, "imu_bias_std": extra_std,
                      "imu_bias_rate": 0.0 + rate, "imu_bias_rate_std": rate_std})
    return state


class _Bands:
    """The monitoring work of a cycle, by hand: filter, r_i, the influence z = (I − Wᵀ)⁻¹ r
    over the residual modules and the comparison of z with the band τ."""

    def __init__(self, A: Adaptive) -> None:
        self.A = A
        self.y = dict.fromkeys(A.residuals, 0.0)
        self.valid = dict.fromkeys(A.residuals, 0.0)
        self.over = 0  # modules at or over the band, summed over the cycles

    def cycle(self, row: Sequence[float], active: Sequence[str], dt: float, conf: str) -> None:
        """One cycle over the ``active`` residual modules, ``row`` the recorded residuals."""
        A, y, valid = self.A, self.y, self.valid
        r = [0.0] * len(A.res_names)
        for m in active:
            j, sens, nom, gain, T = A.residuals[m]
            s = row[j]
            if s == s:  # finite sample: the filter moves
                y[m] += gain * (s - y[m])
                valid[m] += dt
            trusted = (1.0 - math.exp(-valid[m] / T) if T > 0 else 1.0) >= 0.5
            r[j] = min(sens * max(0.0, abs(y[m]) - nom) / nom, 1e12) if trusted else 0.0
        self.over += int(np.count_nonzero(A.influence[conf] @ np.array(r) >= A.tau))


def run_floor_adaptive(
    seed: int, switches: Sequence[tuple[float, str]], setup: Setup | None = None,
    work: Work | None = None, adaptive: Adaptive | None = None,
) -> dict[str, Any]:
    """One adaptive imu_drift run written out, replaying the framework's decision.

    a1 (odometry, LQR) as :func:`run_floor_same_work`, with the IMU's bias drift; at the
    replayed switch to a2 the odometry hands its state to the EKF (``export_state``
    written out, the pack's ``Ekf.import_state``) and the LQR its design speed to the
    fused LQR; in a2 the pack's EKF maths (``predict``, ``update_heading``,
    ``update_position``, its innovation window) with the GPS fixes two steps late (the
    edge's latency), the fused gains. Every ``period`` steps the monitoring work by hand
    (:class:`_Bands`). Records what ``simulate`` records (J, reference, actual, estimate,
    command, the residual columns, the configuration).

    Parameters
    ----------
    seed : int
    switches : sequence of (float, str)
        The framework's switches (:func:`framework_switches`): none, or one to ``a2``.
    """
    from archself_diffdrive.drift_glr import DriftGlr
    from archself_diffdrive.estimators import InnovationTrend, InnovationWindow

    S = setup or load_setup()
    W = work or load_work()
    A = adaptive or load_adaptive()
    if len(switches) > 1 or any(to != "a2" for _, to in switches):
        raise ValueError(f"the floor replays one switch to a2, not {switches}")
    n, dt = S.steps, S.dt
    at = int(round(switches[0][0] / dt)) if switches else n + 1  # steps before the switch
    cha = stream(seed, "chassis").standard_normal((n, 4)).tolist()
    enc = stream(seed, "encoders").standard_normal((n, 2)).tolist()
    imu = stream(seed, "imu").standard_normal(n).tolist()
    gps_rng = stream(seed, "gps")
    rx_, ry_, rth_, rv_, rw_ = (a.tolist() for a in S.ref)
    rc_, rs_ = (a.tolist() for a in S.ref_cs)
    sin, cos, sqrt, exp, hypot = math.sin, math.cos, math.sqrt, math.exp, math.hypot
    r, b, lim, slip, sig_e, sig_h = S.radius, S.base, S.limit, S.slip, S.enc_noise, S.imu_noise
    a_lag = 1.0 - math.exp(-dt / S.tau) if S.tau > 0 else 1.0
    lag = S.tau > 0
    rdt = r * dt
    sq_dt = sqrt(dt)
    kr, kb, alim = S.kin_radius, S.kin_base, S.act_limit
    onset, drift_rate = A.onset, A.magnitude
    v_design = S.design_speed
    k00, k01, k02, k10, k11, k12 = _gain(S, v_design)
    px, py, pth = S.pose0
    wl = wr = 0.0
    ox, oy, oth = W.odo_pose0
    var_pos, var_th, sv = 0.01, W.odo_var_th, W.odo_sv
    window, trend = InnovationWindow(W.windows[0]), InnovationTrend(W.windows[1])
    drift = DriftGlr(math.nan, math.nan, math.nan)
    drift.configure(*W.drift)
    next_fix, last_fix, period, gnoise = 0.0, (math.nan, math.nan), W.gps_period, W.gps_noise
    resp, smooth = W.wheel_response, W.wheel_smoothing
    fused, ekf, line, kin = False, None, deque(), A.kin
    names = A.res_names
    j_wl, j_wr, j_odo, j_ekf = (names.index(m) for m in ("wheel_left", "wheel_right",
                                                         "odometry", "ekf"))
    j_ctl = names.index("lqr")
    bands, active = _Bands(A), ("wheel_left", "wheel_right", "odometry", "lqr")
    prev = None  # the last wheel command
    expected = [0.0, 0.0]
    cmd_err = [math.nan, math.nan]
    odo_sig = ekf_sig = math.nan
    J = [0.0] * n
    ref_rec, act_rec, est_rec = np.empty((n, 5)), np.empty((n, 3)), np.empty((n, 3))
    cmd_rec = np.empty((n, 2))
    res_rec = np.full((n, len(names)), np.nan)
    conf_rec = np.zeros(n, dtype=int)
    for k in range(n):
        t = k * dt
        rx, ry, rth, rv, rw = rx_[k], ry_[k], rth_[k], rv_[k], rw_[k]
        dx, dy = px - rx, py - ry
        J[k] = sqrt(dx * dx + dy * dy)
        ref_rec[k] = (rx, ry, rth, rv, rw)
        act_rec[k] = (px, py, pth)
        # encoders, IMU (and its drift) and GPS
        e = enc[k]
        el = wl + sig_e * e[0]
        er = wr + sig_e * e[1]
        h = pth + S.imu_bias + sig_h * imu[k]
        h = (h + PI) % TWO_PI - PI
        if onset <= t + 1e-9:
            h = h + drift_rate * (t - onset)
        fix = None
        if t >= next_fix - 1e-9:
            next_fix += period * max(1.0, math.floor((t - next_fix) / period) + 1)
            fix = np.array([px, py]) + gnoise * gps_rng.standard_normal(2)
        if not fused:  # dead reckoning, its covariance and its GPS residuals
            v = kr * (el + er) / 2.0
            th0 = oth
            th1 = th0 + ((h - th0 + PI) % (2 * PI) - PI)
            if k:
                mid = 0.5 * (th0 + th1)
                ddx, ddy = v * dt * cos(mid), v * dt * sin(mid)
                ox += ddx
                oy += ddy
                drift.move(t, ddx, ddy)
                var_pos += (sv * dt) ** 2 + (v * dt) ** 2 * var_th
            oth = (th1 + PI) % (2 * PI) - PI
            if fix is not None and (float(fix[0]), float(fix[1])) != last_fix:
                last_fix = (float(fix[0]), float(fix[1]))
                ex, ey = last_fix[0] - ox, last_fix[1] - oy
                window.add(t, ex, ey)
                trend.add(t, ex, ey)
                drift.add(t, ex, ey)
                window.value(), trend.value()
                odo_sig = drift.value()
            np.diag([var_pos, var_pos, var_th])  # the published covariance
        else:  # the EKF: the pack's maths, the fixes through the edge's delay line
            ekf.predict(dt, (el, er), kin)
            ekf.update_heading(h)
            line.append(fix)
            pos = line.popleft()
            if pos is not None:
                ex, ey = ekf.update_position(pos)
                ekf.monitor.add(t, ex, ey)
                ekf_sig = ekf.monitor.value()
            ox, oy, oth = ekf.x[:3].tolist()
            ekf.P[:3, :3].copy()  # the published covariance
        # the LQR (a1's or the fused one) and its tracking error
        if abs(rv - v_design) > 0.005:
            v_design = rv
            k00, k01, k02, k10, k11, k12 = (
                _cached_gain(round(max(rv, 0.05), 2), A.fused_q, A.fused_r) if fused
                else _gain(S, rv))
        dx, dy = ox - rx, oy - ry
        c, s = rc_[k], rs_[k]
        e0 = c * dx + s * dy
        e1 = -s * dx + c * dy
        e2 = (oth - rth + PI) % TWO_PI - PI
        vc = rv - (k00 * e0 + k01 * e1 + k02 * e2)
        wc = rw - (k10 * e0 + k11 * e1 + k12 * e2)
        tracking = hypot(ox - rx, oy - ry)
        half = wc * kb / 2.0
        cl = (vc - half) / kr
        cr = (vc + half) / kr
        peak = max(abs(cl), abs(cr))
        if peak > alim:
            cl, cr = cl * alim / peak, cr * alim / peak
        # the wheels' command error (the last command against this step's encoders)
        if prev is not None:
            for i, m in ((0, el), (1, er)):
                cw = prev[i]
                if resp[i] > 0:
                    cw = expected[i] = expected[i] + (1.0 - exp(-dt / resp[i])) * (cw - expected[i])
                ew = cw - m if cw >= 0 else m - cw
                last = cmd_err[i]
                if smooth[i] > 0 and last == last:
                    ew = last + (1.0 - exp(-dt / smooth[i])) * (ew - last)
                cmd_err[i] = ew
        prev = (cl, cr)
        row = res_rec[k]
        row[j_wl], row[j_wr] = cmd_err
        row[j_ekf if fused else j_odo] = ekf_sig if fused else odo_sig
        row[j_ctl] = tracking
        est_rec[k] = (ox, oy, oth)
        cmd_rec[k] = prev
        conf_rec[k] = 1 if fused else 0
        # chassis
        cl = min(max(cl, -lim), lim)
        cr = min(max(cr, -lim), lim)
        wl0, wr0 = wl, wr
        wl = wl0 + a_lag * (cl - wl0)
        wr = wr0 + a_lag * (cr - wr0)
        ul, ur = (0.5 * (wl0 + wl), 0.5 * (wr0 + wr)) if lag else (wl, wr)
        z = cha[k]
        ul = ul + sqrt(slip * abs(r * ul * dt)) * z[0] / rdt
        ur = ur + sqrt(slip * abs(r * ur * dt)) * z[1] / rdt
        vb = r * (ul + ur) / 2.0
        wb = r * (ur - ul) / b
        dth = wb * dt
        th2 = pth + dth
        s2, c2 = sin(th2), cos(th2)
        if abs(dth) < 1e-9:
            m = pth + 0.5 * dth
            px += vb * dt * cos(m)
            py += vb * dt * sin(m)
        else:
            rad = vb / wb
            px += rad * (s2 - sin(pth))
            py -= rad * (c2 - cos(pth))
        pth = th2
        lat = S.lateral * (z[2] * sq_dt)
        px += -s2 * lat
        py += c2 * lat
        pth += S.yaw * (z[3] * sq_dt)
        if (k + 1) % A.period == 0:  # the monitoring work of a cycle
            bands.cycle(row.tolist(), active, A.period * dt, "a2" if fused else "a1")
        if k + 1 == at:  # the replayed switch a1 -> a2 and its hand-over
            ekf = copy.deepcopy(A.ekf)
            ekf.import_state(_odometry_state(W, A, (ox, oy, oth), var_pos, drift))
            line = deque([None] * A.latency)
            fused, ekf_sig, j_ctl = True, math.nan, names.index("lqr_fused")
            active = ("wheel_left", "wheel_right", "ekf", "lqr_fused")
            k00, k01, k02, k10, k11, k12 = _cached_gain(round(max(v_design, 0.05), 2),
                                                        A.fused_q, A.fused_r)
    t = (np.arange(n) + 1) * dt
    Ja = np.array(J)
    out = {**_metrics(t, Ja), "t": t, "J": Ja, "reference": ref_rec, "actual": act_rec,
           "estimate": est_rec, "command": cmd_rec, "configuration": conf_rec,
           "over_band": bands.over}
    for j, name in enumerate(names):
        out[f"residual.{name}"] = res_rec[:, j]
    return out


# ---------------------------------------------------------------------- the measurement
def _cpu(fn: Any) -> float:
    c = time.process_time()
    fn()
    return time.process_time() - c


def plumbing_cpu(steps: int = 8000, rounds: int = 3) -> tuple[float, float]:
    """CPU of the executor's own work over ``steps`` a1 steps, and of the modules' stubs.

    Every module of a compiled a1 system is replaced by a stub that returns its real
    outputs of step 50 (nudged each call, so no sensor goes stale): ``LiveSystem.step``
    then costs the plumbing (ops, gathering, health checks, publishing) plus the stubs,
    and the stubs alone are timed beside it. Best of ``rounds``.
    """
    import archself
    from archself.system.live import compile_system

    arch = archself.load(DIFFDRIVE)
    system = compile_system(arch, "a1", seed=1, scenario="nominal")
    for _ in range(50):
        system.step()
    calls = [0]

    def stub(out: dict[str, Any]) -> Any:
        def give(*_args: Any) -> dict[str, Any]:
            calls[0] += 1
            return {k: v + calls[0] * 1e-12 if isinstance(v, (float, np.ndarray)) else v
                    for k, v in out.items()}
        return give

    stubs = []
    for name, mod in system.modules.items():
        mod.step = mod.output = stub(dict(system.outputs.get(name, {})))
        stubs.append(mod.step)
    best = alone = math.inf
    for _ in range(rounds):
        best = min(best, _cpu(lambda: [system.step() for _ in range(steps)]))
        alone = min(alone, _cpu(lambda: [f(0.0, 0.05, {}) for _ in range(steps) for f in stubs]))
    return best, alone


def module_cpu(seed: int = 2, rounds: int = 3) -> dict[str, float]:
    """µs a step of each module of a fixed a1 run: its calls of one run recorded, then
    replayed on a fresh copy of the module (best of ``rounds``); and the step's parts
    around them: the executor (:func:`plumbing_cpu`), ``recording`` (``simulate``'s loop
    besides ``LiveSystem.step``) and, part of the executor, the health checks
    the generated step keeps (from switching ``needs_checks`` off; not in the sum)."""
    import archself
    import archself.system.live as live
    from archself.sim import run as simrun

    arch = archself.load(DIFFDRIVE)
    n = 8000
    system = live.compile_system(arch, "a1", seed=seed, scenario="nominal")
    fresh = {name: copy.deepcopy(m) for name, m in system.pool().items()}
    calls: dict[str, list[tuple[str, tuple[Any, ...]]]] = {name: [] for name in fresh}
    def spy(f: Any, c: list, m: str) -> Any:
        def call(*a: Any) -> Any:
            c.append((m, a))
            return f(*a)
        return call

    for name, mod in system.pool().items():
        for meth in ("step", "output"):
            setattr(mod, meth, spy(getattr(mod, meth), calls[name], meth))
    for _ in range(n):
        system.step()
    out: dict[str, float] = {}
    for name, made in calls.items():
        best = math.inf
        for _ in range(rounds):
            mod = copy.deepcopy(fresh[name])
            fns = {"step": mod.step, "output": mod.output}
            best = min(best, _cpu(lambda fns=fns, made=made: [fns[m](*a) for m, a in made]))
        out[name] = best / n * 1e6

    def stepping(checks: bool) -> float:
        s = live.compile_system(arch, "a1", seed=seed, scenario="nominal")
        keep, live.needs_checks = live.needs_checks, (live.needs_checks if checks
                                                       else lambda *_a: False)
        try:
            s.step()
        finally:
            live.needs_checks = keep
        return _cpu(lambda: [s.step() for _ in range(n - 1)]) / (n - 1) * 1e6

    def looping() -> float:
        run = simrun._plan(arch, "nominal", "a1", seed, None, None, None)
        return _cpu(lambda: simrun._step(run, None, None)) / n * 1e6

    step = min(stepping(True) for _ in range(rounds))
    executor, stubs = plumbing_cpu(n, rounds)
    out["executor (modules stubbed)"] = (executor - stubs) / n * 1e6
    out["recording"] = min(looping() for _ in range(rounds)) - step
    out["(of the executor: health)"] = step - min(stepping(False) for _ in range(rounds))
    return out


#: The floor's sections (its comment lines) -> the framework's modules they do the work of
SECTIONS = {"# encoders, IMU and GPS": "encoders, imu, gps",
            "# dead reckoning": "odometry", "# LQR and its": "lqr",
            "# the wheels' command error": "wheel_left, wheel_right (+ recording)",
            "# chassis": "chassis"}


def floor_sections(seed: int = 2, rounds: int = 5) -> dict[str, float]:
    """µs a step of each section of :func:`run_floor_same_work` (its comment lines,
    :data:`SECTIONS`): a timer (``perf_counter_ns``, ≈ 0.1 µs a section) inserted
    before each, best of ``rounds`` per section. An estimate: wall time."""
    import inspect

    S, W = load_setup(), load_work()
    lines, names = [], ["J, reference, actual (recording)"]
    for line in inspect.getsource(run_floor_same_work).splitlines():
        text = line.strip()
        hit = next((v for k, v in SECTIONS.items() if text.startswith(k)), None)
        if hit is not None or text.startswith("t = (np.arange(n) + 1) * dt"):
            lines.append(" " * 8 + f"_t1 = _pc(); _acc[{len(names) - 1}] += _t1 - _t0; _t0 = _t1")
            names += [hit] if hit else []
        lines.append(line)
        if text.startswith("for k in range(n):"):
            lines.append(" " * 8 + "_t0 = _pc()")
    space = dict(vars(sys.modules["floor_diffdrive"]))
    acc = space["_acc"] = [0] * len(names)
    space["_pc"] = time.perf_counter_ns
    exec(compile("\n".join(lines), "<floor sections>", "exec"), space)  # noqa: S102
    best = [math.inf] * len(names)
    for _ in range(rounds):
        acc[:] = [0] * len(names)
        space["run_floor_same_work"](seed, S, W)
        best = [min(b, a / S.steps / 1e3) for b, a in zip(best, acc, strict=True)]
    return dict(zip(names, best, strict=True))


def by_module(seed: int = 2) -> None:
    """Print the framework's µs a step by module beside the floor's sections (fixed a1)."""
    fw, fl = module_cpu(seed), floor_sections(seed)
    print(f"fixed a1, seed {seed}: µs a step, framework by module (replayed calls), "
          f"load {os.getloadavg()[0]:.2f}")
    for name, us in fw.items():
        print(f"  {name:34} {us:6.2f}")
    print(f"  {'sum':34} {sum(v for k, v in fw.items() if not k.startswith('(')):6.2f}")
    print("the floor by section (timers inserted)")
    for name, us in fl.items():
        print(f"  {name:34} {us:6.2f}")
    print(f"  {'sum':34} {sum(fl.values()):6.2f}")


def main(argv: Sequence[str] | None = None) -> None:
    """The framework's per run against the same-work floors, fixed a1 and adaptive."""
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3, 4])
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds per seed")
    ap.add_argument("--by-module", action="store_true",
                    help="µs a step by module (framework) and by section (floor), fixed a1")
    args = ap.parse_args(argv)
    if args.by_module:
        by_module(args.seeds[0])
        return

    import archself
    from archself.runtime import MapeK

    arch = archself.load(DIFFDRIVE)
    S, W, A = load_setup(), load_work(), load_adaptive()
    sw = {s: framework_switches(s) for s in args.seeds}
    for s in args.seeds:  # warm: imports, gain caches; and the trace check
        fw = archself.simulate(arch, SCENARIO, seed=s, adapt=MapeK(arch))
        fl = run_floor_adaptive(s, sw[s], S, W, A)
        same = np.array_equal(fw.series["J"], fl["J"])
        print(f"adaptive seed {s}: switches {sw[s]}, J bit for bit: {same}")
    fixed_fw = lambda s: archself.simulate(arch, "nominal", configuration="a1", seed=s)  # noqa: E731
    rows: dict[str, list[float]] = {k: [] for k in ("fw a1", "floor a1", "fw ad", "floor ad")}
    load0 = os.getloadavg()
    for _ in range(args.rounds):
        for s in args.seeds:
            rows["fw a1"].append(_cpu(lambda s=s: fixed_fw(s)))
            rows["floor a1"].append(_cpu(lambda s=s: run_floor_same_work(s, S, W)))
            rows["fw ad"].append(_cpu(lambda s=s: archself.simulate(
                arch, SCENARIO, seed=s, adapt=MapeK(arch))))
            rows["floor ad"].append(_cpu(lambda s=s: run_floor_adaptive(s, sw[s], S, W, A)))
    med = {k: statistics.median(v) for k, v in rows.items()}
    print(f"load average {load0[0]:.2f} -> {os.getloadavg()[0]:.2f}; seeds {args.seeds}, "
          f"{args.rounds} rounds; CPU per run, median")
    for kind, label in (("a1", "fixed a1 (nominal)"), ("ad", "adaptive imu_drift")):
        f, fl = med[f"fw {kind}"], med[f"floor {kind}"]
        print(f"{label:22} framework {f:.3f} s  floor {fl:.3f} s  framework/floor {f / fl:.2f}x")
    step, stubs = plumbing_cpu()
    print(f"executor plumbing over a1's 8000 steps (modules stubbed): {step - stubs:.3f} s "
          f"({(step - stubs) / 8000 / 12 * 1e6:.2f} us per module-step)")


if __name__ == "__main__":
    main()
