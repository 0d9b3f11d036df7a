"""``archself identify``: edge weights W estimated from perturbation experiments.

(a) the fitting maths (:mod:`archself.runtime.identify_fit`) on synthetic Δr;
(b) end to end on a small architecture of a test-only module type whose residuals
    propagate exactly as the model says;
(c) the command line.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from archself.runtime.identify_fit import (
    fit_edges,
    fit_target,
    propagate,
    usable_targets,
)

# --------------------------------------------------------------------------- (a) maths

#: A graph with a diamond, a cycle (d → b) and a hidden module h (no residual).
NAMES = ["a", "b", "c", "d"]
TRUE = {("a", "b"): 0.5, ("a", "c"): 0.3, ("b", "c"): 0.2, ("b", "d"): 0.4, ("c", "d"): 0.6,
        ("d", "b"): 0.1}
EDGES = [*TRUE, ("h", "d"), ("a", "h")]


def _w() -> np.ndarray:
    W = np.zeros((4, 4))
    for (s, t), w in TRUE.items():
        W[NAMES.index(s), NAMES.index(t)] = w
    return W


def test_noiseless_recovers_w_exactly() -> None:
    dr = propagate(_w(), np.eye(4) * 0.7)  # one experiment per observed module
    est, fits = fit_edges(dr, NAMES, NAMES, EDGES)
    got = {(e.source, e.target): e.weight for e in est if e.identifiable}
    assert set(got) == set(TRUE)
    assert_allclose([got[k] for k in TRUE], list(TRUE.values()), rtol=0, atol=1e-12)
    assert all(f.r2 == pytest.approx(1.0) for f in fits.values())
    hidden = [e for e in est if "h" in (e.source, e.target)]
    assert [e.reason for e in hidden] == ["source has no residual", "target has no residual"]


def test_noisy_recovery_within_tolerance() -> None:
    # 5 seeds per experiment, Δr with noise of 2 % of the excitation: |ŵ − w| ≤ 0.03
    rng = np.random.default_rng(7)
    e = np.repeat(np.eye(4), 5, axis=0)
    dr = propagate(_w(), e) + 0.02 * rng.standard_normal((20, 4))
    exps = [NAMES[k] for k in np.repeat(np.arange(4), 5)]
    est, fits = fit_edges(dr, exps, NAMES, EDGES)
    got = {(e.source, e.target): e for e in est if e.identifiable}
    assert_allclose([got[k].weight for k in TRUE], list(TRUE.values()), atol=0.03)
    # the standard errors are of the size of the error made (within a factor 3)
    err = np.array([abs(got[k].weight - w) for k, w in TRUE.items()])
    se = np.array([got[k].se for k in TRUE])
    assert np.all(se > 0) and np.all(err < 3 * se + 1e-3)
    assert min(f.r2 for f in fits.values()) > 0.95


def test_nonnegative_and_unexcited_sources() -> None:
    X = np.array([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    fit = fit_target(X, np.array([-0.1, -0.2, -0.3]))
    assert fit.identifiable.tolist() == [True, False]
    assert fit.weights[0] == 0.0 and math.isnan(fit.weights[1])
    ols = fit_target(X, np.array([-0.1, -0.2, -0.3]), nonnegative=False)
    assert_allclose(ols.weights[0], -0.1)
    # collinear sources: the second is not identifiable
    col = fit_target(np.array([[1.0, 2.0], [2.0, 4.0]]), np.array([1.0, 2.0]))
    assert col.identifiable.tolist() == [True, False]


def test_no_usable_experiment_is_no_fit() -> None:
    """Every perturbed run failed (or none was usable): an empty fit, not a reshape error."""
    fit = fit_target(np.zeros((0, 2)), np.zeros(0))
    assert fit.rows == 0 and fit.identifiable.tolist() == [False, False]
    (est,), _ = fit_edges(np.zeros((0, 2)), [], ["a", "b"], [("a", "b")])
    assert not est.identifiable and est.reason == "no usable experiment"


def test_hidden_paths_exclude_equations() -> None:
    edges = [("w", "chassis"), ("chassis", "enc"), ("enc", "odo"), ("enc", "w"),
             ("odo", "lqr"), ("lqr", "w"), ("imu", "odo")]
    obs = ["w", "odo", "lqr"]
    # a wheel perturbation reaches odometry past every observed residual
    assert usable_targets("w", obs, edges) == {"lqr"}
    assert usable_targets("imu", obs, edges) == {"w", "lqr"}
    assert usable_targets("enc", obs, edges) == {"lqr"}
    assert usable_targets("lqr", obs, edges) == {"w", "odo"}


# --------------------------------------------------------------------------- (b) end to end
# A test-only pair of module types whose residuals obey (I − Wᵀ) r = e exactly:
# ``idtest.node`` publishes level = base + Σ gains[k]·level_k (last step's inputs, in
# the file order of its incoming edges, plus noise); its residual signal ``measured`` is
# its own published level (faults included) read back through an ``idtest.echo``, the
# way a wheel's command error is read back through the encoders. Runs are inline, so
# the types registered here are seen by the runs.

from archself import registry  # noqa: E402
from archself.modules.base import Param, RuntimeModule  # noqa: E402


class _Node(RuntimeModule):
    role = "node"
    optional_inputs = ("level", "echo")
    multi_inputs = ("level",)
    outputs = ("level",)
    residual_signals = ("measured",)
    fault_kinds = frozenset({"bias"})
    direct_feedthrough = False
    parameters = {"base": Param(1.0), "gains": Param([]), "noise": Param(0.02)}

    def __init__(self, name, params, rng):
        super().__init__(name, params, rng)
        self.state = float(self.params["base"])
        self.signals = {"measured": math.nan}

    def output(self, t):
        return {"level": self.state}

    def step(self, t, dt, inputs):
        levels = inputs.get("level") or []
        gains = list(self.params["gains"])
        total = sum(g * float(v) for g, v in zip(gains, levels, strict=False) if v is not None)
        noise = float(self.params["noise"]) * float(self.rng.standard_normal())
        self.state = float(self.params["base"]) + total + noise
        echo = inputs.get("echo")
        if echo is not None:
            self.signals["measured"] = float(echo)
        return {}


class _Echo(RuntimeModule):
    role = "sensor"
    inputs = ("level",)
    outputs = ("echo",)
    parameters = {}

    def step(self, t, dt, inputs):
        v = inputs.get("level")
        return {"echo": None if v is None else float(v)}


#: True weights (the nodes' gains) of the synthetic file; its a → c is declared 0.1.
TOY_TRUE = {("a", "b"): 0.5, ("a", "c"): 0.3, ("b", "c"): 0.2, ("b", "d"): 0.4,
            ("c", "d"): 0.6, ("d", "b"): 0.1}
TOY_DECLARED = {**TOY_TRUE, ("a", "c"): 0.1}

TOY_YAML = """\
# A synthetic architecture for archself identify (tests/test_identify.py).
archself: 1
name: identify-toy
modules:
  a: {kind: functional, type: idtest.node, params: {base: {value: 1.0}, gains: {value: []}},
      residual: {signal: measured, nominal: 0.1, smoothing_s: 0}}
  b: {kind: functional, type: idtest.node, params: {base: {value: 0.5}, gains: {value: [0.5, 0.1]}},
      residual: {signal: measured, nominal: 0.1, smoothing_s: 0}}
  c: {kind: functional, type: idtest.node, params: {base: {value: 0.2}, gains: {value: [0.3, 0.2]}},
      residual: {signal: measured, nominal: 0.1, smoothing_s: 0}}
  d: {kind: functional, type: idtest.node, params: {base: {value: 0.1}, gains: {value: [0.4, 0.6]}},
      residual: {signal: measured, nominal: 0.1, smoothing_s: 0}}
  ea: {kind: physical, type: idtest.echo}
  eb: {kind: physical, type: idtest.echo}
  ec: {kind: physical, type: idtest.echo}
  ed: {kind: physical, type: idtest.echo}
edges:
  - {from: a, to: b, weight: 0.5, carries: level}
  - {from: d, to: b, weight: 0.1, carries: level}   # a cycle b -> d -> b
  - {from: a, to: c, weight: 0.1, carries: level}   # declared wrong: the gain is 0.3
  - {from: b, to: c, weight: 0.2, carries: level}
  - {from: b, to: d, weight: 0.4, carries: level}
  - {from: c, to: d, weight: 0.6, carries: level}
  - {from: a, to: ea, weight: 0.05, carries: level}
  - {from: b, to: eb, weight: 0.05, carries: level}
  - {from: c, to: ec, weight: 0.05, carries: level}
  - {from: d, to: ed, weight: 0.05, carries: level}
  - {from: ea, to: a, weight: 0.05, carries: echo}
  - {from: eb, to: b, weight: 0.05, carries: echo}
  - {from: ec, to: c, weight: 0.05, carries: echo}
  - {from: ed, to: d, weight: 0.05, carries: echo}
configurations:
  all: {initial: true, modules: [a, b, c, d, ea, eb, ec, ed]}
  chain: {modules: [a, b, d, ea, eb, ed]}
scenarios:
  nominal: {duration_s: 20, seed: 1}
runtime:
  step_s: 0.1
  period_s: 0.5
  objective: {actual: d.level, reference: a.level}
  threshold: 1.0
  warmup_s: 2.0
  cost_weight: 0.1
  stability: {margin: 0.001, lyapunov_alpha: 0.01, horizon_steps: 10}
"""


@pytest.fixture
def toy_types():
    registry.add("idtest.node", _Node)
    registry.add("idtest.echo", _Echo)
    yield
    registry.unregister("idtest.node")
    registry.unregister("idtest.echo")


@pytest.fixture
def toy_file(tmp_path, toy_types):
    p = tmp_path / "toy.yaml"
    p.write_text(TOY_YAML, encoding="utf-8")
    return p


def test_toy_file_is_valid(toy_file) -> None:
    from archself.check import check
    from archself.model.loader import load_architecture

    findings = check(load_architecture(toy_file))
    assert not [f for f in findings if f.severity == "error"], findings


def test_identify_recovers_toy_weights(toy_file) -> None:
    from archself.calibration.identify import identify, written_copy

    ident = identify(toy_file, seeds=2, executor="inline")
    rows = {(r.configuration, r.source, r.target): r for r in ident.rows}
    # configuration "all": every edge between nodes is identified; the linear toy with
    # common random numbers gives the gains to 1e-6
    for (s, t), w in TOY_TRUE.items():
        r = rows[("all", s, t)]
        assert r.identifiable, (s, t, r.reason)
        assert_allclose(r.fitted, w, atol=1e-6)
        assert r.declared == TOY_DECLARED[(s, t)]
        assert r.differs is ((s, t) == ("a", "c"))
    assert all(f.r2 > 0.999999 for f in ident.fits["all"].values())
    # edges to and from the echoes are reported, not guessed
    echo = [r for r in ident.rows if r.target.startswith("e") or r.source.startswith("e")]
    assert echo and not any(r.identifiable for r in echo)
    # configuration "chain" (no c): b's edges from a and d, d's from b
    assert_allclose(rows[("chain", "b", "d")].fitted, 0.4, atol=1e-6)
    assert ("chain", "a", "c") not in rows
    # the written copy: fitted weights in place, comments kept
    text = written_copy(ident)
    assert "{from: a, to: c, weight: 0.3, carries: level}   # declared wrong" in text
    assert "# identified: archself identify" in text
    assert text.startswith("# A synthetic architecture")
    assert "weight: 0.05" in text  # unidentifiable edges keep their declared weight


# --------------------------------------------------------------------------- (c) command line
def test_cli_identify_table_report_and_write_back(toy_file, tmp_path) -> None:
    from typer.testing import CliRunner

    from archself.cli import app

    report, copy = tmp_path / "report.md", tmp_path / "fitted.yaml"
    res = CliRunner().invoke(
        app,
        ["identify", str(toy_file), "--seeds", "2", "--executor", "inline", "-c", "all",
         "-o", str(report), "--write-back", str(copy)],
    )
    assert res.exit_code == 0, res.output
    assert "configuration all" in res.stdout
    assert "  a -> c     0.100     0.300    0.000  DIFFERS" in res.stdout
    assert "  a -> b     0.500     0.500    0.000  ok" in res.stdout
    assert "| all | a → c | 0.100 | 0.300 | 0.000 | DIFFERS |" in report.read_text()
    assert "weight: 0.3, carries: level}   # declared wrong" in copy.read_text()
    # --write-back does not replace an existing file without --force, nor the input ever
    again = CliRunner().invoke(
        app, ["identify", str(toy_file), "--executor", "inline", "--write-back", str(copy)]
    )
    assert again.exit_code == 1 and "exists; pass --force" in again.stderr
    onto = CliRunner().invoke(
        app, ["identify", str(toy_file), "--executor", "inline", "--force",
              "--write-back", str(toy_file)]
    )
    assert onto.exit_code == 1 and "is the input file" in onto.stderr
    js = CliRunner().invoke(
        app, ["identify", str(toy_file), "--seeds", "1", "--executor", "inline", "--json",
              "-c", "chain"]
    )
    assert js.exit_code == 0
    import json

    data = json.loads(js.stdout)
    bd = next(e for e in data["edges"] if (e["source"], e["target"]) == ("b", "d"))
    assert bd["identifiable"] and abs(bd["fitted"] - 0.4) < 1e-6


def test_cli_identify_errors_are_one_line(tmp_path) -> None:
    from typer.testing import CliRunner

    from archself.cli import app

    missing = CliRunner().invoke(app, ["identify", str(tmp_path / "nope.yaml")])
    assert missing.exit_code == 1
    assert missing.stderr.strip().count("\n") == 0 and "no such file" in missing.stderr
    bad = CliRunner().invoke(app, ["identify", str(tmp_path / "x.yaml"), "--perturb", "imu"])
    assert bad.exit_code == 2 and "MODULE=KIND:MAGNITUDE" in bad.stderr


@pytest.mark.parametrize(
    ("args", "msg"),
    [  # refused before any run: every run failed, or the fit crashed, or jobs filled memory
        (["--magnitude", "1e308"], "--magnitude 1e+308: fault magnitude: "),
        (["--perturb", "a=bias:1e308"], "--perturb a=bias:1e+308: fault magnitude: "),
        (["--settle", "-1"], "--settle -1: expected a time ≥ 0 s"),
        (["--settle", "nan"], "--settle nan: expected a time ≥ 0 s"),
        (["--min-excitation", "nan"], "--min-excitation nan: expected a number ≥ 0"),
        (["--seeds", "10000000000000"], "more than half of this machine's memory"),
    ],
)
def test_cli_identify_refuses_bad_values(toy_file, args, msg) -> None:
    from typer.testing import CliRunner

    from archself.cli import app

    res = CliRunner().invoke(app, ["identify", str(toy_file), "--executor", "inline", *args])
    assert res.exit_code == 1 and msg in res.stderr, res.output
    assert res.stderr.strip().count("\n") == 0
