"""The reports committed under docs/reports/ are current.

Compares the deterministic text outputs (DSM CSV/Markdown, DOT, run summary.json,
README.md) and the architecture report's HTML pages (DSM pages and index), not the images
nor the run reports' HTML (which prints simulated numbers in full). The index links the
SVG/PNG drawings only when Graphviz rendered them, as it did for the committed one: without
`dot` the index is left out of the comparison. Regenerate with
``python tools/make_docs_reports.py``.

A run's ``summary.json`` is compared as data: its structure and strings exactly, its
numbers to a relative 1e-4, so that the last bits a different BLAS or SciPy build
gives to a simulation do not fail the test while any change of behaviour does.
"""

from __future__ import annotations

import importlib.util
import json
import math
import shutil
from pathlib import Path
from typing import Any

import pytest

from conftest import ROOT

DOCS = ROOT / "docs" / "reports"
TEXT = (".csv", ".md", ".dot", ".json")
HTML = (".html",)
HINT = "docs/reports is stale: regenerate with `python tools/make_docs_reports.py`"


def _tool():
    spec = importlib.util.spec_from_file_location("make_docs_reports",
                                                  ROOT / "tools" / "make_docs_reports.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _texts(folder: Path, suffixes: tuple[str, ...] = TEXT) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): p.read_text(encoding="utf-8")
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.suffix in suffixes
    }


def _same_data(a: Any, b: Any) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return (isinstance(a, (int, float)) and isinstance(b, (int, float))
                and math.isclose(a, b, rel_tol=1e-4, abs_tol=1e-9))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same_data(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same_data(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def _same(name: str, new: str, old: str) -> bool:
    if name.endswith(".json"):
        return _same_data(json.loads(new), json.loads(old))
    return new == old


def test_same_data_tolerates_last_digits_only() -> None:
    assert _same_data({"e": [1.00001, "a1"]}, {"e": [1.0, "a1"]})
    assert not _same_data({"e": [1.001, "a1"]}, {"e": [1.0, "a1"]})
    assert not _same_data({"e": [1.0, "a2"]}, {"e": [1.0, "a1"]})
    assert not _same_data({"e": [1.0]}, {"e": [1.0, 2.0]})
    assert not _same_data({"e": None}, {"e": 0.0})


def _compare(fresh: Path, committed: Path, suffixes: tuple[str, ...] = TEXT,
             skip: tuple[str, ...] = ()) -> None:
    new, old = _texts(fresh, suffixes), _texts(committed, suffixes)
    for name in skip:
        new.pop(name, None)
        old.pop(name, None)
    assert sorted(new) == sorted(old), HINT
    stale = [name for name in new if not _same(name, new[name], old[name])]
    assert not stale, f"{HINT}; differs: {stale}"


def test_committed_architecture_report_is_current(tmp_path) -> None:
    rendered = shutil.which("dot") is not None
    _tool().build(tmp_path, runs=False, render=rendered)
    _compare(tmp_path / "diffdrive", DOCS / "diffdrive", TEXT + HTML,
             skip=() if rendered else ("index.html",))


def test_architecture_report_html_is_deterministic(tmp_path) -> None:
    from archself.model.loader import load_architecture
    from archself.reports.architecture import write_architecture_report

    arch = load_architecture(ROOT / "architectures" / "diffdrive.yaml").arch
    for out in ("one", "two"):
        write_architecture_report(arch, tmp_path / out, dot=False)
    one, two = _texts(tmp_path / "one", HTML), _texts(tmp_path / "two", HTML)
    assert one and one == two


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
