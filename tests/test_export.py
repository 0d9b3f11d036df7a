"""``archself export``: other tools read what it writes."""

from __future__ import annotations

import csv
import io
import json

import networkx as nx
import numpy as np
import pytest
from ruamel.yaml import YAML
from typer.testing import CliRunner

from archself.cli import app
from archself.model.loader import load_architecture
from archself.reports.export import FORMATS, export, ros2_modes
from archself.resources import data_dir
from archself.runtime.influence import weight_matrix

ARCHS = sorted(data_dir("architectures").glob("*.yaml"))


@pytest.fixture(scope="module", params=ARCHS, ids=lambda p: p.stem)
def arch(request):
    return load_architecture(request.param).arch


def test_graphml_loads_in_networkx_with_the_same_graph(arch, tmp_path) -> None:
    path = tmp_path / "g.graphml"
    path.write_text(export(arch, "graphml"), encoding="utf-8")
    g = nx.read_graphml(path)
    assert sorted(g.nodes) == sorted(arch.modules)
    assert g.number_of_edges() == len(arch.edges)
    for e in arch.edges:
        assert g.edges[e.source, e.target]["weight"] == pytest.approx(e.weight)
        assert g.edges[e.source, e.target]["carries"] == e.carries
    first = arch.initial_configuration()
    for m in arch.modules:
        assert g.nodes[m][f"in_{first}"] == (m in arch.configurations[first].modules)
    # W rebuilt from the export is the runtime's W
    names = list(arch.modules)
    w = nx.to_numpy_array(g, nodelist=names, weight="weight")
    declared = weight_matrix(names, [(e.source, e.target, e.weight) for e in arch.edges])
    np.testing.assert_allclose(w, declared.toarray())


def test_node_link_round_trips(arch) -> None:
    g = nx.node_link_graph(json.loads(export(arch, "node-link")), edges="links")
    assert sorted(g.nodes) == sorted(arch.modules)
    assert {(e.source, e.target) for e in arch.edges} == set(g.edges)


def test_edges_csv_has_a_row_per_edge(arch) -> None:
    rows = list(csv.DictReader(io.StringIO(export(arch, "edges-csv"))))
    assert len(rows) == len(arch.edges)
    for row, e in zip(rows, arch.edges, strict=True):
        assert (row["source"], row["target"], float(row["weight"])) == (e.source, e.target,
                                                                      e.weight)
        for c in row["active_in"].split():
            assert {e.source, e.target} <= set(arch.configurations[c].modules)


def _check_system_modes_structure(doc: dict, arch) -> dict:
    """The keys and value forms of system_modes' example_modes.yaml (micro-ROS/system_modes):
    a system with ``parts`` (whitespace-separated), ``modes`` mapping each part to
    ``inactive`` or ``active.<one of the part's node modes>``, ``rules`` with
    ``if_target``/``if_part``/``new_target``; nodes with ``modes.*.ros__parameters``."""
    system = doc[arch.name.lower()]["ros__parameters"]
    assert system["type"] == "system"
    assert set(system) <= {"type", "parts", "modes", "rules"}
    parts = system["parts"].split()
    assert set(doc) == {arch.name.lower(), *parts}
    for name, modes in system["modes"].items():
        assert set(modes) == set(parts), name
        for part, state in modes.items():
            if state != "inactive":
                kind, mode = state.split(".", 1)
                assert kind == "active"
                assert mode in doc[part]["ros__parameters"]["modes"], (name, part, mode)
    for rule in (system.get("rules") or {}).values():
        assert set(rule) == {"if_target", "if_part", "new_target"}
        for target in (rule["if_target"], rule["new_target"]):
            assert target.startswith("active.") and target[7:] in system["modes"]
        assert rule["if_part"][0] in parts and rule["if_part"][1] == "inactive"
    for part in parts:
        node = doc[part]["ros__parameters"]
        assert node["type"] == "node"
        assert all(set(m) == {"ros__parameters"} for m in node["modes"].values())
    return system


def test_ros2_modes_file_has_the_system_modes_structure(arch) -> None:
    doc = YAML(typ="safe").load(export(arch, "ros2-modes"))
    assert doc == json.loads(json.dumps(ros2_modes(arch)))
    system = _check_system_modes_structure(doc, arch)
    parts = system["parts"].split()
    assert parts == [m for m, mod in arch.modules.items() if mod.kind == "functional"]
    modes = system["modes"]
    assert set(modes) == {"__DEFAULT__", *(c.upper() for c in arch.configurations)}
    first = arch.initial_configuration()
    assert modes["__DEFAULT__"] == modes[first.upper()]
    for c, conf in arch.configurations.items():
        on = {m for m, state in modes[c.upper()].items() if state != "inactive"}
        assert on == set(conf.modules) & set(parts)
    for m in parts:
        node = doc[m]["ros__parameters"]
        assert set(arch.modules[m].params) <= set(node["modes"]["__DEFAULT__"]["ros__parameters"])
    for a in arch.actions:
        if a.kind == "parameter_update" and a.module in parts:
            mode = doc[a.module]["ros__parameters"]["modes"][a.id.upper()]
            assert mode["ros__parameters"] == dict(a.set)


def test_ros2_modes_of_diffdrive_parts_rules_and_rewiring() -> None:
    """Only nodes are parts; the declared degradations are rules; a configuration that
    differs from another only in its wiring is a distinct system mode."""
    from archself.model.loader import load_text

    src = data_dir("architectures") / "diffdrive.yaml"
    arch = load_architecture(src).arch
    doc = ros2_modes(arch)
    system = doc["diffdrive"]["ros__parameters"]
    assert system["parts"].split() == ["planner", "odometry", "ekf", "lqr", "lqr_fused",
                                       "asym_lqr"]
    assert "chassis" not in doc and "kinematic_model" not in doc
    assert system["rules"] == {
        "degrade_A1_odometry": {"if_target": "active.A1", "if_part": ["odometry", "inactive"],
                                "new_target": "active.A2"},
        "degrade_A4_odometry": {"if_target": "active.A4", "if_part": ["odometry", "inactive"],
                                "new_target": "active.A3"},
    }
    text = export(arch, "ros2-modes")
    assert "fallback_odometry (gps is not a node)" in text.split("---")[0]
    # asym_lqr reads the EKF in a3 and dead reckoning in a4: a node mode for a4
    assert system["modes"]["A4"]["asym_lqr"] == "active.A4"
    a4 = doc["asym_lqr"]["ros__parameters"]["modes"]["A4"]["ros__parameters"]
    assert "odometry.pose_estimate" in a4["archself_inputs"]
    assert "ekf.pose_estimate" not in a4["archself_inputs"]
    # a configuration a1 without the GPS → odometry edge: same modules, other wiring
    rewired = src.read_text(encoding="utf-8").replace(
        "configurations:\n",
        "configurations:\n  a5:\n    modules: [chassis, wheel_left, wheel_right, encoders, imu, "
        "gps, planner, odometry, lqr, kinematic_model, dynamic_model, actuator_model]\n"
        "    disabled_edges: [[gps, odometry]]\n", 1)
    arch5 = load_text(rewired, "rewired.yaml").arch
    doc5 = ros2_modes(arch5)
    modes5 = doc5["diffdrive"]["ros__parameters"]["modes"]
    assert modes5["A5"] != modes5["A1"]
    assert modes5["A5"]["odometry"] == "active.A5"
    _check_system_modes_structure(YAML(typ="safe").load(export(arch5, "ros2-modes")), arch5)
    # an explicit node list: any kind may be a node
    doc_n = ros2_modes(arch, ["chassis", "ekf"])
    assert doc_n["diffdrive"]["ros__parameters"]["parts"] == "chassis ekf"


@pytest.mark.parametrize("fmt", FORMATS)
def test_cli_export_writes_each_format(fmt, tmp_path) -> None:
    src = data_dir("architectures") / "process_plant.yaml"
    out = tmp_path / f"out.{fmt}"
    res = CliRunner().invoke(app, ["export", str(src), "--to", fmt, "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert out.read_text(encoding="utf-8") == export(load_architecture(src).arch, fmt)
    res = CliRunner().invoke(app, ["export", str(src), "--to", fmt])
    assert res.exit_code == 0 and res.stdout == out.read_text(encoding="utf-8")


def test_cli_export_rejects_an_unknown_format() -> None:
    src = data_dir("architectures") / "process_plant.yaml"
    res = CliRunner().invoke(app, ["export", str(src), "--to", "dot"])
    assert res.exit_code == 2


def test_info_lists_what_the_file_holds() -> None:
    src = data_dir("architectures") / "diffdrive.yaml"
    res = CliRunner().invoke(app, ["info", str(src), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    arch = load_architecture(src).arch
    assert [m["name"] for m in data["modules"]] == list(arch.modules)
    assert [c["name"] for c in data["configurations"] if c["initial"]] == ["a1"]
    assert {a["id"] for a in data["actions"]} == {a.id for a in arch.actions}
    text = CliRunner().invoke(app, ["info", str(src)]).stdout
    assert "use_ekf_gps: substitute on odometry → a2 (cost 0.2)" in text
