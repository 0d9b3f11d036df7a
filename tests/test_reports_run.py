"""``archself simulate --report``: the run report (figures, decision log, escaping)."""

from __future__ import annotations

import json
import re

import pytest
from typer.testing import CliRunner

from archself.cli import app

from conftest import DIFFDRIVE, FIXTURES, ROOT

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


PLANT = ROOT / "architectures" / "process_plant.yaml"


@pytest.mark.parametrize("path", [HOSTILE, DIFFDRIVE, PLANT],
                         ids=["hostile-xy", "diffdrive-xy", "process-plant-1d"])
def test_legends_cover_no_switch_label(path) -> None:
    """The "a1 → a2" labels at the top of the axes stay visible: no legend lies on them."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from archself.model.loader import load_architecture
    from archself.reports import figures
    from archself.reports.run import build_run_report
    from archself.runtime import MapeK
    from archself.sim.run import simulate

    arch = load_architecture(path).arch
    scenario = SCENARIO if path == HOSTILE else _switching_scenario(arch)
    rep = build_run_report(arch, [simulate(arch, scenario),
                                  simulate(arch, scenario, adapt=MapeK(arch))])
    assert rep.switches
    for plot in (figures.plot_trajectory, figures.plot_error, figures.plot_influence):
        fig = plot(rep)
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        renderer = canvas.get_renderer()
        ax = fig.axes[0]
        labels = [t.get_window_extent(renderer) for t in ax.texts if "→" in t.get_text()]
        legends = [lg.get_window_extent(renderer)
                   for lg in [*fig.legends, ax.get_legend()] if lg is not None]
        assert legends and (labels or plot is figures.plot_trajectory), plot.__name__
        for box in labels:
            assert not any(box.overlaps(lg) for lg in legends), (plot.__name__, box, legends)


def _switching_scenario(arch) -> str:
    """The first scenario with faults (imu_drift in diffdrive.yaml: the adaptive run switches)."""
    return next(name for name, sc in arch.scenarios.items() if sc.faults)


def test_metric_labels_carry_the_objective_unit(tmp_path) -> None:
    """A level in metres, a temperature in K: the report labels what the file declares."""
    from archself.model.loader import load_text
    from archself.reports import figures
    from archself.reports.run import build_run_report
    from archself.sim.run import simulate

    text = MINIMAL.read_text(encoding="utf-8").replace("components: [0, 1]}",
                                                       "components: [0, 1], unit: K}", 1)
    path = tmp_path / "kelvin.yaml"
    path.write_text(text, encoding="utf-8")
    res = runner.invoke(app, ["simulate", str(path), "-s", "calm", "--fixed",
                              "--report", str(tmp_path / "rep")])
    assert res.exit_code == 0, res.output
    html = (tmp_path / "rep" / "index.html").read_text(encoding="utf-8")
    assert "max error [K]" in html and "RMS error [K]" in html and "[m]" not in html
    s = json.loads((tmp_path / "rep" / "summary.json").read_text(encoding="utf-8"))
    assert s["unit"] == "K"
    assert set(s["runs"][0]["metrics"]) == {"max_error", "final_error", "rms_error",
                                            "peak_time_s"}
    arch = load_text(text, str(path)).arch
    rep = build_run_report(arch, [simulate(arch, "calm")])
    assert figures.plot_error(rep).axes[0].get_ylabel() == "tracking error [K]"
