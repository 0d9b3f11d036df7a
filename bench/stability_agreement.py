"""Does the whole-loop verdict predict the simulation? A sweep on the shipped files.

For each variant (a controller gain, a plant parameter, an edge latency or a sign
flip, within and past the declared ranges) of one configuration per shipped file (and
the robot's marginal a1):

- the verdict of ``validate``'s whole-loop check (:func:`archself.check.stability.loop_verdict`
  after ``runtime.stability.settle_s``; diffdrive over ``linearize_s``);
- the simulation: from the same point, two fixed runs (``T_S`` seconds; 200 s for the
  robot's slow GPS loop), one with
  every module's state offset by 1e-3·max(1, |x|), the same noise; ``growth`` =
  ‖Δx(T)‖ / ‖Δx(0)‖ over the loop's whole state. The run *settles* when growth < 1,
  *diverges or oscillates* when growth > 2 or a state is not finite, is *level*
  between (a marginal mode keeps an offset).

Agreement: unstable ↔ diverges/oscillates, verified ↔ settles, marginal ↔ level or
settles. Prints a markdown table (docs/stability.md).

Usage::

    python bench/stability_agreement.py [FILE.yaml ...]
"""

from __future__ import annotations

import math
import sys
import warnings
from typing import Any

import numpy as np

from archself.check.stability import loop_verdict, map_steps
from archself.model.loader import load_architecture
from archself.resources import data_dir
from archself.system.live import compile_system

T_S = 20.0

VARIANTS: dict[str, tuple[str, float, list[tuple[str, list[tuple[str, str, Any]]]]]] = {
    "motor_drive.yaml": ("m1", T_S, [
        ("nominal", []),
        ("pi.kp = 5", [("param", "pi.kp", 5.0)]),
        ("pi.kp = 10 (max)", [("param", "pi.kp", 10.0)]),
        ("pi.kp = 40 (past max)", [("param", "pi.kp", 40.0)]),
        ("pi.ki = 10 (max)", [("param", "pi.ki", 10.0)]),
        ("pi.kp = −1 (sign flip)", [("param", "pi.kp", -1.0)]),
        ("tacho → kf latency 0.2 s", [("latency", "tacho", 0.2)]),
    ]),
    "process_plant.yaml": ("p1", T_S, [
        ("nominal", []),
        ("pi.kp = 50 (max)", [("param", "pi.kp", 50.0)]),
        ("pi.kp = 500 (past max)", [("param", "pi.kp", 500.0)]),
        ("pi.ki = 5 (max)", [("param", "pi.ki", 5.0)]),
        ("pi.kp = −3 (sign flip)", [("param", "pi.kp", -3.0)]),
        ("tank.area_m2 = 0.05", [("param", "tank.area_m2", 0.05)]),
    ]),
    # the GPS loop is slow (0.99948 per step: a time constant of ~100 s): 200 s
    "diffdrive.yaml": ("a2", 200.0, [
        ("nominal", []),
        ("chassis.wheel_time_constant_s = 2 (max)",
         [("param", "chassis.wheel_time_constant_s", 2.0)]),
        ("chassis.wheel_radius_m = −0.1 (sign flip)",
         [("param", "chassis.wheel_radius_m", -0.1)]),
        ("gps → ekf latency 1 s, linearize_s 1.2 (the span misses the fix)",
         [("latency", "gps", 1.0)]),
        ("gps → ekf latency 1 s, linearize_s 2.2",
         [("latency", "gps", 1.0), ("span", "", 2.2)]),
        ("lqr_fused.q_lateral = 10 (100× the file's)", [("param", "lqr_fused.q_lateral", 10.0)]),
        ("lqr_fused.r_speed = r_turn = 1e-4 (min)",
         [("param", "lqr_fused.r_speed", 1e-4), ("param", "lqr_fused.r_turn", 1e-4)]),
        ("a1 (dead reckoning), nominal", [("conf", "", "a1")]),
    ]),
}


def _variant(fname: str, changes: list[tuple[str, str, Any]]) -> Any:
    arch = load_architecture(data_dir("architectures") / fname).arch
    for kind, what, value in changes:
        if kind == "param":
            mod, name = what.split(".")
            arch.modules[mod].params[name].value = value
        elif kind == "conf":
            continue  # the configuration: main() reads it
        elif kind == "span":
            arch.runtime.stability.linearize_s = value
        else:  # latency on every edge out of the module
            for e in arch.edges:
                if e.source == what:
                    e.latency_s = value
    return arch


def _loop_state(system: Any) -> np.ndarray:
    parts = [type(m).state(m) for m in system.modules.values()]
    return np.concatenate(parts) if parts else np.zeros(0)


def _growth(arch: Any, conf: str, seconds: float) -> tuple[float, float]:
    """``(growth after 1 s, growth after seconds)`` of an offset of the loop's state."""
    base = compile_system(arch, conf, seed=0)
    base.step()
    base.run(float(arch.runtime.stability.settle_s))
    runs = []
    for shift in (False, True):
        s = base.snapshot()
        if shift:
            for m in s.modules.values():
                x = type(m).state(m)
                if x.size:
                    type(m).set_state(m, x + 1e-3 * np.maximum(1.0, np.abs(x)))
        x0 = _loop_state(s)
        s.run(1.0)
        x1 = _loop_state(s)
        s.run(seconds - 1.0)
        runs.append((x0, x1, _loop_state(s)))
    d0 = np.linalg.norm(runs[1][0] - runs[0][0])
    out = [np.linalg.norm(runs[1][i] - runs[0][i]) / d0 for i in (1, 2)]
    return tuple(float(g) if math.isfinite(g) else math.inf for g in out)  # type: ignore[return-value]


def main() -> int:
    only = set(sys.argv[1:])
    print("| file | configuration | variant | verdict | max abs(λ) per step | growth after "
          "1 s | growth of an offset (after) | simulation | agree |")
    print("| --- | --- | --- | --- | ---: | ---: | ---: | --- | --- |")
    for fname, (default, seconds, variants) in VARIANTS.items():
        if only and fname not in only:
            continue
        for label, changes in variants:
            arch = _variant(fname, changes)
            conf = next((v for k, _, v in changes if k == "conf"), default)
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                system = compile_system(arch, conf, seed=0)
                system.step()
                system.run(float(arch.runtime.stability.settle_s))
                v = loop_verdict(system, conf, map_steps(arch))
                early, g = _growth(arch, conf, seconds)
            sim = ("diverges/oscillates" if not g < 2 else "settles" if g < 1 else "level")
            agree = {"unstable": sim == "diverges/oscillates", "verified": sim == "settles",
                     "marginal": sim != "diverges/oscillates"}.get(v.verdict, False)
            lam = "—" if v.max_lambda is None else f"{v.max_lambda:.6f}"
            print(f"| {fname} | {conf} | {label} | {v.verdict} | {lam} | {early:.3g} "
                  f"| {g:.3g} ({seconds:g} s) "
                  f"| {sim} | {'yes' if agree else 'NO'} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
