"""A plain wheel carries the schemas, templates and example architectures."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import ROOT


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    proc = subprocess.run(
        [sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", str(out),
         str(ROOT)],
        capture_output=True, text=True,
    )
    if proc.returncode != 0 and "No module named build" in proc.stderr:
        pytest.skip("the 'build' package is not installed")
    assert proc.returncode == 0, proc.stderr[-2000:]
    (whl,) = out.glob("archself-*.whl")
    return whl


def test_wheel_contains_data(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    assert "archself/_data/schemas/architecture.schema.json" in names
    assert "archself/_data/architectures/diffdrive.yaml" in names
    assert any(n.startswith("archself/_data/templates/") for n in names)
    assert "archself/cli/__init__.py" in names
    entry = next(n for n in names if n.endswith("entry_points.txt"))
    assert "archself = archself.cli:main" in zipfile.ZipFile(wheel).read(entry).decode()


def test_wheel_installs_and_finds_its_data(wheel: Path, tmp_path: Path) -> None:
    target = tmp_path / "site"
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--quiet", "--target",
         str(target), str(wheel)], capture_output=True, text=True,
    )
    assert proc.returncode == 0, proc.stderr
    code = (
        "import sys; sys.path.insert(0, sys.argv[1]);"
        "from archself.resources import schema_path, data_dir;"
        "p = schema_path(); assert p.is_file() and '_data' in str(p), p;"
        "assert (data_dir('templates')).is_dir();"
        "from archself.cli import app;"
        "app(['validate', str(data_dir('architectures') / 'diffdrive.yaml')])"
    )
    proc = subprocess.run([sys.executable, "-c", code, str(target)], capture_output=True,
                          text=True, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr + proc.stdout
