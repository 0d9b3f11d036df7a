"""The core runs without the shipped packs: types come only through entry points.

``tests/packs/`` holds a test pack (``toy_pack``) with its own
``toy_pack-0.1.dist-info/entry_points.txt``; putting that folder on the path is
how a third-party pack would be installed. The subprocess makes the shipped packs
unimportable, so the run can only pass if the core imports none of them.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from archself.model.loader import load_architecture
from archself.testing import PackMismatch, check_pack

from conftest import ROOT

PACKS = ("archself_diffdrive", "archself_process", "archself_blocks")
TOY = ROOT / "tests" / "packs"

_SCRIPT = f"""
import json, sys
for name in {PACKS!r}:
    sys.modules[name] = None  # any import of a shipped pack now fails
from archself import registry
from archself.check import check, has_errors
from archself.model.loader import load_architecture
from archself.runtime import MapeK
from archself.sim.run import simulate

loaded = load_architecture(sys.argv[1])
findings = check(loaded)
arch = loaded.arch
res = simulate(arch, "weak_drive", adapt=MapeK(arch))
fixed = simulate(arch, "weak_drive")
print(json.dumps({{
    "errors": [f.message for f in findings if f.severity == "error"],
    "switches": [(s["from"], s["to"], s["action"]) for s in res.switches],
    "final": [res.series["J"][-1], fixed.series["J"][-1]],
    "toy_types": sorted(k for k in registry.known_types() if k.startswith("toy.")),
    "loaded_packs": sorted(m for m in sys.modules if m.split(".")[0] in {PACKS!r}
                           and sys.modules[m] is not None),
}}))
"""


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(TOY)}
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=120)


def test_core_runs_an_architecture_of_a_test_packs_types_only() -> None:
    proc = _run("-c", _SCRIPT, str(TOY / "toy.yaml"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout)
    assert out["errors"] == []
    assert out["toy_types"] == ["toy.controller", "toy.plant", "toy.reference", "toy.sensor"]
    assert out["loaded_packs"] == []
    # the loop diagnoses the weak drive and switches to the stronger controller ...
    assert out["switches"] == [["normal", "strong", "strengthen"]]
    # ... which ends with a fraction of the fixed run's tracking error
    adaptive, fixed = out["final"]
    assert fixed > 0.3 and adaptive < 0.1 * fixed


def test_cli_validates_and_simulates_with_the_packs_blocked() -> None:
    blocked = "; ".join(f"sys.modules[{p!r}] = None" for p in PACKS)
    main = f"import sys; {blocked}; from archself.cli import main; sys.exit(main())"
    proc = _run("-c", main, "validate", str(TOY / "toy.yaml"))
    assert proc.returncode == 0, proc.stderr
    proc = _run("-c", main, "simulate", str(TOY / "toy.yaml"), "-s", "nominal", "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["runs"][0]["switches"] == []


def test_a_file_of_a_blocked_pack_gets_a_message_not_a_traceback() -> None:
    blocked = "; ".join(f"sys.modules[{p!r}] = None" for p in PACKS)
    main = f"import sys; {blocked}; from archself.cli import main; sys.exit(main())"
    proc = _run("-c", main, "validate", str(ROOT / "architectures" / "diffdrive.yaml"))
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr
    assert "failed to load" in proc.stderr


# ---------------------------------------------------------------- lanes equal per-run runs
@pytest.mark.parametrize(("path", "duration_s"), [
    ("architectures/diffdrive.yaml", 80.0),
    ("architectures/process_plant.yaml", 60.0),
    ("architectures/motor_drive.yaml", 30.0),
])
def test_shipped_packs_pass_check_pack(path, duration_s) -> None:
    """Every type of the shipped packs batches, and lanes give the per-run runs."""
    report = check_pack(ROOT / path, seeds=(1, 2), duration_s=duration_s)
    assert report.ok and report.runs == 2 * 2 * len(load_architecture(ROOT / path).arch.scenarios)
    assert "PerLane" not in report.types.values()


def test_check_pack_finds_a_lane_class_that_drifts(monkeypatch) -> None:
    """A batched class 1e-6 off its per-run class is a PackMismatch naming the series."""
    from archself_blocks.lanes_control import PidLanes

    step = PidLanes.step

    def off(self, t, dt, inputs, lanes):
        out = step(self, t, dt, inputs, lanes)
        return {k: (v + 1e-6 if isinstance(v, np.ndarray) else v) for k, v in out.items()}

    monkeypatch.setattr(PidLanes, "step", off)
    with pytest.raises(PackMismatch, match=r"(?s)between lanes.*series 'J' differs first"):
        check_pack(ROOT / "architectures/motor_drive.yaml", scenarios=["nominal"], seeds=(1,),
                   duration_s=5.0, adaptive=False)
    report = check_pack(ROOT / "architectures/motor_drive.yaml", scenarios=["nominal"],
                        seeds=(1,), duration_s=5.0, adaptive=False, raise_on_error=False)
    assert not report.ok and report.runs == 1


def test_check_pack_that_compares_nothing_is_not_a_pass() -> None:
    with pytest.raises(PackMismatch, match="no run compared"):
        check_pack(ROOT / "architectures/motor_drive.yaml", scenarios=[], seeds=(1,))
