"""Static checks of the package: lint (ruff) and types (mypy), as configured in pyproject."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT


def _tool(name: str) -> str:
    exe = shutil.which(name, path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip(f"{name} is not installed (pip install -e '.[dev]')")
    return exe


def test_ruff_is_clean() -> None:
    paths = ["archself", "packs", "tests", "plugins", "bench", "examples"]
    proc = subprocess.run([_tool("ruff"), "check", *paths], cwd=ROOT, capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stdout[-3000:]


def test_mypy_is_clean() -> None:
    proc = subprocess.run([_tool("mypy")], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:]


def test_typed_doors_pass_mypy_strict() -> None:
    """The protocols (archself.contracts), check_pack, and every class that plays a role."""
    files = ["archself/contracts.py", "archself/testing.py", "tests/typing_doors.py"]
    proc = subprocess.run([_tool("mypy"), "--strict", "--follow-imports=silent",
                           "--ignore-missing-imports", *files],
                          cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:]


def test_simulate_imports_only_what_its_modules_need() -> None:
    """``archself simulate`` imports python-control and filterpy only when a module of
    the file needs them: the process plant's modules (PI, tank, valve, observers) need
    neither, so its run imports neither, nor what python-control pulls in
    (scipy.signal, matplotlib), nor pandas."""
    plant = ROOT / "architectures" / "process_plant.yaml"

    code = (
        "import sys\n"
        "from archself.cli import app\n"
        "try:\n"
        f"    app(['simulate', {str(plant)!r}, '--scenario', 'valve_loss'])\n"
        "except SystemExit as e:\n"
        "    assert e.code == 0, e.code\n"
        "print(sorted(m for m in ('control', 'matplotlib', 'scipy.signal', 'pandas', "
        "'filterpy') if m in sys.modules))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip().splitlines()[-1] == "[]"


def test_validate_imports_no_scipy_control_filterpy_or_matplotlib() -> None:
    """``archself validate`` of the diff-drive file: ρ(W) and the singularity of I − Wᵀ
    by numpy (a small W), the data-flow checks in plain Python (docs/benchmarks.md,
    "Start-up" lists what it imports)."""
    code = (
        "import sys\n"
        "from archself.cli import app\n"
        "try:\n"
        f"    app(['validate', {str(ROOT / 'architectures' / 'diffdrive.yaml')!r}])\n"
        "except SystemExit as e:\n"
        "    assert e.code == 0, e.code\n"
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'scipy', 'control', "
        "'filterpy', 'matplotlib', 'pandas', 'networkx'}))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip().splitlines()[-1] == "[]"
