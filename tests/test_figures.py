"""Figures for a paper (issue 15 item 3): Figures returned, formats, readable on real data."""

from __future__ import annotations

import statistics
from pathlib import Path

import numpy as np
import pytest

import archself
from archself.campaign import figures as cfig
from archself.campaign.aggregate import summarize
from archself.campaign.results import read_results
from archself.reports import figures
from archself.reports.run import build_run_report

from conftest import DIFFDRIVE, ROOT

pytest.importorskip("matplotlib")

CAMPAIGN = ROOT / "docs" / "campaign" / "campaign.parquet"


@pytest.fixture(scope="module")
def shipped_campaign() -> tuple[list[dict], object]:
    table, meta = read_results(CAMPAIGN)
    return table.to_pylist(), summarize(table, meta, None, None)


@pytest.fixture(scope="module")
def fault_report() -> object:
    """actuator_fault shortened: a switch to a3, then cycles whose action is not applicable."""
    arch = archself.load(DIFFDRIVE)
    arch.scenarios["actuator_fault"].duration_s = 40
    runs = [archself.simulate(arch, "actuator_fault"),
            archself.simulate(arch, "actuator_fault", adapt=archself.MapeK(arch))]
    return build_run_report(arch, runs)


def test_delay_histogram_shows_the_spike_of_first_cycle_detections(shipped_campaign):
    rows, summary = shipped_campaign
    fig = cfig.plot_delays(rows, ["actuator_fault", "imu_drift"])
    ax = fig.axes[0]
    bars = [p for p in ax.patches if p.get_height() > 0]
    spike = max(bars, key=lambda p: p.get_height())
    # every actuator_fault run switches in the first cycle: one bar of 168 runs, as wide as
    # the other bars (one common set of bins), not a hairline
    assert spike.get_height() == 168
    widths = {round(p.get_width(), 9) for p in bars}
    assert len(widths) == 1 and spike.get_width() >= 0.5
    assert spike.get_x() <= 0.5 <= spike.get_x() + spike.get_width()
    assert any(t.get_text() == "168" for t in ax.texts)
    # the legend's median is the report table's (the mean of the two middle runs)
    imu = next(b for b in summary.scenarios if b["scenario"] == "imu_drift")
    label = next(t.get_text() for t in ax.get_legend().get_texts() if "imu_drift" in t.get_text())
    assert f"median {imu['delay_s']['median']:.3g} s" in label


def test_tau_sweep_has_tau_on_x_not_every_point_at_zero(shipped_campaign):
    _, summary = shipped_campaign
    fig = cfig.plot_tau(summary.tau)
    top, bottom = fig.axes
    taus = sorted({p["value"] for c in summary.tau["curves"] for p in c["points"]})
    xs = {round(float(x), 9) for line in top.get_lines() for x in line.get_xdata()}
    assert len(taus) == 7 and set(np.round(taus, 9)) <= xs
    assert "τ" in bottom.get_xlabel()
    # the false-switch rates (all 0 in this campaign) are a line with their interval,
    # drawn once: over the fault-free runs it is the same for both faulted scenarios
    false = [line for line in bottom.get_lines() if "false switches" in line.get_label()]
    # ... and its legend says over which runs (no panel title saying it differently)
    assert [line.get_label() for line in false] == ["false switches (over fault-free scenarios)"]
    assert [ax.get_title() for ax in fig.axes] == ["", ""]  # no title unless asked
    assert cfig.plot_tau(summary.tau, title=True).axes[0].get_title() == \
        "τ sweep: runtime.threshold"
    # the legend under the figure, none inside the axes (it hid the intervals)
    assert top.get_legend() is None and bottom.get_legend() is None and fig.legends


@pytest.mark.parametrize("metric", ["rms_error", "max_error", "final_error"])
def test_error_boxes_are_not_clipped(shipped_campaign, metric):
    rows, summary = shipped_campaign
    names = [b["scenario"] for b in summary.scenarios]
    fig = cfig.plot_errors(rows, names, metric, summary.unit)
    assert [ax.get_title() for ax in fig.axes] == names
    for ax, name in zip(fig.axes, names, strict=True):
        lo, hi = ax.get_ylim()
        values = [r[metric] for r in rows if r["scenario"] == name]
        assert lo < min(values) and max(values) < hi, name
        # the median under each box (not on it), the table's median (mean of the middle two)
        ticks = [t.get_text().split("\n") for t in ax.get_xticklabels()]
        assert [t[0] for t in ticks] == ["fixed", "adaptive"]
        for mode, (_, written) in zip(("fixed", "adaptive"), ticks, strict=True):
            runs = [r[metric] for r in rows if r["scenario"] == name and r["mode"] == mode]
            assert float(written) == pytest.approx(statistics.median(runs), rel=5e-3)
        assert not ax.texts  # nothing written over the boxes
    assert fig.axes[0].get_ylabel().endswith("[m]")


def test_trajectory_has_units_equal_aspect_and_the_reference_on_top(fault_report):
    fig = figures.plot_trajectory(fault_report)
    ax = fig.axes[0]
    assert ax.get_xlabel().endswith("[m]") and ax.get_ylabel().endswith("[m]")
    assert ax.get_aspect() == 1.0
    lines = {line.get_label(): line for line in ax.get_lines()}
    ref = lines["reference"]
    assert all(ref.get_zorder() > line.get_zorder()
               for label, line in lines.items() if label in figures.LABELS.values())
    assert fig.legends[0].get_texts()[0].get_text() == "reference"  # outside the axes


def test_influence_figure_says_why_cycles_were_rejected(fault_report):
    assert fault_report.rejections, "the shortened run has rejected cycles"
    top = fault_report.rejections[0]
    assert (top.action, top.reason) == ("compensate_left_wheel", "not applicable")
    assert "only in a1, a2" in top.label
    fig = figures.plot_influence(fault_report)
    assert len(fig.axes) == 2  # the channels and the strip of rejected cycles
    legend_texts = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert any(f"{len(top.t)} cycles: compensate_left_wheel: not applicable" in t
               for t in legend_texts)


def test_influence_figure_spans_what_happened_and_names_few_channels():
    """imu_drift: the odometry channel crosses τ at 62.5 s of a 400 s run."""
    arch = archself.load(DIFFDRIVE)
    runs = [archself.simulate(arch, "imu_drift"),
            archself.simulate(arch, "imu_drift", adapt=archself.MapeK(arch))]
    rep = build_run_report(arch, runs)
    ax = figures.plot_influence(rep).axes[0]
    lo, hi = ax.get_xlim()
    switch = rep.switches[0]["t_s"]
    assert lo <= rep.faults[0]["onset_s"] and lo < switch < hi
    assert hi - lo < 0.25 * rep.z_t[-1]  # not the 400 s run
    names = [t.get_text() for t in ax.get_legend().get_texts()]
    channels = [n for n in names if n.startswith("|z| ") and "other" not in n]
    assert channels[0] == "|z| odometry" and len(channels) <= figures.SHOWN_MAX
    assert f"|z| of {len(rep.z) - len(channels)} other modules" in names
    assert len(names) <= figures.SHOWN_MAX + 4  # + others, τ, fault onset, switch


def test_delay_histogram_counts_have_integer_ticks(shipped_campaign):
    rows, _ = shipped_campaign
    few = [r for r in rows if r["replicate"] < 2]  # 2 runs per bar at most: 0.2-step ticks before
    ax = cfig.plot_delays(few, ["actuator_fault", "imu_drift"]).axes[0]
    ticks = [t for t in ax.get_yticks() if ax.get_ylim()[0] <= t <= ax.get_ylim()[1]]
    np.testing.assert_allclose(ticks, np.round(ticks), atol=1e-12)
    assert len(ticks) >= 2


def test_every_api_figure_is_for_a_paper(fault_report, shipped_campaign, tmp_path: Path):
    """TrueType in a saved PDF (whatever the global rcParams), column sizes, no titles."""
    import matplotlib

    rows, summary = shipped_campaign
    names = ["actuator_fault", "imu_drift"]
    made = {
        "trajectory": figures.plot_trajectory(fault_report, size="one"),
        "error": figures.plot_error(fault_report, size="one"),
        "influence": figures.plot_influence(fault_report, size="two"),
        "delays": cfig.plot_delays(rows, names, size="one"),
        "errors": cfig.plot_errors(rows, names, "rms_error", "m", size="two"),
        "tau": cfig.plot_tau(summary.tau, size=(3.5, 3.0)),
        "results": cfig.plot_results(CAMPAIGN, "max_error", size="one"),
    }
    widths = {"trajectory": 3.5, "error": 3.5, "influence": 7.16, "delays": 3.5,
              "errors": 7.16, "tau": 3.5, "results": 3.5}
    for name, fig in made.items():
        assert fig.get_figwidth() == pytest.approx(widths[name]), name
        # no title; the error panels are labelled with their scenario
        titles = {ax.get_title() for ax in fig.axes} - {""}
        assert not fig.get_suptitle() and titles <= {*names, "nominal"}, (name, titles)
        with matplotlib.rc_context({"pdf.fonttype": 3}):  # the global default: Type 3
            fig.savefig(tmp_path / f"{name}.pdf")
        pdf = (tmp_path / f"{name}.pdf").read_bytes()
        assert b"/FontType 3" not in pdf and b"/Subtype /Type3" not in pdf, name
        assert b"/CIDFontType2" in pdf, name  # TrueType (Type 42) fonts embedded
    with pytest.raises(ValueError, match="size must be one of"):
        figures.plot_error(fault_report, size="three")
    assert figures.plot_error(fault_report, title=True).axes[0].get_title() == \
        "Tracking error: actuator_fault"


def test_figure_formats_are_deterministic(fault_report, tmp_path: Path):
    fig = figures.plot_error(fault_report)
    for fmt, magic in (("png", b"\x89PNG"), ("pdf", b"%PDF-"), ("svg", b"<?xml")):
        a = figures.figure_bytes(fig, fmt, 200)
        assert a[:5].startswith(magic) and a == figures.figure_bytes(fig, fmt, 200)
    small, large = (len(figures.figure_bytes(fig, "png", d)) for d in (72, 300))
    assert large > small
    with pytest.raises(ValueError, match="unknown figure format"):
        figures.figure_bytes(fig, "bmp")


def _positions(dot_file: Path) -> dict[str, tuple[str, str]]:
    import shutil
    import subprocess

    exe = shutil.which("dot")
    if exe is None:
        pytest.skip("Graphviz dot is not installed")
    out = subprocess.run([exe, "-Tplain", str(dot_file)], capture_output=True, text=True,
                         check=True).stdout
    return {f[1]: (f[2], f[3]) for f in (line.split() for line in out.splitlines())
            if f and f[0] == "node"}


def test_configuration_drawings_and_diffs_keep_node_positions(tmp_path: Path) -> None:
    from archself.reports.architecture import write_architecture_report

    arch = archself.load(DIFFDRIVE)
    write_architecture_report(arch, tmp_path / "r", dot=False)
    files = sorted((tmp_path / "r").glob("*.dot"))
    assert len(files) >= 10  # the whole graph, 4 configurations, 6 diffs
    layouts = {f.name: _positions(f) for f in files}
    first = layouts["graph-architecture.dot"]
    assert set(first) == set(arch.modules)
    for name, pos in layouts.items():
        assert pos == first, name
    # a configuration hides the modules it does not run, a diff marks them
    a1 = (tmp_path / "r" / "graph-config-a1.dot").read_text()
    assert '"ekf" [label="ekf\\nestimator.ekf"' in a1 and 'style="invis"' in a1
    diff = (tmp_path / "r" / "diff-a1--a2.dot").read_text()
    assert 'xlabel="+"' in diff and 'xlabel="−"' in diff
