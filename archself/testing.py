"""Conformance checks a module pack runs in its own tests.

:func:`check_pack` proves a pack's batched (lane) classes equal its per-run classes:
every module type of an architecture file that names a ``lanes`` class must give
:class:`~archself.contracts.BatchedModule`, and every scenario run as lanes
(:func:`~archself.lanes.run.simulate_lanes`) must give the per-run runs
(:func:`~archself.sim.run.simulate`), fixed and with the MAPE-K loop: the same
switches at the same times, the same module faults (``RunResult.faults``) and every
recorded series and metric within ``atol``; and
each batched class's per-lane ``state()`` must equal its per-run twin's state vector
(the layout the whole-loop linearization perturbs, docs/stability.md).
The in-repo packs (tests/test_packs.py) and the example plugin
(``plugins/archself-example``) run it as a third party would::

    from archself.testing import check_pack

    def test_my_pack_lanes_equal_per_run():
        check_pack("examples/my_system.yaml", seeds=(0, 1, 2), duration_s=30)

Examples
--------
>>> from archself.resources import data_dir
>>> report = check_pack(data_dir("architectures") / "process_plant.yaml",
...                     scenarios=["nominal"], seeds=(1, 2), duration_s=5, adaptive=False)
>>> report.ok, report.runs
(True, 2)
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from archself.contracts import BatchedModule
from archself.errors import ArchselfError
from archself.model.architecture import Architecture
from archself.model.loader import load_architecture

__all__ = ["PackMismatch", "PackReport", "check_pack"]


class PackMismatch(ArchselfError, AssertionError):
    """A pack's batched classes do not behave as its per-run classes (:func:`check_pack`)."""


@dataclass
class PackReport:
    """What :func:`check_pack` compared and what differed.

    Attributes
    ----------
    types : dict of str to str
        Module type → its batched class (``"PerLane"`` where the type has none).
    runs : int
        Lane runs compared with their per-run twins.
    problems : list of str
        One line per difference (empty when the pack conforms).
    """

    types: dict[str, str] = field(default_factory=dict)
    runs: int = 0
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when nothing differed."""
        return not self.problems


def check_pack(
    arch: Any,
    *,
    scenarios: Iterable[str] | None = None,
    seeds: Sequence[int] = (0, 1, 2),
    duration_s: float | None = None,
    fixed: bool = True,
    adaptive: bool = True,
    atol: float = 1e-9,
    raise_on_error: bool = True,
) -> PackReport:
    """Check that lanes of ``arch`` equal its per-run runs, type by type and run by run.

    Parameters
    ----------
    arch : Architecture or path
        An architecture (or its file) made of the pack's module types.
    scenarios : iterable of str, optional
        Scenarios to run (default: every scenario of the file).
    seeds : sequence of int
        One lane per seed.
    duration_s : float, optional
        Cut every scenario to this duration (a test's budget); faults after it are
        not exercised.
    fixed, adaptive : bool
        Compare fixed runs (the initial configuration), runs with the MAPE-K loop, or both.
    atol : float
        Largest absolute difference of a series or metric value (the batched classes'
        last bits; 0 demands bit-for-bit equality).
    raise_on_error : bool
        Raise :class:`PackMismatch` listing the differences (for tests); otherwise
        return them in the report.

    Returns
    -------
    PackReport
    """
    from archself.lanes.run import simulate_lanes
    from archself.runtime.mapek import MapeK
    from archself.sim.run import simulate

    if not isinstance(arch, Architecture):
        if not isinstance(arch, (str, PathLike)):
            raise TypeError(f"check_pack: arch must be an Architecture or a path, got "
                            f"{type(arch).__name__}")
        arch = load_architecture(Path(arch)).arch
    if duration_s is not None:
        arch = arch.model_copy(update={"scenarios": {
            name: sc.model_copy(update={"duration_s": min(float(duration_s), sc.duration_s)})
            for name, sc in arch.scenarios.items()}})
    report = PackReport()
    _check_types(arch, report)
    _check_states(arch, list(seeds), report, atol)
    modes = [m for m, on in (("fixed", fixed), ("adaptive", adaptive)) if on]
    for scenario in list(scenarios) if scenarios is not None else list(arch.scenarios):
        for mode in modes:
            loop = mode == "adaptive"
            got = simulate_lanes(arch, scenario, list(seeds), adapt=loop)
            for lane, seed in zip(got, seeds, strict=True):
                want = simulate(arch, scenario, seed=seed, adapt=MapeK(arch) if loop else None)
                where = f"{scenario} {mode} seed {seed}"
                report.problems += [f"{where}: {p}" for p in _differences(lane, want, atol)]
                report.runs += 1
    if report.runs == 0:  # nothing compared is a finding, not a pass
        report.problems.append("no run compared: no scenario, no seed, or neither fixed nor "
                               "adaptive; lanes and per-run runs were not checked")
    if report.problems and raise_on_error:
        head = f"{len(report.problems)} difference(s) between lanes and per-run runs"
        raise PackMismatch(head + ":\n  " + "\n  ".join(report.problems[:20]))
    return report


def _check_types(arch: Any, report: PackReport) -> None:
    """Every module type of ``arch`` gives a :class:`BatchedModule` (its class in ``report``)."""
    from archself.lanes.batching import lane_module
    from archself.system.live import build_module

    for name, spec in arch.modules.items():
        try:
            lanes = lane_module([build_module(arch, name, seed=0)])
        except ArchselfError as exc:
            report.problems.append(f"{spec.type}: {exc}")
            continue
        report.types[spec.type] = type(lanes).__name__
        if not isinstance(lanes, BatchedModule):
            report.problems.append(f"{spec.type}: its lanes class {type(lanes).__name__} is "
                                   "not a BatchedModule (archself.contracts)")


def _check_states(arch: Any, seeds: list[int], report: PackReport, atol: float,
                  steps: int = 20) -> None:
    """Each batched class's per-lane state equals its per-run twin's ``state()`` vector.

    The initial configuration is compiled once per seed as lanes and once per seed per
    run, both stepped ``steps`` times; every module whose lanes class is not
    ``PerLane`` (whose lanes are the per-run instances themselves) is compared, through
    both its array state (``state()``, where the class declares ``state_rows``) and the
    per-run bridge (``bridged_state()``: a ``store`` that leaves a state out).
    """
    from archself.lanes.module import PerLane
    from archself.lanes.system import LaneSystem
    from archself.system.live import compile_system

    if not seeds:
        return
    try:
        lanes = LaneSystem([compile_system(arch, seed=s) for s in seeds])
        twins = [compile_system(arch, seed=s) for s in seeds]
        for _ in range(steps):
            lanes.step()
            for twin in twins:
                twin.step()
    except ArchselfError as exc:
        report.problems.append(f"state check: the initial configuration did not run: {exc}")
        return
    for name, mod in lanes.modules.items():
        if isinstance(mod, PerLane):
            continue
        try:
            views = [mod.state(), mod.bridged_state()]
        except ArchselfError as exc:
            report.problems.append(f"{name}: state() of its lanes class failed: {exc}")
            continue
        for j, twin in enumerate(twins):
            want = twin._module(name).state()
            got = next((v[j] for v in views if v[j].shape != want.shape or not np.allclose(
                v[j], want, rtol=0.0, atol=atol, equal_nan=True)), None)
            if got is not None:
                report.problems.append(
                    f"{name} ({type(mod).__name__}), seed {seeds[j]}: lane state "
                    f"{np.round(got, 12).tolist()} after {steps} steps, per run "
                    f"{np.round(want, 12).tolist()}")


def _differences(got: Any, want: Any, atol: float) -> list[str]:
    """What differs between a lane's run and its per-run twin (empty when they agree)."""
    out = []
    if got.final_configuration != want.final_configuration:
        out.append(f"ends in {got.final_configuration}, per run in {want.final_configuration}")
    if [(s.get("t"), s.get("to")) for s in got.switches] != \
            [(s.get("t"), s.get("to")) for s in want.switches]:
        out.append(f"switches {got.switches} differ from the per-run {want.switches}")
    if got.faults != want.faults:
        out.append(f"module faults {got.faults} differ from the per-run {want.faults}")
    for key in sorted(set(want.series) | set(got.series)):
        if key not in got.series or key not in want.series:
            out.append(f"series {key!r} recorded by one side only")
            continue
        a = np.asarray(got.series[key], dtype=float)
        b = np.asarray(want.series[key], dtype=float)
        if a.shape != b.shape:
            out.append(f"series {key!r}: shape {a.shape}, per run {b.shape}")
            continue
        bad = ~np.isclose(a, b, rtol=0.0, atol=atol, equal_nan=True)
        if bad.any():
            k = int(bad.argmax())  # the first differing value (flattened: step-major)
            out.append(f"series {key!r} differs first at step {k // max(1, a[0].size)}: "
                       f"{float(a.flat[k])!r}, per run {float(b.flat[k])!r}")
    for key, b in want.metrics.items():
        a = got.metrics.get(key, math.nan)
        if not (math.isnan(a) and math.isnan(b)) and not abs(a - b) <= atol:
            out.append(f"metric {key}: {a!r}, per run {b!r}")
    return out
