"""The LQR controllers in N lanes: the symmetric and the asymmetric (adaptive) one, batched.

:class:`LqrControllerLanes` and :class:`AsymLqrControllerLanes` are the
:class:`~archself.lanes.LaneModule` classes of
:class:`~archself_diffdrive.controllers.LqrController` and
:class:`~archself_diffdrive.controllers.AsymLqrController`. Each lane keeps its own
reference speed and its own 2×3 gain; the gains are the lane instances' own
(:meth:`~archself_diffdrive.controllers.LqrController.gain`, python-control, cached
per instance), fetched when a lane's reference speed moves by more than 5 mm/s, so
a sweep over the weights keeps its gains per lane. The tracking error, the
feed-forward, the wheel speeds of the lane's kinematic model, the common scaling
to the actuator's speed limit and the effectiveness estimate (recursive least
squares with the lane's forgetting factor, clipped to ``[min_effectiveness, 1]``)
are the per-run float operations in the same order, on arrays (the residual
``tracking_error`` by ``np.hypot``: the last bit may differ). A lane without a
reference or a pose estimate repeats its last command (absent before the first);
a lane whose command is not finite is reported as failed (the executor holds its
last one), as the per-run system does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from archself.lanes.module import LaneModule, ModelFields
from archself_diffdrive.lanes_estimators import kinematics_fields

__all__ = ["AsymLqrControllerLanes", "LqrControllerLanes"]

PI = math.pi
TWO_PI = 2.0 * math.pi


class LqrControllerLanes(LaneModule):
    """:class:`~archself_diffdrive.controllers.LqrController` in N lanes (see the module doc)."""

    def __init__(self, modules: Sequence[Any]) -> None:
        n = len(modules)
        self.kin = kinematics_fields()
        self.limit = ModelFields({"max_wheel_speed_rad_s": math.inf})  # none: no limit
        self.v_ref = np.zeros(n)
        self.K = np.zeros((n, 2, 3))
        self.last_cmd = np.full((n, 2), math.nan)  # NaN: None (nothing commanded yet)
        self.tracking_error = np.full(n, math.nan)
        self.dynamics: list[Any] = [None] * n
        self._dynamics_in: Any = None  # (lanes, objects) of the last dynamics input taken
        super().__init__(modules)

    # ------------------------------------------------------------------ a step
    def _take_dynamics(self, dyn: list[Any] | None, idx: np.ndarray) -> None:
        """``dynamics = input or dynamics`` per lane (the model object only the API reads)."""
        if dyn is None:
            return
        key = (idx.tobytes(), dyn)
        if key == self._dynamics_in:
            return
        for i, d in zip(idx.tolist(), dyn, strict=True):
            if d is not None:
                self.dynamics[i] = d
        self._dynamics_in = (key[0], list(dyn))

    def _body_command(self, ref, est, idx) -> tuple[np.ndarray, np.ndarray]:
        """``(v, ω)`` of rows ``ref``/``est`` of lanes ``idx`` (``LqrController.body_command``)."""
        v_ref = ref[:, 3]
        moved = np.abs(v_ref - self.v_ref[idx]) > 0.005
        if moved.any():
            for i, v in zip(idx[moved].tolist(), v_ref[moved].tolist(), strict=True):
                self.v_ref[i] = v
                self.K[i] = self.modules[i].gain(v)
        dx = est[:, 0] - ref[:, 0]
        dy = est[:, 1] - ref[:, 1]
        thr = ref[:, 2]
        c, s = np.cos(thr), np.sin(thr)
        e0 = c * dx + s * dy
        e1 = -s * dx + c * dy
        e2 = (est[:, 2] - thr + PI) % TWO_PI - PI
        K = self.K[idx]
        du0 = K[:, 0, 0] * e0 + K[:, 0, 1] * e1 + K[:, 0, 2] * e2
        du1 = K[:, 1, 0] * e0 + K[:, 1, 1] * e1 + K[:, 1, 2] * e2
        self.tracking_error[idx] = np.hypot(dx, dy)
        return v_ref - du0, ref[:, 4] - du1

    @staticmethod
    def _wheel_speeds(v, w, r, base) -> tuple[np.ndarray, np.ndarray]:
        half = w * base / 2.0
        return (v - half) / r, (v + half) / r

    @staticmethod
    def _limit(left, right, lim) -> np.ndarray:
        """``[l, r]`` rows, both wheels scaled together where the faster exceeds ``lim``."""
        peak = np.maximum(np.abs(left), np.abs(right))
        over = peak > lim
        if over.any():
            left, right, lim, peak = left.copy(), right.copy(), lim[over], peak[over]
            left[over] = left[over] * lim / peak
            right[over] = right[over] * lim / peak
        return np.stack([left, right], axis=1)

    def _command(self, inputs, idx, cmd_of) -> np.ndarray:
        """The commands of lanes ``idx`` (the last one where a lane lacks its inputs).

        ``cmd_of(v, ω, r, base, lim, sub)`` gives the command of the lanes ``sub`` with
        both inputs.
        """
        self._take_dynamics(inputs.get("dynamics"), idx)
        ref = inputs.get("reference")
        est = inputs.get("pose_estimate")
        cmd = self.last_cmd[idx]
        if ref is None or est is None:
            return cmd
        n = len(idx)
        r, base = self.kin(inputs.get("kinematics"), n)
        (lim,) = self.limit(inputs.get("actuation"), n)
        ok = ~(np.isnan(ref[:, 0]) | np.isnan(est[:, 0]))
        if ok.all():
            cmd = cmd_of(*self._body_command(ref, est, idx), r, base, lim, idx)
        elif ok.any():
            v, w = self._body_command(ref[ok], est[ok], idx[ok])
            cmd[ok] = cmd_of(v, w, r[ok], base[ok], lim[ok], idx[ok])
        self.last_cmd[idx] = cmd
        return cmd

    def _publish(self, cmd: np.ndarray, idx: np.ndarray) -> dict[str, Any]:
        """``wheel_cmd`` (None if no lane has one); non-finite commands reported as failed."""
        absent = np.isnan(cmd[:, 0])
        if math.isfinite(float(cmd.sum())):
            return {"wheel_cmd": cmd}
        bad = ~np.isfinite(cmd).all(1) & ~absent  # a NaN row is a lane without a command
        self.failed.update({int(i): "non-finite output" for i in idx[bad]})
        return {"wheel_cmd": None if absent.all() else cmd}

    def step(self, t, dt, inputs, lanes):
        def cmd_of(v, w, r, base, lim, sub):
            return self._limit(*self._wheel_speeds(v, w, r, base), lim)

        idx = self.indices(lanes)
        return self._publish(self._command(inputs, idx, cmd_of), idx)

    def local_signals(self, lanes):
        return {"tracking_error": self.tracking_error[lanes].copy()}

    # ------------------------------------------------------------------ the per-run bridge
    def load(self, lanes):
        for i in self.indices(lanes):
            m = self.modules[i]
            self.v_ref[i] = m.v_ref
            self.K[i] = m.K
            self.last_cmd[i] = math.nan if m.last_cmd is None else m.last_cmd
            self.tracking_error[i] = m.signals["tracking_error"]
            self.dynamics[i] = m.dynamics
        self._dynamics_in = None

    def store(self, lanes):
        for i in self.indices(lanes):
            m = self.modules[i]
            m.v_ref = float(self.v_ref[i])
            m.K = m.gain(m.v_ref)
            cmd = self.last_cmd[i]
            m.last_cmd = None if math.isnan(cmd[0]) else cmd.copy()
            m.signals["tracking_error"] = float(self.tracking_error[i])
            m.dynamics = self.dynamics[i]


class AsymLqrControllerLanes(LqrControllerLanes):
    """:class:`~archself_diffdrive.controllers.AsymLqrController` in N lanes."""

    def __init__(self, modules: Sequence[Any]) -> None:
        n = len(modules)
        self.eff = np.ones((n, 2))
        self.num = np.zeros((n, 2))
        self.den = np.zeros((n, 2))
        self.sent = np.full((n, 2), math.nan)  # NaN: None (no command sent last step)
        self.lam = np.ones(n)
        self.lam_of = np.full(n, math.nan)  # NaN: None (the dt of lam)
        super().__init__(modules)

    def _adapt(self, dt: float, enc: np.ndarray, idx: np.ndarray) -> None:
        """``AsymLqrController._adapt`` in lanes ``idx`` (their ``enc`` rows)."""
        stale = self.lam_of[idx] != dt
        if stale.any():
            for i in idx[stale].tolist():
                self.lam_of[i] = dt
                self.lam[i] = math.exp(-dt / self.tau[i])
        lam = self.lam[idx, None]
        c = self.sent[idx]
        num = lam * self.num[idx] + c * enc
        den = lam * self.den[idx] + c * c
        with np.errstate(divide="ignore", invalid="ignore"):
            est = np.where(den > 1e-3, num / den, 1.0)
        self.eff[idx] = np.minimum(np.maximum(est, self.emin[idx, None]), 1.0)
        self.num[idx], self.den[idx] = num, den

    def step(self, t, dt, inputs, lanes):
        idx = self.indices(lanes)
        enc = inputs.get("encoder_speeds")
        if enc is not None:
            go = ~(np.isnan(enc[:, 0]) | np.isnan(self.sent[idx, 0]))
            if go.any():
                self._adapt(dt, enc[go], idx[go])

        def cmd_of(v, w, r, base, lim, sub):
            left, right = self._wheel_speeds(v, w, r, base)
            eff = self.eff[sub]
            return self._limit(left / eff[:, 0], right / eff[:, 1], lim)

        cmd = self._command(inputs, idx, cmd_of)
        self.sent[idx] = cmd  # the command sent, or the last one repeated
        return self._publish(cmd, idx)

    def load(self, lanes):
        super().load(lanes)
        for i in self.indices(lanes):
            m = self.modules[i]
            self.eff[i], self.num[i], self.den[i] = m._eff, m._num, m._den
            self.sent[i] = math.nan if m._sent is None else m._sent
            self.lam[i] = m._lam
            self.lam_of[i] = math.nan if m._lam_of is None else m._lam_of
        self.tau = self.lane_attr("_tau")
        self.emin = self.lane_attr("_emin")

    def store(self, lanes):
        super().store(lanes)
        for i in self.indices(lanes):
            m = self.modules[i]
            m._eff, m._num = self.eff[i].tolist(), self.num[i].tolist()
            m._den = self.den[i].tolist()
            m._sent = None if math.isnan(self.sent[i, 0]) else tuple(self.sent[i].tolist())
            m._lam = float(self.lam[i])
            lam_of = float(self.lam_of[i])
            m._lam_of = None if math.isnan(lam_of) else lam_of
