"""Exports of an architecture to other tools' formats (``archself export``).

==============  ============================================================
format          what it holds
==============  ============================================================
``graphml``     the module graph: nodes with kind, type, description and one
                boolean ``in_<configuration>`` per configuration; edges with
                weight (W_ji), carries, latency and uncertainty (networkx
                ``write_graphml``; opens in yEd, Gephi, Cytoscape)
``node-link``   the same graph as node-link JSON (``networkx.node_link_data``;
                d3.js and networkx read it)
``edges-csv``   one row per edge: source, target, weight, carries, latency_s,
                uncertainty, and the configurations in which it is active
``ros2-modes``  a ROS 2 ``system_modes`` mode file (SMH): see :func:`ros2_modes`
==============  ============================================================

Examples
--------
>>> from archself.model.loader import load_architecture
>>> from archself.resources import data_dir
>>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
>>> g = architecture_graph(arch)
>>> g.nodes["ekf"]["in_a2"], g.nodes["ekf"]["in_a1"]
(True, False)
>>> g.edges["imu", "odometry"]["weight"]
0.6
"""

from __future__ import annotations

import csv
import io
import json
from typing import Any

from archself.check.graph import active_edges
from archself.model.architecture import Architecture

__all__ = ["FORMATS", "architecture_graph", "edges_csv", "export", "ros2_modes"]

FORMATS = ("graphml", "node-link", "edges-csv", "ros2-modes")

DEFAULT_MODE = "__DEFAULT__"  #: the system_modes name of a part's default mode


def _active_in(arch: Architecture) -> list[str]:
    """Per edge, the configurations it is active in (space-separated names)."""
    active = {c: {i for i, _ in active_edges(arch, c)} for c in arch.configurations}
    return [" ".join(c for c in arch.configurations if i in active[c])
            for i in range(len(arch.edges))]


def architecture_graph(arch: Architecture) -> Any:
    """The module graph as a ``networkx.DiGraph`` whose attributes GraphML can store.

    Graph attributes: ``name``, ``initial`` (configuration). Node attributes:
    ``kind``, ``type``, ``description``, ``in_<c>`` for every configuration ``c``.
    Edge attributes: ``weight``, ``carries``, ``latency_s``, ``uncertainty``,
    ``active_in`` (space-separated configuration names).
    """
    import networkx as nx

    g = nx.DiGraph(name=arch.name, initial=arch.initial_configuration())
    members = {c: set(conf.modules) for c, conf in arch.configurations.items()}
    for name, mod in arch.modules.items():
        g.add_node(name, kind=mod.kind, type=mod.type, description=mod.description or "",
                   **{f"in_{c}": name in mods for c, mods in members.items()})
    for e, active_in in zip(arch.edges, _active_in(arch), strict=True):
        g.add_edge(e.source, e.target, weight=float(e.weight), carries=e.carries,
                   latency_s=float(e.latency_s), uncertainty=float(e.uncertainty),
                   active_in=active_in)
    return g


def edges_csv(arch: Architecture) -> str:
    """One CSV row per edge (RFC 4180, header first).

    Examples
    --------
    >>> from archself.model.loader import load_architecture
    >>> from archself.resources import data_dir
    >>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
    >>> for line in edges_csv(arch).splitlines()[:2]:
    ...     print(line)
    source,target,weight,carries,latency_s,uncertainty,active_in
    lqr,wheel_left,0.3,wheel_cmd,0.0,0.0,a1
    """
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["source", "target", "weight", "carries", "latency_s", "uncertainty", "active_in"])
    for e, active_in in zip(arch.edges, _active_in(arch), strict=True):
        w.writerow([e.source, e.target, e.weight, e.carries, e.latency_s, e.uncertainty,
                    active_in])
    return out.getvalue()


def _ros_value(v: Any) -> Any:
    """A parameter value ROS 2 can hold (bool, int, float, str or a flat list of one of them)."""
    if isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, (list, tuple)) and all(isinstance(x, (bool, int, float, str)) for x in v):
        return list(v)
    return json.dumps(v)  # nested lists (waypoints): a string the node parses


def _mode_name(name: str) -> str:
    return name.upper().replace("-", "_").replace(".", "_").replace(" ", "_")


def ros2_modes(arch: Architecture) -> dict[str, Any]:
    """The architecture as a ROS 2 ``system_modes`` mode file (as data; dump it as YAML).

    The mapping (docs/export.md):

    - the architecture is one **system** named after the file's ``name``; its
      ``parts`` are the modules (one node each, named as in the file);
    - every **configuration** is a system mode (its name upper-cased; the initial
      configuration is also ``__DEFAULT__``) in which the configuration's modules
      are ``active`` and the others ``inactive``;
    - every module is a **node** whose ``__DEFAULT__`` mode holds the file's
      nominal parameter values as ``ros__parameters``; every ``parameter_update``
      action adds a node mode named after the action id with the values it sets,
      and the system modes use it where the action applies (nowhere by default:
      it is the MAPE-K loop that chooses it, as the mode manager's client).

    Examples
    --------
    >>> from archself.model.loader import load_architecture
    >>> from archself.resources import data_dir
    >>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
    >>> m = ros2_modes(arch)
    >>> m["diffdrive"]["ros__parameters"]["modes"]["A2"]["ekf"]
    'active'
    >>> m["lqr"]["ros__parameters"]["modes"]["STIFFEN_LATERAL_GAIN"]["ros__parameters"]
    {'q_lateral': 0.01}
    """
    system = _mode_name(arch.name).lower()
    first = arch.initial_configuration()
    modes: dict[str, dict[str, str]] = {}
    for c, conf in [(DEFAULT_MODE, arch.configurations[first]), *arch.configurations.items()]:
        on = set(conf.modules)
        modes[c if c == DEFAULT_MODE else _mode_name(c)] = {
            m: "active" if m in on else "inactive" for m in arch.modules}
    doc: dict[str, Any] = {system: {"ros__parameters": {
        "type": "system",
        "parts": " ".join(arch.modules),
        "modes": modes,
    }}}
    updates: dict[str, dict[str, dict[str, Any]]] = {}
    for a in arch.actions:
        if a.kind == "parameter_update" and a.set:
            updates.setdefault(a.module, {})[_mode_name(a.id)] = {
                "ros__parameters": {k: _ros_value(v) for k, v in a.set.items()}}
    for name, mod in arch.modules.items():
        nominal = {k: _ros_value(p.value) for k, p in mod.params.items()}
        node_modes: dict[str, Any] = {DEFAULT_MODE: {"ros__parameters": nominal}}
        node_modes.update(updates.get(name, {}))
        doc[name] = {"ros__parameters": {"type": "node", "modes": node_modes}}
    return doc


def export(arch: Architecture, fmt: str) -> str:
    """The text of ``arch`` in format ``fmt`` (one of :data:`FORMATS`).

    Raises
    ------
    ValueError
        For an unknown format.
    """
    if fmt == "graphml":
        import networkx as nx

        return "\n".join(nx.generate_graphml(architecture_graph(arch), prettyprint=True)) + "\n"
    if fmt == "node-link":
        import networkx as nx

        data = nx.node_link_data(architecture_graph(arch), edges="links")
        return json.dumps(data, indent=2, ensure_ascii=False) + "\n"
    if fmt == "edges-csv":
        return edges_csv(arch)
    if fmt == "ros2-modes":
        from ruamel.yaml import YAML

        yaml = YAML()
        yaml.default_flow_style = False
        yaml.width = 4096  # one line per list of parts
        out = io.StringIO()
        out.write(f"# ROS 2 system_modes mode file exported by archself from '{arch.name}'\n---\n")
        yaml.dump(ros2_modes(arch), out)
        return out.getvalue()
    raise ValueError(f"unknown export format {fmt!r}; choose one of {', '.join(FORMATS)}")
