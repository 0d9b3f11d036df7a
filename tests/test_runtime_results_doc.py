"""The per-seed tables in docs/ still show what the code computes.

docs/runtime.md ("Results on the differential-drive robot") is the output of
``bench/runtime_results.py`` and docs/hardening.md ("Results") that of
``bench/hardening_runtime.py``. Regenerating them takes minutes, so these tests
recompute the row of one seed (seed 1) through the scripts' own functions and
check that the committed row is identical: a change to the runtime, the modules
or diffdrive.yaml that moves a number makes them fail until the page is
regenerated.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from functools import cache
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]
DIFFDRIVE = str(ROOT / "architectures" / "diffdrive.yaml")
SEED = 1


@cache
def bench(name: str) -> ModuleType:
    """Import ``bench/<name>.py`` (bench/ is not a package)."""
    spec = importlib.util.spec_from_file_location(f"bench_{name}", ROOT / "bench" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def section(page: str, heading: str) -> list[str]:
    """The lines of ``docs/<page>`` under ``heading`` up to the next heading of its level."""
    lines = (ROOT / "docs" / page).read_text(encoding="utf-8").splitlines()
    start = lines.index(heading)
    level = len(heading.split(" ", 1)[0])
    same_or_higher = re.compile(rf"#{{1,{level}}} ")
    end = next(
        (k for k in range(start + 1, len(lines)) if same_or_higher.match(lines[k])),
        len(lines),
    )
    return lines[start + 1 : end]


def doc_row(lines: list[str], seed: int) -> str:
    rows = [line for line in lines if line.startswith(f"| {seed} |")]
    assert len(rows) == 1, f"expected one row of seed {seed}, found {rows}"
    return rows[0]


# ------------------------------------------------------------------ docs/runtime.md
RUNTIME = ("runtime.md", "## Results on the differential-drive robot")


def test_runtime_page_shows_the_scripts_header_settings_and_seeds() -> None:
    from archself.model.loader import load_architecture

    rr = bench("runtime_results")
    lines = section(*RUNTIME)
    text = "\n".join(lines)
    assert rr.HEADER in text
    assert rr.settings(load_architecture(DIFFDRIVE).arch) in lines
    assert "python bench/runtime_results.py --seeds 20" in text
    seeds = [int(m.group(1)) for line in lines if (m := re.match(r"\| (\d+) \|", line))]
    assert seeds == list(range(20))
    assert sum(line.startswith("Summary: ") for line in lines) == 1


@pytest.mark.slow
def test_runtime_table_row_is_current() -> None:
    """imu_drift, actuator_fault (adaptive and fixed) and nominal for seed 1."""
    rr = bench("runtime_results")
    assert doc_row(section(*RUNTIME), SEED) == rr.seed_row(SEED, DIFFDRIVE)


# ------------------------------------------------------------------ docs/hardening.md
def _hardening_scenarios() -> list[str]:
    hr = bench("hardening_runtime")
    return hr.SCENARIOS + [f"drift_then_gps_{k}" for k in hr.GPS_KINDS]


@pytest.mark.slow
@pytest.mark.parametrize("scenario", _hardening_scenarios())
def test_hardening_table_row_is_current(scenario: str) -> None:
    hr = bench("hardening_runtime")
    lines = section("hardening.md", f"### {scenario}")
    computed = hr.table([hr.run_one((DIFFDRIVE, scenario, SEED))]).splitlines()
    header, row = computed[:2], computed[2]
    assert lines[1:3] == header
    assert doc_row(lines, SEED) == row
