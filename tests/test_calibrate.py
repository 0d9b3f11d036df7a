"""``archself calibrate``: bands from nominal runs for a stated false-alarm rate.

The process plant with its scenarios shortened to 120 s (2 s per seed in all four
configurations) keeps this file at about 20 s.
"""

from __future__ import annotations

import json
import math
import os
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from typer.testing import CliRunner

from archself.calibration.bands import _max_abs_z, cycle_scales, influence_block
from archself.calibration.edit import format_band, set_nominals
from archself.calibration.runs import Recorder, seeds_from
from archself.cli import app

from conftest import ROOT

PLANT = ROOT / "architectures" / "process_plant.yaml"


def short_plant(tmp: Path, duration: int = 120) -> Path:
    """The process plant with every scenario shortened (text edit: comments kept)."""
    text = PLANT.read_text(encoding="utf-8").replace("duration_s: 600", f"duration_s: {duration}")
    path = tmp / "plant.yaml"
    path.write_text(text, encoding="utf-8")
    return path


@cache
def _calibration(tmp: str):
    from archself.calibration import calibrate

    return calibrate(
        short_plant(Path(tmp)), seeds=16, false_switch=0.1, configurations=["p1"],
        executor="inline",
    )


@pytest.fixture(scope="module")
def cal(tmp_path_factory: pytest.TempPathFactory):
    return _calibration(str(tmp_path_factory.mktemp("cal")))


# ------------------------------------------------------------------ the arithmetic
def test_cycle_scale_is_the_edge_of_the_candidate_set() -> None:
    rng = np.random.default_rng(3)
    x = rng.gamma(2.0, 0.5, (200, 3))
    x[:5] = 0.0  # no signal: no band raises a candidate
    base = np.array([0.5, 1.0, 2.0])
    sens = np.array([1.0, 0.5, 2.0])
    w = np.array([[0, 0.5, 0], [0, 0, 0.4], [0.2, 0, 0]])  # a loop a -> b -> c -> a
    m = np.linalg.inv(np.eye(3) - w.T)
    s = cycle_scales(x, base, sens, m, 0.8)
    assert np.all(s[:5] == 0) and np.all(s[5:] > 0)
    below = _max_abs_z(x[5:], (s[5:] * (1 - 1e-6))[:, None] * base, sens, m)
    above = _max_abs_z(x[5:], (s[5:] * (1 + 1e-6))[:, None] * base, sens, m)
    assert np.all(below >= 0.8) and np.all(above < 0.8)


def test_a_channels_closed_form_scale_is_the_bisections() -> None:
    from archself.calibration.bands import Cell, channel_scales, critical_scales

    rng = np.random.default_rng(4)
    w = np.array([[0, 0.5, 0], [0, 0, 0.4], [0.2, 0, 0]])
    m = np.linalg.inv(np.eye(3) - w.T)
    x = [rng.gamma(2.0, 0.5, (50, 3)) for _ in range(6)]
    cell = Cell("s", "c", ["a", "b", "c"], x, np.zeros(6, dtype=bool), m, np.array([1, 0.5, 2]))
    bands = {"a": 0.5, "b": 1.0, "c": 2.0}
    per = channel_scales(cell, bands, 0.8)
    for j in range(3):
        alone = Cell("s", "c", cell.modules, [np.where(np.arange(3) == j, xr, 0) for xr in x],
                     cell.forced, m, cell.sens)
        assert np.allclose(per[:, j], critical_scales(alone, bands, 0.8), rtol=1e-7)
    # the whole run alarms at least as early as its strongest channel
    assert np.all(critical_scales(cell, bands, 0.8) >= per.max(axis=1) * (1 - 1e-7))


def test_format_band_rounds_up() -> None:
    for v in (0.000612345, 0.15, 1.0, 12345.6, 3.3e-7):
        text = format_band(v)
        assert float(text) >= v and float(text) <= v * 1.01
    with pytest.raises(ValueError):
        format_band(math.inf)


def test_offline_z_is_the_runtimes(tmp_path: Path) -> None:
    """max |z| from the recorded residuals equals the MapeK decision log's, cycle by cycle."""
    from archself.model.loader import load_architecture
    from archself.runtime import MapeK
    from archself.sim.run import simulate

    arch = load_architecture(short_plant(tmp_path, 90)).arch
    for spec in arch.modules.values():  # tight bands, so that z is not 0 ...
        if spec.residual is not None:
            spec.residual.nominal *= 0.1
    arch.runtime.threshold = 1e3  # ... and a τ that never lets the loop act
    names = [m for m, s in arch.modules.items() if s.residual]
    rec = Recorder(arch, names)
    simulate(arch.model_copy(deep=True), "nominal", seed=5, adapt=rec)
    loop = MapeK(arch)
    simulate(arch.model_copy(deep=True), "nominal", seed=5, adapt=loop)
    active = [m for m in names if m in arch.configurations["p1"].modules]
    m = influence_block(arch, "p1", active)
    cols = [names.index(a) for a in active]
    bands = np.array([arch.modules[a].residual.nominal for a in active])
    sens = np.array([arch.modules[a].residual.sensitivity for a in active])
    offline = _max_abs_z(np.array(rec.x)[:, cols], bands, sens, m)
    records = [d for d in loop.decisions if d.phase != "warmup"]
    assert len(records) == len(offline) == 90 and not loop.switches
    for k, rec_k in enumerate(records):
        z = [abs(v) for v in rec_k.to_dict()["z"].values() if v is not None]
        assert offline[k] == pytest.approx(max(z), rel=1e-9, abs=1e-12)
    assert offline.max() > 0 and np.count_nonzero(offline) > 10


# ------------------------------------------------------------------ bands and rates
def test_bands_are_positive_and_finite(cal) -> None:
    assert cal.scale > 0 and math.isfinite(cal.scale)
    for name in ("valve", "observer_a", "pi"):
        b = cal.modules[name]
        assert b.calibrated and b.new > 0 and math.isfinite(b.new)
    assert not cal.modules["observer_b"].calibrated  # not active in p1: kept
    assert cal.modules["observer_b"].new == cal.modules["observer_b"].old
    (cell,) = cal.cells
    assert cell.runs == 16 and cell.new_empirical <= 0.1
    assert cell.new_predicted == pytest.approx(0.1, abs=0.03)


def test_calibration_shows_in_a_line_and_a_short_card(cal) -> None:
    text = repr(cal)
    assert "\n" not in text and len(text) < 200 and "false_switch=0.1" in text
    assert f"runs={cal.runs}" in text
    page = cal._repr_html_()
    assert "observer_a" in page and f"{cal.modules['valve'].new:.4g}" in page
    assert len(page) < 3000


def test_calibrated_bands_hold_their_rate_on_fresh_seeds(cal) -> None:
    """Adaptive nominal runs on 24 unseen seeds: false alarms within the binomial tolerance.

    p = 0.1 over 24 runs: 2.4 expected, P(X ≥ 8) < 0.002. Halving the bands must
    break the check (it is not vacuous).
    """
    from archself.model.loader import load_text
    from archself.runtime import MapeK
    from archself.sim.run import simulate

    arch = load_text(cal.text, "calibrated.yaml").arch
    fresh = seeds_from(0, 16, 24)
    assert not set(fresh) & set(cal.data[0].seeds)

    def alarms(a) -> tuple[int, int]:
        runs_with_candidates = switches = 0
        for seed in fresh:
            loop = MapeK(a)
            res = simulate(a.model_copy(deep=True), "nominal", seed=seed, adapt=loop)
            late = loop.decisions[a.runtime.warmup_steps :]
            runs_with_candidates += any(d.candidates for d in late)
            switches += bool(res.switches)
        return runs_with_candidates, switches

    with_cand, switched = alarms(arch)
    assert switched <= with_cand <= 7
    tight = arch.model_copy(deep=True)
    for name, b in cal.modules.items():
        if b.calibrated:
            tight.modules[name].residual.nominal = b.new * 0.5
    assert alarms(tight)[0] >= 12


# ------------------------------------------------------------------ the calibrated copy
def test_cli_writes_a_calibrated_copy_that_keeps_comments(tmp_path: Path) -> None:
    src = short_plant(tmp_path)
    before = src.read_text(encoding="utf-8")
    out, rep = tmp_path / "calibrated.yaml", tmp_path / "report"
    result = CliRunner().invoke(
        app,
        [
            "calibrate", str(src), "--seeds", "4", "-c", "p1", "-c", "p2", "--workers", "2",
            "--false-switch", "0.25", "-o", str(out), "--report", str(rep), "--json",
            "--save-runs", str(tmp_path / "runs.npz"),
        ],
    )
    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["runs"] == 8 and data["executor"] == "local"
    assert src.read_text(encoding="utf-8") == before  # the input is untouched
    text = out.read_text(encoding="utf-8")
    old_lines, new_lines = before.splitlines(), text.splitlines()
    assert len(old_lines) == len(new_lines)
    changed = [(a, b) for a, b in zip(old_lines, new_lines, strict=True) if a != b]
    calibrated = [m for m, b in data["bands"].items() if b["calibrated"]]
    assert len(changed) == len(calibrated) == 4  # valve, both observers, pi
    for a, b in changed:
        assert "nominal:" in a and "# calibrated: p = 0.25/run, 4 nominal runs" in b
    comments = [line for line in old_lines if line.lstrip().startswith("#")]
    assert comments and all(c in new_lines for c in comments)

    from archself.check import check, has_errors
    from archself.model.loader import load_architecture

    loaded = load_architecture(out)
    assert not has_errors(check(loaded))
    for m in calibrated:
        assert loaded.arch.modules[m].residual.nominal == data["bands"][m]["new"] > 0
    for name in ("index.html", "calibration.md", "calibration.json", "tail.svg"):
        assert (rep / name).is_file()
    html = (rep / "index.html").read_text(encoding="utf-8")
    assert "observer_a" in html and "Gumbel" in html

    # the saved runs give the same bands offline, also for the calibrated copy ...
    again = CliRunner().invoke(
        app,
        ["calibrate", str(out), "--from-runs", str(tmp_path / "runs.npz"), "--json",
         "--false-switch", "0.25"],
    )
    assert again.exit_code == 0, again.stderr
    assert {m: b["new"] for m, b in json.loads(again.stdout)["bands"].items()} == {
        m: b["new"] for m, b in data["bands"].items()
    }
    # ... but not for another architecture
    other = tmp_path / "other.yaml"
    other.write_text(before.replace("weight: 0.6, carries: inflow", "weight: 0.5, carries: inflow"),
                     encoding="utf-8")
    refused = CliRunner().invoke(
        app, ["calibrate", str(other), "--from-runs", str(tmp_path / "runs.npz")]
    )
    assert refused.exit_code == 1 and "runs of another architecture" in refused.stderr


def test_set_nominals_edits_only_the_numbers() -> None:
    text = (
        "modules:\n"
        "  a:  # the first\n"
        "    residual: {signal: e, nominal: 0.5}   # hand-tuned\n"
        "  b:\n"
        "    residual:\n"
        "      signal: e\n"
        "      nominal: 2.0  # calibrated: old note\n"
        "      smoothing_s: 1\n"
    )
    out = set_nominals(text, "t.yaml", {"a": 0.25, "b": 3.14159}, "note", verify=False)
    assert out.splitlines() == [
        "modules:",
        "  a:  # the first",
        "    residual: {signal: e, nominal: 0.25}   # hand-tuned; calibrated: note",
        "  b:",
        "    residual:",
        "      signal: e",
        "      nominal: 3.15  # calibrated: note",
        "      smoothing_s: 1",
    ]


# ------------------------------------------------------------------ refusals
def test_the_input_is_never_overwritten_without_force(tmp_path: Path) -> None:
    src = short_plant(tmp_path)
    before = src.read_text(encoding="utf-8")
    link = tmp_path / "same-inode.yaml"
    os.link(src, link)
    run = CliRunner().invoke
    for args, code in (
        (["-o", str(src)], 1),
        (["-o", str(link)], 1),  # another name of the same file
        (["-o", str(link), "--force"], 1),  # --force alone never replaces the input
        (["--in-place"], 2),
        (["--in-place", "-o", str(tmp_path / "x.yaml"), "--force"], 2),
    ):
        result = run(app, ["calibrate", str(src), "--seeds", "1", *args])
        assert result.exit_code == code, (args, result.stderr)
        assert len(result.stderr.strip().splitlines()) == 1
    assert src.read_text(encoding="utf-8") == before
    result = run(
        app,
        ["calibrate", str(src), "--seeds", "2", "-c", "p1", "--false-switch", "0.5",
         "--in-place", "--force", "--workers", "1"],
    )
    assert result.exit_code == 0, result.stderr
    after = src.read_text(encoding="utf-8")
    assert after != before and "# calibrated:" in after
    assert link.read_text(encoding="utf-8") == before  # replaced atomically (new inode)


def test_user_errors_are_located_one_liners(tmp_path: Path) -> None:
    src = short_plant(tmp_path)
    text = src.read_text(encoding="utf-8")
    run = CliRunner().invoke
    result = run(app, ["calibrate", str(src), "-s", "level_drift", "--seeds", "1"])
    assert result.exit_code == 1
    assert "scenarios.level_drift.faults: scenario 'level_drift' has faults" in result.stderr
    assert result.stderr.startswith(f"{src}:")
    none = tmp_path / "none.yaml"
    none.write_text(text.replace("normalization: nominal", "normalization: none"), "utf-8")
    result = run(app, ["calibrate", str(none), "--seeds", "1"])
    assert result.exit_code == 1
    line = next(i for i, t in enumerate(text.splitlines(), 1) if "normalization:" in t)
    assert result.stderr.startswith(f"{none}:{line}:")
    assert run(app, ["calibrate", str(src), "--false-switch", "0"]).exit_code == 2
    assert run(app, ["calibrate", str(src), "--executor", "ray"]).exit_code == 2


def test_a_damaged_runs_file_is_a_one_line_error(tmp_path: Path) -> None:
    """--from-runs with the right digest but damaged metadata or arrays: exit 1, not 3."""
    from archself.calibration import calibrate

    src = short_plant(tmp_path, 30)
    good = tmp_path / "runs.npz"
    calibrate(src, seeds=1, false_switch=0.1, configurations=["p1"], executor="inline",
              save_runs=good)
    z = dict(np.load(good, allow_pickle=False))
    meta = json.loads(str(z.pop("meta")))
    cases = {
        "meta_text": (z, "x", "(meta: expected an object, got a string)"),
        "no_seeds": (z, {k: v for k, v in meta.items() if k != "seeds"},
                     "(meta.seeds: expected an integer, got nothing)"),
        "no_phase": (z, {**meta, "runs": [{k: v for k, v in r.items() if k != "phase"}
                                          for r in meta["runs"]]},
                     "(meta.runs[0].phase: expected one of calibration, verify, got nothing)"),
        "bad_seed": (z, {**meta, "root_seed": True},
                     "(meta.root_seed: expected an integer, got bool)"),
        "x_1d": ({**z, "x0": z["x0"][:, 0]}, meta, "arrays of run 0"),
        "x_narrow": ({**z, "x0": z["x0"][:, :2]}, meta, "does not fit"),
        "unknown_conf": (z, {**meta, "runs": [dict(r, configuration="zz")
                                              for r in meta["runs"]]}, "does not fit"),
    }
    for name, (arrays, m, msg) in cases.items():
        bad = tmp_path / f"{name}.npz"
        np.savez(bad, **arrays, meta=np.array(json.dumps(m)))
        result = CliRunner().invoke(app, ["calibrate", str(src), "--from-runs", str(bad)])
        assert result.exit_code == 1 and msg in result.stderr, (name, result.output)
        assert len(result.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("args", [["--seeds", "1000000000000"],
                                  ["--seeds", "1", "--verify-seeds", "1000000000000"]])
def test_too_many_runs_are_refused_before_any_starts(tmp_path: Path, args: list[str]) -> None:
    """They grew the driver past 1.8 GB in 30 s (every job built, no run started)."""
    result = CliRunner().invoke(app, ["calibrate", str(short_plant(tmp_path)), "-c", "p1", *args])
    assert result.exit_code == 1, result.output
    assert "more than half of this machine's memory" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


# ------------------------------------------------------------------ operating envelope
def test_an_envelope_widens_the_bands_to_its_worst_point(tmp_path: Path) -> None:
    from archself.calibration import CalibrationError, calibrate

    plant = short_plant(tmp_path, 90)
    common = dict(seeds=6, false_switch=0.1, executor="inline")
    quiet = calibrate(plant, configurations=["p2"], **common)
    noisy = calibrate(plant, envelope=["modules.level_b.params.noise_m.value=0.008,0.032"],
                      configurations=["p2"], **common)
    assert noisy.runs == 2 * quiet.runs  # every point of the envelope gets as many seeds
    # observer B's innovation (m) reads transmitter B: its band grows with the worst noise
    assert noisy.modules["observer_b"].new > 1.5 * quiet.modules["observer_b"].new
    assert "× 2 envelope points" in noisy.text
    # observer A's transmitter check is in standard errors: the same band at any noise
    quiet_a = calibrate(plant, configurations=["p1"], **common)
    noisy_a = calibrate(plant, envelope=["modules.level_a.params.noise_m.value=0.005,0.02"],
                        configurations=["p1"], **common)
    assert_allclose(noisy_a.modules["observer_a"].new, quiet_a.modules["observer_a"].new,
                    rtol=0.25)
    with pytest.raises(CalibrationError, match="--envelope"):
        calibrate(plant, envelope=["modules.nope.params.x.value=1,2"], **common)


def test_each_envelope_point_runs_seeds_of_its_own() -> None:
    """The runs of all points are pooled into one tail fit, so each must be a fresh
    draw: with one set of seeds for every point, a statistic that does not depend on
    the noise (the robot's drift test) repeated its maximum at every point."""
    from archself.calibration.runs import plan_runs
    from archself.campaign import parse_sweep

    text = (ROOT / "architectures" / "process_plant.yaml").read_text()
    env = [parse_sweep("modules.level_b.params.noise_m.value=0.008,0.032")]
    seeds = seeds_from(0, 0, 6)
    jobs = plan_runs(text, "plant.yaml", ["nominal"], ["p1"], seeds, envelope=env)
    by_point: dict[tuple[float, ...], list[int]] = {}
    for job in jobs:
        by_point.setdefault(job.point, []).append(job.seed)
    assert by_point == {(0.008,): seeds[:3], (0.032,): seeds[3:]}
    assert sorted(job.replicate for job in jobs) == [0, 0, 1, 1, 2, 2]
    with pytest.raises(ValueError, match="do not split"):
        plan_runs(text, "plant.yaml", ["nominal"], ["p1"], seeds[:5], envelope=env)


# ------------------------------------------------------------------ weighted budget
def test_a_weight_gives_a_channel_a_larger_share_of_the_same_budget() -> None:
    """Weighted Bonferroni: channel j alone alarms in a share p·w_j/Σw of the runs."""
    from archself.calibration.bands import Cell, channel_shape, quantile_level

    rng = np.random.default_rng(0)
    runs = [rng.gumbel(1.0, 0.1, (1, 2)) for _ in range(400)]
    cell = Cell("s", "c", ["a", "b"], runs, np.zeros(400, bool), np.zeros((2, 2)), np.ones(2))
    even = channel_shape(cell, "a", 0.01, 0.5)  # no influence: plain levels
    assert_allclose(even, quantile_level(cell.run_max("a"), 0.005), rtol=1e-12)
    heavy = {"a": 3.0}
    assert_allclose(channel_shape(cell, "a", 0.01, 0.5, heavy),
                    quantile_level(cell.run_max("a"), 0.0075), rtol=1e-12)
    assert_allclose(channel_shape(cell, "b", 0.01, 0.5, heavy),
                    quantile_level(cell.run_max("b"), 0.0025), rtol=1e-12)
    assert channel_shape(cell, "a", 0.01, 0.5, heavy) < even < channel_shape(
        cell, "b", 0.01, 0.5, heavy)


def test_a_weighted_calibration_narrows_that_band_and_says_so(tmp_path: Path, cal) -> None:
    from archself.calibration import CalibrationError, calibrate

    plant = short_plant(tmp_path)
    heavy = calibrate(plant, seeds=16, false_switch=0.1, configurations=["p1"],
                      executor="inline", weights={"observer_a": 4.0})
    assert heavy.modules["observer_a"].new < cal.modules["observer_a"].new
    assert "weight observer_a 4," in heavy.text
    assert heavy.modules["observer_a"].weight == 4.0
    assert heavy.to_dict()["bands"]["observer_a"]["weight"] == 4.0
    from archself.calibration.report import write_report

    write_report(heavy, tmp_path / "report")
    assert "per nominal run, weight observer_a 4 ·" in (
        tmp_path / "report" / "calibration.md").read_text(encoding="utf-8")
    with pytest.raises(CalibrationError, match="--weight nope=2: .* no module 'nope'"):
        calibrate(plant, seeds=1, executor="inline", weights={"nope": 2.0})
    with pytest.raises(CalibrationError, match="expected a weight > 0"):
        calibrate(plant, seeds=1, executor="inline", weights={"observer_a": 0.0})
    assert CliRunner().invoke(app, ["calibrate", str(plant), "--weight", "observer_a"]
                              ).exit_code == 2
