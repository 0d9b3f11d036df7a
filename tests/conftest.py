"""Shared fixtures; ``pytest --regen-golden`` rewrites golden files instead of comparing."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# tests/packs holds a test pack with its own entry points; importing it here (doctest
# collection) would put it on sys.path and register its types in every test.
collect_ignore = ["packs", "ros2_plain_client.py"]  # the ROS 2 client imports rclpy: a script
FIXTURES = ROOT / "tests" / "fixtures"

#: The persistent design cache (archself.linear.designs) of this session and of the
#: processes it starts: a fresh folder, never the user's (set when the suite is collected,
#: so the doctests of archself/ and packs/ use it too); removed at the end.
DESIGN_CACHE = tempfile.mkdtemp(prefix="archself-test-cache-")
os.environ["ARCHSELF_CACHE_DIR"] = DESIGN_CACHE
os.environ.pop("ARCHSELF_CACHE", None)


def pytest_unconfigure(config: pytest.Config) -> None:
    shutil.rmtree(DESIGN_CACHE, ignore_errors=True)
DIFFDRIVE = ROOT / "architectures" / "diffdrive.yaml"


#: The distributions whose module types the tests see: archself itself (the packs), the
#: in-repo example plugin and the test pack of tests/packs. A third-party plugin installed
#: in the same environment must not change a golden message (its ``sensor.*`` type would
#: join the "did you mean" and the list of ``sensor.*`` types).
IN_REPO_DISTRIBUTIONS = frozenset({"archself", "archself-example", "toy-pack"})


def in_repo_entry_points() -> dict:
    """The ``archself.modules`` entry points of :data:`IN_REPO_DISTRIBUTIONS`, by type key."""
    import re
    from importlib.metadata import entry_points

    from archself.registry import ENTRY_POINT_GROUP

    def dist(ep) -> str:  # noqa: ANN001
        name = ep.dist.name if ep.dist is not None else ""
        return re.sub(r"[-_.]+", "-", name).lower()

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)
            if dist(ep) in IN_REPO_DISTRIBUTIONS}


@pytest.fixture(autouse=True, scope="session")
def _only_in_repo_plugins():
    """The registry reads only the in-repo entry points, whatever else is installed."""
    from archself import registry

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(registry, "_POINTS", in_repo_entry_points())
        yield


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
