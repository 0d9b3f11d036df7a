"""The reports committed under docs/reports/ are current.

Compares the deterministic text outputs (DSM CSV/Markdown, DOT, run summary.json,
README.md), not the images. Regenerate with ``python tools/make_docs_reports.py``.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from conftest import ROOT

DOCS = ROOT / "docs" / "reports"
TEXT = (".csv", ".md", ".dot", ".json")
HINT = "docs/reports is stale: regenerate with `python tools/make_docs_reports.py`"


def _tool():
    spec = importlib.util.spec_from_file_location("make_docs_reports",
                                                  ROOT / "tools" / "make_docs_reports.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _texts(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): p.read_text(encoding="utf-8")
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.suffix in TEXT
    }


def _compare(fresh: Path, committed: Path) -> None:
    new, old = _texts(fresh), _texts(committed)
    assert sorted(new) == sorted(old), HINT
    stale = [name for name in new if new[name] != old[name]]
    assert not stale, f"{HINT}; differs: {stale}"


def test_committed_architecture_report_is_current(tmp_path) -> None:
    _tool().build(tmp_path, runs=False, render=False)
    _compare(tmp_path / "diffdrive", DOCS / "diffdrive")


def test_committed_index_pages_exist() -> None:
    for page in ("diffdrive/index.html", "runs/nominal/index.html", "runs/imu_drift/index.html",
                 "runs/actuator_fault/index.html", "README.md"):
        assert (DOCS / page).is_file(), page


@pytest.mark.slow
def test_committed_run_reports_are_current(tmp_path) -> None:
    _tool().build(tmp_path, runs=True, render=False)
    _compare(tmp_path / "runs", DOCS / "runs")
    assert (tmp_path / "README.md").read_text(encoding="utf-8") == \
        (DOCS / "README.md").read_text(encoding="utf-8"), HINT
