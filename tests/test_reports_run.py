"""``archself simulate --report``: the run report (figures, decision log, escaping)."""

from __future__ import annotations

import json
import re

import pytest
from typer.testing import CliRunner

from archself.cli import app
from archself.io.jsondata import RunReportSummary

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
    RunReportSummary.model_validate(s, strict=True)  # its model: no other key, no conversion


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


def test_quality_attributes_over_time_and_the_trade_off(tmp_path) -> None:
    """One figure: each attribute's utility and U of the configuration the run was in,
    and the configurations in the attributes' space with the path taken (issue 35)."""
    from numpy.testing import assert_allclose

    from archself import load
    from archself.reports import figures
    from archself.reports.run import build_run_report
    from archself.reports.run_report import write_run_report
    from archself.runtime import MapeK
    from archself.sim.run import simulate

    arch = load(DIFFDRIVE)
    arch.scenarios["actuator_fault"].duration_s = 25.0  # left wheel −20 % from 20 s
    fixed = simulate(arch, "actuator_fault")
    adaptive = simulate(arch, "actuator_fault", adapt=MapeK(arch))
    rep = build_run_report(arch, [fixed, adaptive])
    q = rep.qualities
    assert q["preferences"] == {"energy": 0.4, "accuracy": 0.6}
    assert_allclose([q["configurations"][c]["U"] for c in ("a1", "a3")],
                    [0.4 * (33 - 31.1) / 3, 0.6 + 0.4 * (33 - 32.1) / 3], rtol=1e-9)
    assert rep.timeline("adaptive") == [(0.05, "a1"), (21.0, "a3")]  # the first sample on
    fig = figures.plot_qualities(rep)
    over_time, trade = fig.axes
    lines = {ln.get_label(): ln for ln in over_time.get_lines()}
    u = lines["U (adaptive architecture)"]
    assert_allclose(u.get_xdata(), [0.05, 21.0, 25.0], atol=1e-9)
    assert_allclose(u.get_ydata(), [0.2533333, 0.72, 0.72], atol=1e-6)
    assert_allclose(lines["U (fixed architecture)"].get_ydata(), [0.2533333] * 2, atol=1e-6)
    assert_allclose(lines["u accuracy (weight 0.6)"].get_ydata(), [0.0, 1.0, 1.0])
    # the trade-off: accuracy (weight 0.6) on x, energy on y; a1/a4 and a2/a3 share points
    assert trade.get_xlabel() == "accuracy [m]" and trade.get_ylabel() == "energy [W]"
    texts = sorted(t.get_text() for t in trade.texts if "U " in t.get_text())
    assert texts == ["a1 (U 0.25), a4 (U 0.25)", "a2 (U 0.72), a3 (U 0.72)"]
    assert "21 s" in [t.get_text() for t in trade.texts]
    write_run_report(arch, [fixed, adaptive], tmp_path / "r")
    assert (tmp_path / "r" / "qualities.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert '"qualities.png"' in (tmp_path / "r" / "index.html").read_text(encoding="utf-8")
    # a file without qualities: no such figure
    res = runner.invoke(app, ["simulate", str(MINIMAL), "-s", "calm", "--report",
                              str(tmp_path / "m")])
    assert res.exit_code == 0, res.output
    assert not (tmp_path / "m" / "qualities.png").exists()
