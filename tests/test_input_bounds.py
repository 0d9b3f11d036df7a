"""Inputs bounded by meaning (issue 18): inputs too special or too large for a fixture file.

A FIFO and 16 MB of waypoints are made here at run time; their messages are golden
files in ``tests/golden/input_bounds/`` (the temporary folder written as ``TMP``).
The fixtures of the other cases are in ``tests/fixtures/invalid/``
(``make_bound_fixtures.py``). No time is asserted (``bench/`` measures); a hang
would show as the subprocess timeout.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from archself.errors import LoadError
from archself.model.loader import MAX_YAML_BYTES, SchemaError, load_text

from conftest import FIXTURES, ROOT, compare_golden

GOLDEN = ROOT / "tests" / "golden" / "input_bounds"
MINIMAL = (FIXTURES / "valid" / "minimal.yaml").read_text()


def _cli(args: list[str], tmp_path: Path) -> subprocess.CompletedProcess[str]:
    """``archself ARGS`` in a subprocess (a FIFO would block it forever: bounded by a timeout)."""
    return subprocess.run(
        [sys.executable, "-m", "archself", *args], capture_output=True, text=True,
        timeout=60, cwd=tmp_path, env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )


@pytest.mark.parametrize("command", ["validate", "simulate", "report"])
def test_a_fifo_is_refused_before_reading(tmp_path: Path, command: str, regen: bool) -> None:
    """No writer ever opens the FIFO: reading it would block forever."""
    fifo = tmp_path / "arch.yaml"
    os.mkfifo(fifo)
    args = {"validate": ["validate", "arch.yaml"],
            "simulate": ["simulate", "arch.yaml", "-s", "calm"],
            "report": ["report", "arch.yaml", "-o", "out"]}[command]
    result = _cli(args, tmp_path)
    assert result.returncode == 1
    assert result.stdout == ""
    assert "Traceback" not in result.stderr
    assert result.stderr.count("\n") == 1, "one line"
    compare_golden(GOLDEN / f"fifo_{command}.expected", result.stderr, regen)
    assert not (tmp_path / "out").exists()


def test_the_loader_refuses_a_fifo(tmp_path: Path) -> None:
    """The Python API too (``load_architecture``), not only the command line."""
    from archself.model.loader import load_architecture

    fifo = tmp_path / "arch.yaml"
    os.mkfifo(fifo)
    with pytest.raises(LoadError, match=r"is a FIFO \(named pipe\), expected a regular file"):
        load_architecture(fifo)


def _waypoints(n: int) -> str:
    points = ", ".join(f"[{0.5 * i:.1f}, {(i * 7919) % 1000 / 1000:.6f}]" for i in range(n))
    return MINIMAL.replace("waypoints: {value: [[0, 0], [5, 1], [10, 0]], unit: m}",
                           f"waypoints: {{value: [{points}], unit: m}}")


def test_16_mb_of_waypoints_are_refused_at_load(tmp_path: Path, regen: bool) -> None:
    """Over the YAML cap: refused before parsing, located where the cap is passed."""
    big = tmp_path / "waypoints.yaml"
    big.write_text(_waypoints(800_000))
    assert big.stat().st_size > 16 * 10**6
    result = _cli(["validate", "waypoints.yaml"], tmp_path)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr and "MemoryError" not in result.stderr
    (line,) = result.stderr.splitlines()
    assert line.startswith("waypoints.yaml:16:")  # the line of the waypoints
    compare_golden(GOLDEN / "huge_waypoints.expected", result.stderr, regen)


def test_too_many_numbers_in_one_parameter() -> None:
    """Under the byte caps, a value of more than MAX_PARAM_NUMBERS numbers is refused."""
    from archself.model.architecture import MAX_PARAM_NUMBERS

    text = _waypoints(MAX_PARAM_NUMBERS // 2 + 1)
    assert len(text) < MAX_YAML_BYTES
    with pytest.raises(SchemaError) as info:
        load_text(text, "w.yaml")
    (f,) = info.value.findings
    assert f.path == "modules.path.params.waypoints.value"
    assert f"more than the cap of {MAX_PARAM_NUMBERS:,}" in f.message
    assert f.line == 16


def test_json_documents_load_as_yaml_does() -> None:
    """JSON (YAML 1.2 includes it) goes through the json module: the same data, or the same
    refusal (a duplicate key, NaN) through the YAML path."""
    import json

    from archself.model.loader import load_data

    data, _ = load_data(MINIMAL, "m.yaml")
    as_json = "# a comment line\n" + json.dumps(data, indent=1)
    again, src = load_data(as_json, "m.json")
    assert again == data
    assert src.root is None  # nothing composed on the happy path
    assert src.locate(("runtime", "threshold"), key=False) == (
        as_json.splitlines().index('  "threshold": 0.5,') + 1, 16)
    with pytest.raises(LoadError, match="duplicate key 'a'"):
        load_data('{"a": 1, "a": 2}', "d.json")
    nan, _ = load_data('{"a": NaN}', "n.json")  # YAML reads NaN as a string
    assert nan == {"a": "NaN"}


def test_generated_100k_file_is_under_the_caps() -> None:
    """``archself generate 100000`` writes JSON under MAX_FILE_BYTES (YAML would pass 8 MiB)."""
    from archself.model.generate import generate_architecture
    from archself.model.loader import MAX_FILE_BYTES

    text = generate_architecture(100_000, seed=0)
    assert MAX_YAML_BYTES < len(text.encode()) < MAX_FILE_BYTES
    head = text.split("\n", 2)[1]
    assert head.startswith('{"archself": 1')


def test_a_declared_range_of_a_module_type_is_enforced(monkeypatch) -> None:
    """``Param(min=, max=)`` of a type bounds the file's value, min/max and an action's set."""
    from archself import registry
    from archself.check import check
    from archself.modules.base import Param

    cls = registry.lookup("sensor.encoders")
    params = dict(cls.parameters)
    params["noise_rad_s"] = Param(0.05, "rad/s", "noise", min=0.0, max=1.0)
    monkeypatch.setattr(cls, "parameters", params)
    text = MINIMAL.replace(
        "  encoders: {kind: physical, type: sensor.encoders}",
        "  encoders: {kind: physical, type: sensor.encoders, params: {noise_rad_s: "
        "{value: 5.0, max: 20}}}",
    ).replace("scenarios:", "actions:\n  - {id: tune, module: encoders, kind: parameter_update, "
              "cost: 0, set: {noise_rad_s: 3.0}, improvement: {method: sensitivity, "
              "delta_theta: -1}}\nscenarios:")
    findings = [f for f in check(load_text(text, "e.yaml")) if f.severity == "error"]
    by_path = {f.path: f.message for f in findings}
    assert by_path["modules.encoders.params.noise_rad_s.value"] == (
        "5 is outside [0, 1] rad/s, the range type 'sensor.encoders' declares for 'noise_rad_s'")
    assert "20 is outside [0, 1] rad/s" in by_path["modules.encoders.params.noise_rad_s.max"]
    assert "new value: 3 is outside [0, 1] rad/s" in by_path["actions[0].set.noise_rad_s"]


def test_the_work_estimate_matches_the_run() -> None:
    """``run_estimate`` counts the steps a run takes (the work rule's basis)."""
    from archself.check import run_estimate

    arch = load_text(MINIMAL).arch
    steps, size, work = run_estimate(arch, "calm")
    assert steps == 400  # 20 s / 0.05 s
    assert size == 400 * 250  # no residual modules
    assert work == 9 * 400  # 9 modules, no actions


@pytest.mark.parametrize("arch_file, latency, cap", [
    ("tests/fixtures/valid/minimal.yaml", "1e7", "more than the cap of 100,000,000"),
    ("architectures/motor_drive.yaml", "1e7", "copied by each of about 3,201 snapshots"),
])
def test_an_edge_latency_past_the_work_cap_is_a_located_error(arch_file: str, latency: str,
                                                               cap: str) -> None:
    # latency_s: 1e7 validated; its line of 1e8 values, copied by every action's snapshot
    # each cycle, kept motor_drive's simulate busy for hours
    from archself.check import check

    text = (ROOT / arch_file).read_text(encoding="utf-8")
    first = "weight: 0.3, carries: wheel_cmd}" if "minimal" in arch_file else "weight: 0.3}"
    text = text.replace(first, first[:-1] + f", latency_s: {latency}}}", 1)
    (f,) = [f for f in check(load_text(text, "x.yaml")) if f.code == "work"]
    assert f.severity == "error" and f.path == "edges[0].latency_s" and f.line is not None
    assert cap in f.message and "shorten latency_s or raise runtime.step_s" in f.message
    ok = text.replace(f"latency_s: {latency}", "latency_s: 1e4")  # 1e5 steps: runs in seconds
    assert [f for f in check(load_text(ok, "x.yaml")) if f.code == "work"] == []
