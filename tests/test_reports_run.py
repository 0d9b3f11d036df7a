"""``archself simulate --report``: the run report (figures, decision log, escaping)."""

from __future__ import annotations

import json
import re

import pytest
from typer.testing import CliRunner

from archself.cli import app

from conftest import FIXTURES

HOSTILE = FIXTURES / "valid" / "hostile_names.yaml"
MINIMAL = FIXTURES / "valid" / "minimal.yaml"
SCENARIO = "drift <script>"
runner = CliRunner()


@pytest.fixture(scope="module")
def compare_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "report"
    res = runner.invoke(app, ["simulate", str(HOSTILE), "-s", SCENARIO, "--compare",
                              "--report", str(out)])
    assert res.exit_code == 0, res.output
    assert f"report: {out / 'index.html'}" in res.stderr
    return out


def test_files_and_summary(compare_report) -> None:
    for f in ("index.html", "trajectory.png", "error.png", "influence.png", "summary.json"):
        assert (compare_report / f).stat().st_size > 500, f
    for f in ("trajectory.png", "error.png", "influence.png"):
        assert (compare_report / f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    s = json.loads((compare_report / "summary.json").read_text(encoding="utf-8"))
    assert [r["mode"] for r in s["runs"]] == ["fixed", "adaptive"]
    (sw,) = s["runs"][1]["switches"]
    assert sw["to"] == 'fusion "GPS" & <i>' and sw["action"] == 'use <ekf> & "gps"'
    outcomes = [row["outcome"] for row in s["decision_log"]]
    assert outcomes[0] == "warm-up over" and "switch" in outcomes
    assert s["warmup_s"] == 3.0 and s["selector"] == "|z| ≥ τ = 0.5"


def test_summary_is_deterministic(compare_report, tmp_path) -> None:
    res = runner.invoke(app, ["simulate", str(HOSTILE), "-s", SCENARIO, "--compare",
                              "--report", str(tmp_path)])
    assert res.exit_code == 0
    assert (tmp_path / "summary.json").read_text() == (compare_report / "summary.json").read_text()


def test_html_shows_figures_log_and_escapes(compare_report) -> None:
    html = (compare_report / "index.html").read_text(encoding="utf-8")
    assert "<script" not in html.lower()
    assert "drift &lt;script&gt;" in html
    assert "fusion &#34;GPS&#34; &amp; &lt;i&gt;" in html
    for f in ("trajectory.png", "error.png", "influence.png", "summary.json"):
        assert f'"{f}"' in html
    assert re.search(r'<tr class="switch">.*?use &lt;ekf&gt; &amp; &#34;gps&#34;', html, re.S)
    assert "Fig. 5" in html and "Fig. 6" in html and "Fig. 2–4" in html


def test_fixed_run_report_has_no_influence_figure(tmp_path) -> None:
    res = runner.invoke(app, ["simulate", str(MINIMAL), "-s", "calm", "--fixed",
                              "--report", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert not (tmp_path / "influence.png").exists()
    html = (tmp_path / "index.html").read_text(encoding="utf-8")
    assert "A fixed run has no MAPE-K loop" in html


def test_report_into_a_file_fails_cleanly(tmp_path) -> None:
    (tmp_path / "f").write_text("x")
    res = runner.invoke(app, ["simulate", str(MINIMAL), "-s", "calm", "--report",
                              str(tmp_path / "f")])
    assert res.exit_code == 1
    assert res.stderr.strip().splitlines()[-1].endswith("not a folder")
