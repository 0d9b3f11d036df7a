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

from conftest import ROOT

PACKS = ("archself_diffdrive", "archself_process", "archself_blocks")
TOY = ROOT / "tests" / "packs"

_SCRIPT = f"""
import json, sys
for name in {PACKS!r}:
    sys.modules[name] = None  # any import of a shipped pack now fails
from archself import registry
from archself.check import check, has_errors
from archself.loader import load_architecture
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
