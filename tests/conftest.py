"""Shared fixtures; ``pytest --regen-golden`` rewrites golden files instead of comparing."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# tests/packs holds a test pack with its own entry points; importing it here (doctest
# collection) would put it on sys.path and register its types in every test.
collect_ignore = ["packs"]
FIXTURES = ROOT / "tests" / "fixtures"
DIFFDRIVE = ROOT / "architectures" / "diffdrive.yaml"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--regen-golden",
        action="store_true",
        default=False,
        help="Rewrite golden files (error messages, reports) from the current output.",
    )


@pytest.fixture
def regen(request: pytest.FixtureRequest) -> bool:
    return bool(request.config.getoption("--regen-golden"))


def compare_golden(path: Path, actual: str, regen: bool) -> None:
    """Assert ``actual`` equals the golden file ``path`` (or rewrite it with --regen-golden)."""
    if regen or not path.exists():
        path.write_text(actual, encoding="utf-8")
        if not regen:
            pytest.fail(f"golden file {path} was missing and has been written; re-run")
        return
    expected = path.read_text(encoding="utf-8")
    assert actual == expected, f"output differs from {path} (regenerate with --regen-golden)"
