"""Start-up of the command line and validation of a 10,000-module file (subprocesses)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from conftest import DIFFDRIVE

ARCHSELF = str(Path(sys.executable).parent / "archself")


def _run(*args: str, ok: int = 0) -> None:
    res = subprocess.run([ARCHSELF, *args], capture_output=True, text=True)
    assert res.returncode == ok, res.stderr


def test_startup_help(benchmark) -> None:
    benchmark.pedantic(_run, args=("--help",), rounds=10, iterations=1, warmup_rounds=1)


def test_startup_validate_diffdrive(benchmark) -> None:
    benchmark.pedantic(
        _run, args=("validate", str(DIFFDRIVE)), rounds=10, iterations=1, warmup_rounds=1
    )


@pytest.fixture(scope="module")
def file_10k(tmp_path_factory) -> Path:
    from archself.model.generate import generate_architecture

    path = tmp_path_factory.mktemp("gen") / "g10k.yaml"
    path.write_text(generate_architecture(10_000, seed=1), encoding="utf-8")
    return path


def test_validate_10k(benchmark, file_10k: Path) -> None:
    benchmark.pedantic(_run, args=("validate", str(file_10k)), rounds=3, iterations=1)


def test_load_10k_in_process(benchmark, file_10k: Path) -> None:
    """YAML compose + conversion + schema of the 10,000-module file, without start-up."""
    from archself.model.loader import load_architecture

    loaded = benchmark.pedantic(load_architecture, args=(file_10k,), rounds=3, iterations=1)
    assert len(loaded.arch.modules) == 10_000
    assert loaded.source.locate(("modules", "m9999", "type")) > (10_000, 1)


def test_convert_10k_nodes(benchmark, file_10k: Path) -> None:
    """The node graph → data conversion alone (the part archself owns; compose is libyaml's)."""
    from archself.io.yaml_source import Converter as _Converter
    from archself.io.yaml_source import parse as _parse

    text = file_10k.read_text(encoding="utf-8")
    node = _parse(text, str(file_10k))
    data = benchmark.pedantic(
        lambda: _Converter(str(file_10k)).convert(node), rounds=3, iterations=1
    )
    assert len(data["modules"]) == 10_000
