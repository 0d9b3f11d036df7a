"""Hostile sizes and shapes (issue 39, the input side): limits while reading, caps that
follow the real cost, build-time shapes found at validate, and a build fuzz.

Every refusal is one located line and exit 1: nesting of 30,000 to 10^6 brackets (a
SIGSEGV in the YAML composer before), integers of more than 4,300 digits (exit 3), a
list of 900,000 waypoints (1.33 GB before), a waypoint at 1e6 m (9.5 GB, then a
crash), a scenario shorter than a step (exit 0 with null metrics), a period shorter
than the step, a shape only the build refused, control characters, a 4,094-character
error line. The fuzz (:func:`fuzz_outcome`) mutates the files of the corpus with the
mutators of ``tests/test_fuzz_loader.py`` (delete, replace with junk, rename; and a
list entry removed) and, for each file that validates, builds every configuration and
steps it: no crash, no internal error, no build error without a location. No time is
asserted; the subprocesses are bounded by a timeout.
"""

from __future__ import annotations

import copy
import json
import math
import os
import random
import subprocess
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from test_fuzz_loader import _paths
from typer.testing import CliRunner

from archself.check import check, has_errors
from archself.cli import app
from archself.errors import ArchselfError, LoadError
from archself.model.loader import load_data, load_text

from conftest import DIFFDRIVE, FIXTURES, ROOT

MINIMAL = (FIXTURES / "valid" / "minimal.yaml").read_text()
HEATED = (FIXTURES / "valid" / "heated_chain.yaml").read_text()
WAYPOINTS = "waypoints: {value: [[0, 0], [5, 1], [10, 0]], unit: m}"


def _cli(args: list[str], cwd: Path, stdin: bytes | None = None) -> subprocess.CompletedProcess:
    """``archself ARGS`` in a subprocess (a crash is a signal, a hang the timeout)."""
    return subprocess.run(
        [sys.executable, "-m", "archself", *args], capture_output=True, timeout=120,
        cwd=cwd, input=stdin, env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )


def _one_located_line(proc: subprocess.CompletedProcess, name: str) -> str:
    """The one stderr line of a refusal (exit 1), located at ``name:LINE:COL``."""
    err = proc.stderr.decode()
    assert proc.returncode == 1, (proc.returncode, err[:300])
    (line,) = err.splitlines()
    assert line.startswith(f"{name}:"), line
    where = line[len(name) + 1:].split(":", 2)
    assert where[0].isdigit() and where[1].isdigit(), line
    return line


def _error_findings(text: str, file: str = "x.yaml") -> list[Any]:
    return [f for f in check(load_text(text, file)) if f.severity == "error"]


# --------------------------------------------------------------------------- 1. depth
@pytest.mark.parametrize("levels", [30_000, 10**5, 10**6])
@pytest.mark.parametrize("kind", ["yaml", "json", "stdin"])
def test_deep_nesting_is_refused_before_composing(tmp_path: Path, levels: int,
                                                  kind: str) -> None:
    """Was SIGSEGV (exit 139, no message) in the composer from about 30,000 levels."""
    if kind == "yaml":
        text = "archself: 1\nname: " + "[" * levels + "]" * levels + "\n"
    else:
        text = '{"archself": 1, "name": ' + "[" * levels + "]" * levels + "}\n"
    name = "deep.json" if kind == "json" else "deep.yaml"
    (tmp_path / name).write_text(text)
    if kind == "stdin":
        proc = _cli(["validate", "-"], tmp_path, stdin=text.encode())
        name = "<stdin>"
    else:
        proc = _cli(["validate", name], tmp_path)
    line = _one_located_line(proc, name)
    assert "nesting deeper than 64 levels" in line
    # located at the first bracket past the cap: the 65th list under the root mapping
    col = int(line.split(":")[2])
    start = text.index("[")
    assert col - (start - text.rfind("\n", 0, start)) == 64


@pytest.mark.parametrize("levels", [63, 64, 65, 66])
def test_the_depth_cap_is_the_same_for_yaml_json_and_the_prescan(monkeypatch,
                                                                 levels: int) -> None:
    """The event pre-scan, the converter and the JSON walk refuse the same documents."""
    from archself.io import yaml_source as yaml_nodes

    outcomes = set()
    for prescan_from in (0, 10**9):  # always / never pre-scanned
        monkeypatch.setattr(yaml_nodes, "_PRESCAN_FROM", prescan_from)
        monkeypatch.setattr(yaml_nodes, "MAX_COMPOSED",
                            yaml_nodes.MAX_COMPOSED if prescan_from == 0 else 10**9)
        for text in ("a: " + "[" * levels + "1" + "]" * levels,
                     '{"a": ' + "[" * levels + "1" + "]" * levels + "}"):
            try:
                load_data(text, "x")
                outcomes.add("ok")
            except LoadError as exc:
                assert "nesting deeper than 64 levels" in str(exc)
                outcomes.add("refused")
    assert outcomes == ({"ok"} if levels < 64 else {"refused"})


def test_900k_waypoints_are_refused_while_reading_in_bounded_memory() -> None:
    """A 5.4 MB YAML of 900,000 waypoints (under the 8 MiB cap) took 1.33 GB of nodes
    before the model refused it: now the event pre-scan stops at 500,000 nodes."""
    import tracemalloc

    from archself.io.yaml_source import MAX_COMPOSED

    points = ",".join(f"[{i % 10},{i % 7}]" for i in range(900_000))
    text = MINIMAL.replace(WAYPOINTS, f"waypoints: {{value: [{points}], unit: m}}")
    tracemalloc.start()
    try:
        with pytest.raises(LoadError) as info:
            load_text(text, "w.yaml")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert f"more than {MAX_COMPOSED:,} YAML nodes" in str(info.value)
    assert info.value.line == 16  # the waypoints' line, at the node past the cap
    assert peak < 100 * 2**20, f"{peak / 2**20:.0f} MiB traced"


def test_json_of_more_values_than_the_node_cap_is_refused_before_reading(monkeypatch) -> None:
    """20 million waypoint numbers in 60 MB of JSON took 89 s and 5.1 GB: the values are
    counted on the text first (the cap lowered here to keep the test small)."""
    from archself.io import yaml_source

    monkeypatch.setattr(yaml_source, "MAX_NODES", 1000)
    data, _ = load_data(MINIMAL, "m.yaml")
    data["modules"]["path"]["params"]["waypoints"]["value"] = [[0, 0]] * 400
    text = json.dumps(data, indent=1)
    with pytest.raises(LoadError, match="more than 1,000 JSON values") as info:
        load_data(text, "w.json")
    assert info.value.line is not None and info.value.line > text.count("\n") // 2


# --------------------------------------------------------------------------- 4./9. memory
def test_a_far_waypoint_is_refused_by_the_planner_estimate(tmp_path: Path) -> None:
    """One waypoint at 1e6 m (inside the declared ±1e6) used 9.5 GB, then numpy gave up."""
    text = MINIMAL.replace(WAYPOINTS, "waypoints: {value: [[0, 0], [5, 1], [1e6, 0]], "
                                      "unit: m}")
    (f,) = _error_findings(text)
    assert f.code == "build" and f.path == "modules.path.params"
    assert (f.line, f.col) == (14, 5)
    assert "would take about 22.4 GiB" in f.message and "cap of 2 GiB" in f.message
    (tmp_path / "far.yaml").write_text(text)
    line = _one_located_line(_cli(["simulate", "far.yaml", "-s", "calm"], tmp_path),
                             "far.yaml")
    assert "22.4 GiB" in line


def test_the_planner_estimate_follows_the_table_it_builds() -> None:
    """The estimate is of the arrays spline_path makes: within a factor 2 of their bytes."""
    from archself_diffdrive.planner import SplinePlanner, spline_path

    params = {"waypoints": [[0, 0], [300, 40], [600, 0]], "resolution_m": 0.02}
    path = spline_path(params["waypoints"], params["resolution_m"])
    rows = len(path["x"])
    made = rows * 8 * 5 + rows * 4 * 32  # five float arrays, then four lists of floats
    estimate = SplinePlanner.memory_estimate(params, 0.05)
    assert made < estimate < 4 * made


# --------------------------------------------------------------------------- 6. integers
@pytest.mark.parametrize("kind", ["yaml", "json", "list"])
def test_integers_over_4300_digits_are_located_errors(tmp_path: Path, kind: str) -> None:
    """Were exit 3 'internal error: ValueError: Exceeds the limit (4300 digits)'."""
    big = "9" * 5000
    text = {"yaml": f"archself: 1\nname: x\nruntime: {{step_s: {big}}}\n",
            "json": f'{{"archself": 1,\n "name": {big}}}\n',
            "list": f"archself: 1\nname: [1,\n  {big}]\n"}[kind]
    (tmp_path / "big.yaml").write_text(text)
    line = _one_located_line(_cli(["validate", "big.yaml"], tmp_path), "big.yaml")
    assert "an integer of 5,000 digits is out of range (at most 4,300 digits)" in line
    assert line.startswith({"yaml": "big.yaml:3:", "json": "big.yaml:2:",
                            "list": "big.yaml:3:3:"}[kind])


def test_a_4300_digit_integer_is_read() -> None:
    """The cap is Python's: 4,300 digits still convert (the schema then judges them)."""
    data, _ = load_data("a: " + "9" * 4300, "x")
    assert data["a"] == 10**4300 - 1


def test_traces_with_huge_integers_or_deep_nesting_say_so(tmp_path: Path) -> None:
    """Were 'not an archself trace (ValueError)' / '(RecursionError)'."""
    (tmp_path / "int.json").write_text('{"meta": {"n": ' + "9" * 5000 + "}}")
    (tmp_path / "deep.json").write_text('{"meta": ' + "[" * 10**5 + "]" * 10**5 + "}")
    for name, why in (("int.json", "an integer of 5,000 digits (at most 4,300)"),
                      ("deep.json", "nested too deeply")):
        result = CliRunner().invoke(app, ["explain", str(tmp_path / name)])
        assert result.exit_code == 1
        assert result.stderr.strip().endswith(f"not an archself trace: {why}"), result.stderr


# --------------------------------------------------------------------------- 8. clock, shapes
def test_a_scenario_shorter_than_one_step_is_a_located_error(tmp_path: Path) -> None:
    """Was exit 0 with every metric null."""
    text = MINIMAL.replace("calm: {duration_s: 20}", "calm: {duration_s: 0.01}")
    (f,) = _error_findings(text)
    assert (f.code, f.path, f.line) == ("clock", "scenarios.calm.duration_s", 38)
    assert "shorter than one step (runtime.step_s 0.05 s)" in f.message
    (tmp_path / "short.yaml").write_text(text)
    _one_located_line(_cli(["simulate", "short.yaml", "-s", "calm"], tmp_path), "short.yaml")


def test_a_period_shorter_than_the_step_is_a_located_error() -> None:
    text = MINIMAL.replace("period_s: 1.0", "period_s: 0.01")
    (f,) = _error_findings(text)
    assert (f.code, f.path, f.line) == ("clock", "runtime.period_s", 41)
    assert "period_s 0.01 s is shorter than runtime.step_s 0.05 s" in f.message


def test_module_periods_and_rates_shorter_than_the_step_are_located_errors() -> None:
    """``Param(period=True)``: a discrete plant's sample time, a GNSS fix rate (Hz)."""
    diff = DIFFDRIVE.read_text()
    text = diff.replace("rate_hz: {value: 1.0, min: 0.1, max: 20.0, unit: Hz}",
                        "rate_hz: {value: 100.0, min: 0.1, max: 200.0, unit: Hz}")
    assert text != diff
    (f,) = _error_findings(text)
    assert f.code == "clock" and f.path.endswith(".params.rate_hz.value")
    assert "a rate of 100 Hz (one event every 0.01 s) is shorter than runtime.step_s" in f.message
    assert f.line == diff.splitlines().index(
        next(x for x in diff.splitlines() if "rate_hz:" in x)) + 1
    ok = diff.replace("rate_hz: {value: 1.0, min: 0.1, max: 20.0, unit: Hz}",
                      "rate_hz: {value: 20.0, min: 0.1, max: 20.0, unit: Hz}")
    assert _error_findings(ok) == []  # a fix every step is fine


def test_a_ragged_waypoint_is_a_located_finding_at_validate() -> None:
    """``[5]`` passed validate and failed at build without file:line."""
    text = MINIMAL.replace(WAYPOINTS, "waypoints: {value: [[0, 0], [5], [10, 0]], unit: m}")
    (f,) = _error_findings(text)
    assert (f.code, f.path, f.line) == ("build", "modules.path.params.waypoints.value", 16)
    assert f.message == ("'path' (planner.spline) cannot be built: waypoints must be a list "
                         "of at least two [x, y] points")


def test_a_state_space_c_of_the_wrong_width_is_a_located_finding() -> None:
    """A ``C`` of the wrong width in generic.state_space failed only at build."""
    data, _ = load_data(HEATED, "h.yaml")
    name, mod = next((n, m) for n, m in data["modules"].items()
                     if m["type"] == "generic.state_space")
    n_states = len(mod["params"]["A"]["value"])
    mod["params"]["C"] = {"value": [[1.0] * (n_states + 1)]}
    (f,) = _error_findings(json.dumps(data, indent=1), "h.json")
    assert f.code == "build" and f.path == f"modules.{name}.params.C.value"
    assert f.line is not None and f.line > 1
    assert f"'{name}' (generic.state_space) cannot be built" in f.message


def test_a_parameter_update_that_cannot_build_is_located_at_the_action() -> None:
    data, _ = load_data(DIFFDRIVE.read_text(), "d.yaml")
    planner = next(n for n, m in data["modules"].items() if m["type"] == "planner.spline")
    data["actions"].append({"id": "bad_path", "kind": "parameter_update", "module": planner,
                            "set": {"waypoints": [[0, 0], [5]]}, "cost": 0.1,
                            "improvement": {"method": "sensitivity", "delta_theta": -0.2}})
    findings = _error_findings(json.dumps(data, indent=1), "d.json")
    assert [(f.code, f.path) for f in findings] == [
        ("build", f"actions[{len(data['actions']) - 1}].set.waypoints")]
    assert "cannot be built after action 'bad_path'" in findings[0].message


def test_control_characters_are_located(tmp_path: Path) -> None:
    """Were 'unacceptable character #x0001' without line:col."""
    (tmp_path / "c.yaml").write_bytes(b"archself: 1\nname: ab\x01c\n")
    (tmp_path / "c.json").write_bytes(b'{"archself": 1,\n "name": "ab\x07c"}')
    line = _one_located_line(_cli(["validate", "c.yaml"], tmp_path), "c.yaml")
    assert line == ("c.yaml:2:9: error: invalid YAML: control character U+0001 (not allowed "
                    "in YAML text)")
    line = _one_located_line(_cli(["validate", "c.json"], tmp_path), "c.json")
    assert line.startswith("c.json:2:13: error: invalid YAML: control character U+0007")


def test_long_error_lines_are_cut(tmp_path: Path) -> None:
    """A 3,000-byte ``!!binary`` scalar made one 4,094-character error line."""
    import base64

    blob = base64.b64encode(bytes(range(256)) * 12).decode()
    (tmp_path / "b.yaml").write_text(f"archself: 1\nname: !!binary {blob}\n")
    line = _one_located_line(_cli(["validate", "b.yaml"], tmp_path), "b.yaml")
    assert line.startswith("b.yaml:2:7: error: unsupported YAML tag")
    assert len(line) == 300 and line.endswith("...")


# --------------------------------------------------------------------------- fuzz
CORPUS = [DIFFDRIVE, FIXTURES / "valid" / "minimal.yaml", FIXTURES / "valid" / "heated_chain.yaml",
          FIXTURES / "valid" / "actuator_swap.yaml", ROOT / "architectures" / "motor_drive.yaml",
          ROOT / "architectures" / "process_plant.yaml"]


def _junk(rng: random.Random, depth: int = 0) -> Any:
    """A junk value, as ``test_fuzz_loader.junk`` draws them (deterministic here)."""
    k = rng.randrange(9 if depth < 2 else 6)
    if k == 0:
        return None
    if k == 1:
        return rng.random() < 0.5
    if k == 2:
        return rng.randint(-10**6, 10**6)
    if k == 3:
        return rng.choice([0.0, -1.0, 1e-12, 1e308, math.inf, -math.inf, math.nan,
                           rng.uniform(-5, 5)])
    if k == 4:
        return "".join(rng.choice("ab_.: -[]{}1é") for _ in range(rng.randrange(7)))
    if k == 5:
        return rng.uniform(-100, 100)
    if k in (6, 7):
        return [_junk(rng, depth + 1) for _ in range(rng.randrange(4))]
    return {"".join(rng.choice("abc_") for _ in range(rng.randrange(1, 4))):
            _junk(rng, depth + 1) for _ in range(rng.randrange(3))}


def mutate(data: dict, rng: random.Random) -> dict:
    """1 to 3 mutations of ``test_fuzz_loader``: delete (a list entry too: ``[5]``),
    replace with junk, rename; or a number scaled (shapes kept, values moved)."""
    data = copy.deepcopy(data)
    paths = [p for p in _paths(data) if p]
    for _ in range(rng.randint(1, 3)):
        path = rng.choice(paths)
        parent: Any = data
        try:
            for p in path[:-1]:
                parent = parent[p]
            last = path[-1]
            op = rng.choice(["delete", "replace", "rename", "scale", "delete"])
            if op == "delete":
                del parent[last]
            elif op == "replace":
                parent[last] = _junk(rng)
            elif op == "scale" and isinstance(parent[last], (int, float)) and not isinstance(
                    parent[last], bool):
                parent[last] = parent[last] * rng.choice([-1, 0, 1e-6, 1e3, 1e9])
            elif isinstance(parent, dict) and last in parent:
                parent[f"{last}x"] = parent.pop(last)
        except (KeyError, IndexError, TypeError):
            continue  # an earlier mutation removed the path
    return data


def fuzz_outcome(text: str, file: str = "fuzz.json", steps: int = 3) -> str:
    """What archself does with ``text``: ``refused`` (located findings or a located
    error), ``built`` (valid; every configuration built and stepped), or a failure:
    ``unlocated`` (a message without file:line), ``build-error`` (valid, but the build
    or a step raised), ``internal`` (an exception not archself's: exit 3)."""
    from archself.system.live import compile_system

    try:
        loaded = load_text(text, file)
        findings = check(loaded)
    except ArchselfError as exc:
        ok = str(exc).startswith(f"{file}:") and "\n" not in str(exc)
        return "refused" if ok and getattr(exc, "line", None) else "unlocated"
    except Exception as exc:  # noqa: BLE001 - what the fuzz counts
        return f"internal: {type(exc).__name__}: {exc}"[:200]
    if has_errors(findings):
        located = all(f.file == file and f.line for f in findings if f.severity == "error")
        return "refused" if located else "unlocated"
    arch = loaded.arch
    scenario = next(iter(arch.scenarios), None)
    try:
        for conf in arch.configurations:
            system = compile_system(arch, conf, seed=1, scenario=scenario)
            for _ in range(steps):
                system.step()
    except Exception as exc:  # noqa: BLE001 - a valid file that does not build or step
        return f"build-error: {type(exc).__name__}: {exc}"[:200]
    return "built"


def run_fuzz(n: int, seed: int) -> Counter:
    """Outcomes of ``n`` mutated files, round-robin over :data:`CORPUS`."""
    import warnings

    bases = [load_data(p.read_text(), str(p))[0] for p in CORPUS]
    rng = random.Random(seed)
    out: Counter = Counter()
    failures = []
    for i in range(n):
        text = json.dumps(mutate(bases[i % len(bases)], rng), allow_nan=True, indent=1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a mutated value may overflow: not a failure
            outcome = fuzz_outcome(text)
        out[outcome.split(":")[0]] += 1
        if outcome not in ("refused", "built"):
            failures.append((i, CORPUS[i % len(bases)].name, outcome))
    out["failures"] = failures  # type: ignore[assignment]
    return out


def _check_fuzz(n: int, seed: int) -> None:
    counts = run_fuzz(n, seed)
    failures = counts.pop("failures")
    print(f"\nfuzz of {n} files (seed {seed}): {dict(counts)}")
    assert not failures, failures[:5]
    assert counts["refused"] + counts["built"] == n
    assert counts["built"] > n // 20, "the mutations leave some files valid"


def test_fuzz_200_mutated_files_refuse_located_or_build() -> None:
    _check_fuzz(200, seed=39)


def test_the_fuzz_finds_what_the_build_rule_catches(monkeypatch) -> None:
    """Without the ``build`` rule the same 200 files include a valid file whose build fails
    unlocated (24 of the 2,000 of the slow run: ragged waypoints, a C of the wrong width,
    a non-square A, a reference of one value): the fuzz can fail."""
    import archself.check.rules as check_module

    monkeypatch.setattr(check_module, "check_build", lambda ctx: None)
    counts = run_fuzz(200, seed=39)
    assert counts["build-error"] >= 1
    assert all(o.startswith("build-error: CompileError") for _, _, o in counts["failures"])


@pytest.mark.slow
def test_fuzz_2000_mutated_files_refuse_located_or_build() -> None:
    """The issue's 'Done when': 0 crashes, 0 exit 3, 0 build errors without location."""
    _check_fuzz(2000, seed=2039)
