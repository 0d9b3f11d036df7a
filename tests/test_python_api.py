"""The Python API of a notebook: lazy names on ``archself``, tidy frames, an HTML summary."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import numpy as np
import pytest

import archself

from conftest import DIFFDRIVE, FIXTURES

pd = pytest.importorskip("pandas")

HEAVY = ("control", "filterpy", "matplotlib", "pandas")
PUBLIC = ("load", "validate", "simulate", "RunResult", "MapeK", "explain", "plan_campaign",
          "run_campaign", "read_results", "read_trace", "parse_sweep", "calibrate", "Architecture",
          "Finding", "ArchselfError", "LoadError")


def test_public_names_are_exported_lazily() -> None:
    assert set(PUBLIC) == set(archself.__all__) and set(PUBLIC) <= set(dir(archself))
    assert all(getattr(archself, name) is not None for name in archself.__all__)
    from archself.runtime import MapeK, explain
    from archself.sim.run import simulate

    assert archself.simulate is simulate and archself.MapeK is MapeK
    assert archself.explain is explain
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        archself.nope  # noqa: B018


def test_import_archself_stays_light() -> None:
    code = (
        "import sys, archself\n"
        f"heavy = [m for m in {HEAVY!r} + ('numpy', 'scipy') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
        f"from archself import {', '.join(PUBLIC)}\n"
        f"heavy = [m for m in {HEAVY!r} if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_load_and_validate() -> None:
    arch = archself.load(DIFFDRIVE)
    assert isinstance(arch, archself.Architecture) and arch.initial_configuration() == "a1"
    assert not [f for f in archself.validate(DIFFDRIVE) if f.severity == "error"]
    missing = archself.validate(FIXTURES / "no-such-file.yaml")
    assert [f.code for f in missing] == ["load"]


def test_load_refuses_a_file_with_semantic_errors(tmp_path: Any) -> None:
    text = DIFFDRIVE.read_text(encoding="utf-8").replace("max_spectral_radius: 0.95",
                                                         "max_spectral_radius: 0.0001")
    bad = tmp_path / "bad.yaml"
    bad.write_text(text, encoding="utf-8")
    errors = [f for f in archself.validate(bad) if f.severity == "error"]
    assert errors
    with pytest.raises(archself.LoadError) as info:
        archself.load(bad)
    assert str(info.value) == str(errors[0])
    assert archself.load(bad, check=False).name == "diffdrive"


@pytest.fixture(scope="module")
def run() -> Any:
    """30 s of diffdrive, left wheel failing at 5 s: the loop switches a1 → a3."""
    arch = archself.load(DIFFDRIVE)
    sc = arch.scenarios["actuator_fault"]
    sc.duration_s = 30
    sc.faults[0].onset_s = 5
    return archself.simulate(arch, "actuator_fault", adapt=archself.MapeK(arch))


def test_to_pandas_columns_dtypes_and_length(run: Any) -> None:
    df = run.to_pandas()
    n = len(run.series["t"])
    assert len(df) == n == 600
    cols = list(df.columns)
    assert cols[:2] == ["t", "J"]
    # vector columns named by the publishing types' element names (output_elements)
    assert cols[2:15] == ["reference_x", "reference_y", "reference_theta", "reference_v",
                          "reference_omega", "actual_x", "actual_y", "actual_theta",
                          "estimate_x", "estimate_y", "estimate_theta", "command_left",
                          "command_right"]
    for name in ("residual.wheel_left", "configuration"):
        assert name in cols, name
    assert not [c for c in cols if c[-2:] in ("_0", "_1")] and "actual" not in cols
    assert all(df[c].dtype == np.float64 for c in cols if c != "configuration")
    np.testing.assert_array_equal(df["actual_y"].to_numpy(), run.series["actual"][:, 1])
    np.testing.assert_array_equal(df["command_right"].to_numpy(), run.series["command"][:, 1])
    assert df.attrs["scenario"] == "actuator_fault" and df.attrs["unit"] == "m"


def test_named_columns_round_trip_through_parquet_and_old_traces_keep_indices(
        run: Any, tmp_path) -> None:
    import dataclasses

    run.write_trace(tmp_path / "run.parquet")
    disk = pd.read_parquet(tmp_path / "run.parquet")
    assert list(disk.columns) == list(run.to_pandas().columns)
    back = archself.read_trace(tmp_path / "run.parquet")
    np.testing.assert_allclose(back.series["reference"], run.series["reference"], rtol=1e-6,
                               atol=1e-6)
    # a run without element names (an old trace, a type declaring none): indices, as before
    old = dataclasses.replace(run, meta={k: v for k, v in run.meta.items() if k != "elements"})
    assert "reference_4" in old.to_pandas().columns
    old.write_trace(tmp_path / "old.parquet")
    assert "actual_2" in pd.read_parquet(tmp_path / "old.parquet").columns
    np.testing.assert_allclose(archself.read_trace(tmp_path / "old.parquet").series["actual"],
                               run.series["actual"], rtol=1e-6, atol=1e-6)


def test_configuration_column_holds_names(run: Any) -> None:
    df = run.to_pandas()
    conf = df["configuration"]
    assert isinstance(conf.dtype, pd.CategoricalDtype)
    assert list(conf.cat.categories) == run.configurations
    assert conf.iloc[0] == "a1" and conf.iloc[-1] == "a3"
    assert set(conf.unique()) == {"a1", "a3"}
    switch_t = run.switches[0]["t_s"]
    assert (conf[df["t"] > switch_t + 0.1] == "a3").all()


def test_decisions_frame_one_row_per_cycle_and_active_module(run: Any) -> None:
    dd = run.decisions_frame()
    assert list(dd.columns) == ["cycle", "t", "configuration", "phase", "module", "r", "z",
                                "candidate"]
    assert dd["candidate"].dtype == bool and dd["cycle"].dtype == np.int64
    assert dd["z"].dtype == np.float64 and dd["r"].dtype == np.float64
    expected = sum(len(d.z) for d in run.decisions)
    assert len(dd) == expected and dd["cycle"].nunique() == len(run.decisions) == 60
    counts = dd.groupby("cycle").size()
    assert (counts == [len(d.z) for d in run.decisions]).all()
    assert not dd.duplicated(["cycle", "module"]).any()
    # W ≥ 0 and r_i ≥ 0: z = (I − Wᵀ)⁻¹ r = r + Wᵀr + … ≥ r
    assert (dd["z"] >= dd["r"] - 1e-9).all()
    assert set(dd["configuration"].unique()) == {"a1", "a3"}
    # the inactive modules of a3 have no row after the switch, a3's own ones do
    after = dd[dd["configuration"] == "a3"]
    assert "asym_lqr" in set(after["module"]) and "lqr" not in set(after["module"])
    d = run.decisions[20]
    rows = dd[dd["cycle"] == d.cycle].set_index("module")
    assert set(rows.index[rows["candidate"]]) == set(d.candidates)
    assert rows.loc["wheel_left", "z"] == pytest.approx(d.z["wheel_left"])


def test_decisions_frame_of_a_fixed_run_is_empty() -> None:
    arch = archself.load(DIFFDRIVE)
    arch.scenarios["nominal"].duration_s = 2
    dd = archself.simulate(arch, "nominal").decisions_frame()
    assert len(dd) == 0 and "candidate" in dd.columns


def test_repr_html_summarizes_and_escapes(run: Any) -> None:
    page = run._repr_html_()
    assert "actuator_fault" in page and "a1 → a3" in page and "max error [m]" in page
    assert "compensate_left_wheel" in page
    import dataclasses

    odd = dataclasses.replace(run, scenario="<script>x</script>", switches=[])
    page = odd._repr_html_()
    assert "<script>" not in page and "&lt;script&gt;" in page


def test_missing_pandas_is_a_one_line_error(run: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pandas", None)
    for method in (run.to_pandas, run.decisions_frame):
        with pytest.raises(ImportError) as info:
            method()
        assert "pip install 'archself[pandas]'" in str(info.value)
        assert "\n" not in str(info.value)


@pytest.mark.parametrize("call", [
    lambda: archself.load(None),
    lambda: archself.load(5),  # os.stat would take it as a file descriptor
    lambda: archself.load(""),
    lambda: archself.load("archself: 1\nname: x\n"),  # the text, not its path
    lambda: archself.load(archself.load(DIFFDRIVE)),
    lambda: archself.simulate(None, "nominal"),
    lambda: archself.simulate(DIFFDRIVE, "nominal", seed=-1),
    lambda: archself.simulate(DIFFDRIVE, "nominal", seed="x"),
    lambda: archself.simulate(DIFFDRIVE, "nominal", seed=1.5),
    lambda: archself.simulate(DIFFDRIVE, "nominal", adapt=5),
    lambda: archself.simulate(DIFFDRIVE, "nominal", progress="x"),
    lambda: archself.MapeK(str(DIFFDRIVE)),
    lambda: archself.read_trace(None),
    lambda: archself.read_trace(""),
    lambda: archself.explain(str(DIFFDRIVE)),
])
def test_odd_arguments_are_one_line_archself_errors(call: Any) -> None:
    """Not a TypeError from deep inside: an ArchselfError saying what was expected."""
    with pytest.raises(archself.ArchselfError) as info:
        call()
    assert "\n" not in str(info.value) and "expected" in str(info.value), str(info.value)


def test_validate_of_a_non_path_gives_a_finding() -> None:
    (finding,) = archself.validate(None)
    assert finding.severity == "error" and "expected the path of a file" in finding.message


def test_reprs_are_one_line_and_dir_is_the_public_api(run: Any) -> None:
    """A notebook cell ending in a result or a model shows a line, not 10^5 characters."""
    import archself

    text = repr(run)
    assert "\n" not in text and len(text) < 300 and text.startswith("RunResult(scenario=")
    assert f"seed={run.seed}" in text
    arch = archself.load(str(DIFFDRIVE))
    assert repr(arch) == ("Architecture(name='diffdrive', modules=15, edges=39, "
                          "configurations=4, actions=7, scenarios=8)")
    assert dir(archself) == sorted([*archself.__all__, "__version__"])


def test_html_displays_are_short_whatever_the_size(run: Any, tmp_path) -> None:
    """Architecture, RunReport and CampaignOutcome show as bounded, escaped cards."""
    from pathlib import Path

    from archself.campaign.driver import CampaignOutcome
    from archself.model.generate import generate_architecture
    from archself.reports.run import build_run_report

    small = archself.load(DIFFDRIVE)._repr_html_()
    assert "diffdrive" in small and "a1 (initial)" in small and "15 (" in small
    big_file = tmp_path / "big.yaml"
    big_file.write_text(generate_architecture(2000, seed=1), encoding="utf-8")
    big = archself.load(big_file, check=False)
    page = big._repr_html_()
    assert "2000 (" in page and "(1992 more)" in page and len(page) < 2 * len(small) + 500
    odd = big.model_copy(update={"description": "<b>x</b>"})
    assert "<b>x</b>" not in odd._repr_html_() and "&lt;b&gt;x&lt;/b&gt;" in odd._repr_html_()

    report = build_run_report(None, [run])
    assert "\n" not in repr(report) and len(repr(report)) < 300  # not the series
    rep = report._repr_html_()
    assert "actuator_fault" in rep and "a1 → a3" in rep and "max error [m]" in rep

    campaign = Path(__file__).parents[1] / "docs" / "campaign" / "campaign.parquet"
    outcome = CampaignOutcome(campaign, 1008, 0, 1008, 0, 1008, 2, "local", 60.0)
    card = outcome._repr_html_()
    assert "1008 in the file" in card and "… (30 more)" in card  # 42 groups, 12 shown
    assert len(card) < 5000
    frame = outcome.table()
    assert len(frame) == 42 and frame["runs"].sum() == 1008
    assert set(frame.index.names) == {"scenario", "runtime.threshold", "mode"}
    gone = CampaignOutcome(tmp_path / "none.parquet", 1, 0, 0, 1, 0, 1, "inline", 0.1)
    assert "no such file" in gone._repr_html_()  # a card saying why, not an exception


def test_run_plot_is_the_error_over_time(run: Any) -> None:
    fixed = dataclasses_replace_mode(run)
    fig = run.plot(fixed, size="one")
    (ax,) = fig.axes
    assert ax.get_ylabel() == "tracking error [m]" and ax.get_title() == ""
    labels = [line.get_label() for line in ax.get_lines()]
    assert labels[:2] == ["fixed architecture", "adaptive architecture"]
    switch = [line for line in ax.get_lines() if line.get_label() == "architecture switch"]
    np.testing.assert_allclose(switch[0].get_xdata()[0], run.switches[0]["t_s"], atol=1e-9)
    np.testing.assert_allclose(ax.get_lines()[1].get_ydata(), run.series["J"], rtol=0)
    assert fig.get_figwidth() == 3.5
    assert run.plot(title=True).axes[0].get_title() == "Tracking error: actuator_fault"
    png = fig._repr_png_()
    assert png[:4] == b"\x89PNG" and len(png) < 60_000


def dataclasses_replace_mode(run: Any) -> Any:
    """The same run relabelled fixed with J doubled: a second curve to tell apart."""
    import dataclasses

    return dataclasses.replace(run, mode="fixed", switches=[],
                               series={**run.series, "J": 2 * np.asarray(run.series["J"])})
