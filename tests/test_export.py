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


def _check_system(doc: dict, name: str) -> set[str]:
    """The keys and value forms of system_modes' example_modes.yaml (micro-ROS/system_modes)
    for system ``name`` and, recursively, its sub-systems: ``parts`` (whitespace-separated),
    ``modes`` mapping each part to ``inactive`` or ``active.<one of the part's modes>``,
    ``rules`` with ``if_target``/``if_part``/``new_target``; nodes with
    ``modes.*.ros__parameters``. Returns the names of the system and everything below it."""
    system = doc[name]["ros__parameters"]
    assert system["type"] == "system"
    assert set(system) <= {"type", "parts", "modes", "rules"}
    parts = system["parts"].split()
    assert "__DEFAULT__" in system["modes"]
    for mname, modes in system["modes"].items():
        assert set(modes) == set(parts), mname
        for part, state in modes.items():
            if state != "inactive":
                kind, mode = state.split(".", 1)
                assert kind == "active"
                assert mode in doc[part]["ros__parameters"]["modes"], (mname, part, mode)
    for rule in (system.get("rules") or {}).values():
        assert set(rule) == {"if_target", "if_part", "new_target"}
        for target in (rule["if_target"], rule["new_target"]):
            assert target.startswith("active.") and target[7:] in system["modes"]
        assert rule["if_part"][0] in parts and rule["if_part"][1] == "inactive"
    reached = {name}
    for part in parts:
        entry = doc[part]["ros__parameters"]
        if entry["type"] == "system":
            reached |= _check_system(doc, part)
            continue
        assert entry["type"] == "node"
        assert all(set(m) == {"ros__parameters"} for m in entry["modes"].values())
        reached.add(part)
    return reached


def _check_system_modes_structure(doc: dict, arch) -> dict:
    assert set(doc) == _check_system(doc, arch.name.lower())
    return doc[arch.name.lower()]["ros__parameters"]


def _active_nodes(doc: dict, system: str, mode: str) -> set[str]:
    """The nodes a system mode runs, through its sub-systems' modes."""
    out = set()
    for part, state in doc[system]["ros__parameters"]["modes"][mode].items():
        if state == "inactive":
            continue
        if doc[part]["ros__parameters"]["type"] == "system":
            out |= _active_nodes(doc, part, state.split(".", 1)[1])
        else:
            out.add(part)
    return out


def _nodes(doc: dict, system: str) -> list[str]:
    """The node parts of a system, through its sub-systems, in order."""
    out = []
    for part in doc[system]["ros__parameters"]["parts"].split():
        sub = doc[part]["ros__parameters"]["type"] == "system"
        out += _nodes(doc, part) if sub else [part]
    return out


@pytest.mark.parametrize("flat", [False, True])
def test_ros2_modes_file_has_the_system_modes_structure(arch, flat) -> None:
    doc = YAML(typ="safe").load(export(arch, "ros2-modes", flat=flat))
    assert doc == json.loads(json.dumps(ros2_modes(arch, flat=flat)))
    system = _check_system_modes_structure(doc, arch)
    name = arch.name.lower()
    assert sorted(_nodes(doc, name)) == sorted(
        m for m, mod in arch.modules.items() if mod.kind == "functional")
    modes = system["modes"]
    assert set(modes) == {"__DEFAULT__", *(c.upper() for c in arch.configurations)}
    first = arch.initial_configuration()
    assert modes["__DEFAULT__"] == modes[first.upper()]
    for c, conf in arch.configurations.items():
        assert _active_nodes(doc, name, c.upper()) == set(conf.modules) & set(_nodes(doc, name))
    for m in _nodes(doc, name):
        node = doc[m]["ros__parameters"]
        assert set(arch.modules[m].params) <= set(node["modes"]["__DEFAULT__"]["ros__parameters"])
    for a in arch.actions:
        if a.kind == "parameter_update" and a.module in doc:
            mode = doc[a.module]["ros__parameters"]["modes"][a.id.upper()]
            assert mode["ros__parameters"] == dict(a.set)


def test_ros2_modes_of_diffdrive_parts_rules_and_rewiring() -> None:
    """Flat: only nodes are parts; the declared degradations are rules; a configuration
    that differs from another only in its wiring is a distinct system mode."""
    from archself.model.loader import load_text

    src = data_dir("architectures") / "diffdrive.yaml"
    arch = load_architecture(src).arch
    doc = ros2_modes(arch, flat=True)
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
    text = export(arch, "ros2-modes", flat=True)
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
    doc5 = ros2_modes(arch5, flat=True)
    modes5 = doc5["diffdrive"]["ros__parameters"]["modes"]
    assert modes5["A5"] != modes5["A1"]
    assert modes5["A5"]["odometry"] == "active.A5"
    _check_system_modes_structure(YAML(typ="safe").load(export(arch5, "ros2-modes",
                                                               flat=True)), arch5)
    # hierarchical, the flat a5 takes the subsystem modes its modules match
    hier5 = ros2_modes(arch5)["diffdrive"]["ros__parameters"]["modes"]["A5"]
    assert (hier5["localization"], hier5["control"]) == ("active.DEAD_RECKONING",
                                                         "active.SYMMETRIC")
    # an explicit node list: any kind may be a node
    doc_n = ros2_modes(arch, ["chassis", "ekf"])
    assert doc_n["diffdrive"]["ros__parameters"]["parts"] == "chassis localization"
    assert ros2_modes(arch, ["chassis", "ekf"], flat=True)["diffdrive"]["ros__parameters"][
        "parts"] == "chassis ekf"


def test_hierarchical_modes_round_trip_through_ros2_modes(tmp_path) -> None:
    """Subsystems are parts of type system with their own modes; reading the export back
    gives the file's subsystems and each configuration's modes, and a file rebuilt from
    them expands to the same configurations."""
    from archself.model.loader import load_text

    src = data_dir("architectures") / "diffdrive.yaml"
    arch = load_architecture(src).arch
    out = tmp_path / "modes.yaml"
    res = CliRunner().invoke(app, ["export", str(src), "--to", "ros2-modes", "-o", str(out)])
    assert res.exit_code == 0, res.output
    doc = YAML(typ="safe").load(out.read_text(encoding="utf-8"))
    top = doc["diffdrive"]["ros__parameters"]
    assert top["parts"].split() == ["planner", "localization", "control"]
    assert "rules" not in top  # odometry's degradations: inside a subsystem (header)
    assert "use_ekf_gps (odometry is in subsystem localization)" in out.read_text()
    # read back: subsystems (mode → the nodes it runs) and each configuration's modes
    subsystems = {
        s: {m.lower(): [p for p, st in row.items() if st != "inactive"]
            for m, row in doc[s]["ros__parameters"]["modes"].items() if m != "__DEFAULT__"}
        for s in top["parts"].split() if doc[s]["ros__parameters"]["type"] == "system"}
    assert subsystems == {s: sub.modes for s, sub in arch.subsystems.items()}
    picked = {c.lower(): {s: row[s].split(".", 1)[1].lower() for s in subsystems}
              for c, row in top["modes"].items() if c != "__DEFAULT__"}
    assert picked == {c: conf.modes for c, conf in arch.configurations.items()}
    assert top["modes"]["__DEFAULT__"] == top["modes"]["A1"]
    # a file rebuilt from what was read back expands to the same flat configurations
    text = src.read_text(encoding="utf-8")
    head, rest = text.split("subsystems:\n", 1)
    tail = rest[rest.index("actions:\n"):]
    platform = [m for m in arch.configurations["a1"].modules
                if not any(m in ms for sub in arch.subsystems.values()
                           for ms in sub.modes.values())]
    confs = {c: {"modes": ms, "modules": platform, **({"initial": True} if c == "a1" else {})}
             for c, ms in picked.items()}
    block = (f"subsystems: {json.dumps({s: {'modes': m} for s, m in subsystems.items()})}\n"
             f"configurations: {json.dumps(confs)}\n\n")
    again = load_text(head + block + tail, "rebuilt.yaml").arch
    assert {c: conf.modules for c, conf in again.configurations.items()} == {
        c: conf.modules for c, conf in arch.configurations.items()}


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
