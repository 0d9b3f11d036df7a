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

from archself.check.rules import active_edges
from archself.errors import ArchselfError
from archself.model.architecture import Architecture

__all__ = ["FORMATS", "architecture_graph", "edges_csv", "export", "node_modules", "ros2_modes",
           "ros2_rules"]

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


def node_modules(arch: Architecture, nodes: list[str] | None = None) -> list[str]:
    """The modules that run as ROS 2 nodes (the parts of the exported system).

    Parameters
    ----------
    arch : Architecture
    nodes : list of str, optional
        The modules to take (any kind); default: the ``functional`` modules, since
        a ``physical`` module is the plant (its sensors and actuators are topics of
        the robot's drivers, not lifecycle nodes) and a ``model`` module lives inside
        the loop's linearization, not on the robot.

    Returns
    -------
    list of str
        In file order.

    Raises
    ------
    ArchselfError
        A name that is not a module of the file (one line, with the known ones).

    Examples
    --------
    >>> from archself.model.loader import load_architecture
    >>> from archself.resources import data_dir
    >>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
    >>> node_modules(arch)
    ['planner', 'odometry', 'ekf', 'lqr', 'lqr_fused', 'asym_lqr']
    """
    if nodes is None:
        return [m for m, mod in arch.modules.items() if mod.kind == "functional"]
    unknown = [n for n in nodes if n not in arch.modules]
    if unknown:
        raise ArchselfError(f"{arch.name}: nodes: {unknown[0]!r} is not a module; "
                            f"modules: {', '.join(arch.modules)}")
    return [m for m in arch.modules if m in set(nodes)]


def _inputs_of(arch: Architecture, nodes: list[str]) -> dict[str, dict[str, tuple[str, ...]]]:
    """configuration → node → its active input edges as ``source.carries`` (sorted)."""
    out: dict[str, dict[str, tuple[str, ...]]] = {}
    for c in arch.configurations:
        ins: dict[str, list[str]] = {n: [] for n in nodes}
        for _, e in active_edges(arch, c):
            if e.target in ins:
                ins[e.target].append(f"{e.source}.{e.carries}")
        out[c] = {n: tuple(sorted(v)) for n, v in ins.items()}
    return out


def _inside(arch: Architecture, parts: list[str], flat: bool) -> dict[str, list[str]]:
    """subsystem → its parts (file order), for the subsystems holding a part (none if flat)."""
    if flat:
        return {}
    out: dict[str, list[str]] = {}
    for s, sub in arch.subsystems.items():
        mods = {m for ms in sub.modes.values() for m in ms}
        held = [p for p in parts if p in mods]
        if held:
            out[s] = held
    return out


def ros2_rules(
    arch: Architecture, nodes: list[str], *, flat: bool = False
) -> tuple[dict[str, Any], list[str]]:
    """system_modes ``rules`` for the degradations the file declares, and what cannot be one.

    A structural action keyed to a node module ``m`` that applies in configuration
    ``c`` and leads to ``c'`` becomes the rule "in system mode ``C``, if part ``m``
    is inactive, go to ``C'``" (``degrade_<C>_<m>``). An action keyed to a module
    that is not a node (a sensor, a wheel) has no part whose state a mode manager
    could watch: it is returned as one line instead (the MAPE-K loop still takes it);
    so is one keyed to a node inside a subsystem (unless ``flat``), since a rule of the
    system watches its direct parts.
    """
    rules: dict[str, Any] = {}
    not_rules: list[str] = []
    owner = {p: s for s, held in _inside(arch, nodes, flat).items() for p in held}
    for a in arch.actions:
        if a.kind == "parameter_update" or a.to is None:
            continue
        if a.module not in nodes or a.module in owner:
            why = (f"{a.module} is in subsystem {owner[a.module]}" if a.module in owner
                   else f"{a.module} is not a node")
            not_rules.append(f"{a.id} ({why})")
            continue
        for c, conf in arch.configurations.items():
            if c == a.to or a.module not in conf.modules or (a.applies_in
                                                            and c not in a.applies_in):
                continue
            rules[f"degrade_{_mode_name(c)}_{a.module}"] = {
                "if_target": f"active.{_mode_name(c)}",
                "if_part": [a.module, "inactive"],
                "new_target": f"active.{_mode_name(a.to)}",
            }
    return rules, not_rules


def _wiring(
    arch: Architecture, parts: list[str]
) -> tuple[dict[str, dict[str, str]], dict[str, dict[str, Any]]]:
    """Node modes of the parts wired differently in a configuration than in the initial one.

    Returns node → configuration → its node mode, and node → node mode → its
    ``ros__parameters`` (``archself_inputs``; under ``__DEFAULT__`` the reference inputs).
    """
    first = arch.initial_configuration()
    inputs = _inputs_of(arch, parts)
    wiring: dict[str, dict[str, str]] = {}
    wired_modes: dict[str, dict[str, Any]] = {}
    for p in parts:
        held = [c for c, conf in arch.configurations.items() if p in conf.modules]
        base = first if first in held else (held[0] if held else None)
        ref = inputs[base][p] if base else ()
        for c in held:
            if inputs[c][p] != ref:
                wiring.setdefault(p, {})[c] = _mode_name(c)
                wired_modes.setdefault(p, {})[_mode_name(c)] = {
                    "ros__parameters": {"archself_inputs": list(inputs[c][p])}}
        if p in wired_modes:
            wired_modes[p][DEFAULT_MODE] = list(ref)
    return wiring, wired_modes


def _subsystem_modes(
    arch: Architecture, inside: dict[str, list[str]]
) -> tuple[dict[str, dict[str, str | None]], dict[str, dict[str, list[str]]]]:
    """Each configuration's mode of each subsystem, and each subsystem's modes (its parts).

    A composed configuration names its modes; a flat one takes the mode whose parts are
    the ones it runs, else a mode named after it; a subsystem none of whose parts run
    is off (None).
    """
    modes = {s: {_mode_name(m): [p for p in held if p in arch.subsystems[s].modes[m]]
                 for m in arch.subsystems[s].modes} for s, held in inside.items()}
    chosen: dict[str, dict[str, str | None]] = {}
    for c, conf in arch.configurations.items():
        on = set(conf.modules)
        pick: dict[str, str | None] = {}
        for s, held in inside.items():
            running = [p for p in held if p in on]
            declared = (conf.modes or {}).get(s)
            if declared is not None and declared in arch.subsystems[s].modes:
                pick[s] = _mode_name(declared)
                continue
            name = next((k for k, v in modes[s].items() if v == running), None)
            if name is None and running:
                name = _mode_name(c)
                modes[s][name] = running
            pick[s] = name if running else None
        chosen[c] = pick
    return chosen, modes


def ros2_modes(
    arch: Architecture, nodes: list[str] | None = None, *, flat: bool = False
) -> dict[str, Any]:
    """The architecture as a ROS 2 ``system_modes`` mode file (as data; dump it as YAML).

    The mapping (docs/export.md):

    - the architecture is one **system** named after the file's ``name``; its
      ``parts`` are the modules that run as nodes (:func:`node_modules`: the
      functional ones by default), one lifecycle node each, named as in the file —
      except those inside a **subsystem** (``subsystems`` of the file, unless
      ``flat``): a subsystem holding nodes is a part of type ``system`` whose parts
      are its nodes and whose modes are its modes (``__DEFAULT__``: its mode in the
      initial configuration);
    - every **configuration** is a system mode (its name upper-cased; the initial
      configuration is also ``__DEFAULT__``) in which each node part is
      ``active.<node mode>`` when the configuration holds it, else ``inactive``, and
      each subsystem ``active.<its mode>`` (:func:`_subsystem_modes`) or ``inactive``;
    - every part is a **node** whose ``__DEFAULT__`` mode holds the file's nominal
      parameter values as ``ros__parameters``; every ``parameter_update`` action
      adds a node mode named after the action id with the values it sets (the
      MAPE-K loop chooses it, as the mode manager's client); a node part whose active
      inputs differ between configurations (another source, a ``rewire`` or a
      configuration's ``disabled_edges``) gets a node mode per configuration that
      wires it differently from the initial one (or the first holding it), with its inputs as the
      parameter ``archself_inputs``, so that rewired configurations stay distinct
      system modes (a node inside a subsystem reads what the other modes run);
    - ``rules``: the degradations the file declares (:func:`ros2_rules`).

    Examples
    --------
    >>> from archself.model.loader import load_architecture
    >>> from archself.resources import data_dir
    >>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
    >>> m = ros2_modes(arch)
    >>> a2 = m["diffdrive"]["ros__parameters"]["modes"]["A2"]
    >>> a2["planner"], a2["localization"], a2["control"]
    ('active.__DEFAULT__', 'active.FUSED', 'active.SYMMETRIC_FUSED')
    >>> m["localization"]["ros__parameters"]["modes"]["FUSED"]
    {'odometry': 'inactive', 'ekf': 'active.__DEFAULT__'}
    >>> ros2_modes(arch, flat=True)["diffdrive"]["ros__parameters"]["modes"]["A2"]["ekf"]
    'active.__DEFAULT__'
    >>> m["lqr"]["ros__parameters"]["modes"]["STIFFEN_LATERAL_GAIN"]["ros__parameters"]
    {'q_lateral': 0.01}
    """
    parts = node_modules(arch, nodes)
    first = arch.initial_configuration()
    inside = _inside(arch, parts, flat)
    free = [p for p in parts if not any(p in held for held in inside.values())]
    wiring, wired_modes = _wiring(arch, free)
    chosen, sub_modes = _subsystem_modes(arch, inside)
    modes: dict[str, dict[str, str]] = {}
    for c, conf in [(DEFAULT_MODE, first), *((c, c) for c in arch.configurations)]:
        on = set(arch.configurations[conf].modules)
        row = {p: f"active.{wiring.get(p, {}).get(conf, DEFAULT_MODE)}" if p in on else "inactive"
               for p in free}
        row.update({s: f"active.{m}" if (m := chosen[conf][s]) else "inactive" for s in inside})
        modes[c if c == DEFAULT_MODE else _mode_name(c)] = row
    rules, _ = ros2_rules(arch, parts, flat=flat)
    body: dict[str, Any] = {"type": "system", "parts": " ".join([*free, *inside]), "modes": modes}
    if rules:
        body["rules"] = rules
    doc: dict[str, Any] = {_mode_name(arch.name).lower(): {"ros__parameters": body}}
    for s, held in inside.items():
        own = {m: {p: "active.__DEFAULT__" if p in run else "inactive" for p in held}
               for m, run in sub_modes[s].items()}
        default = dict(own[chosen[first][s] or next(iter(own))])
        doc[s] = {"ros__parameters": {"type": "system", "parts": " ".join(held),
                                      "modes": {DEFAULT_MODE: default, **own}}}
    doc.update(_node_entries(arch, parts, wired_modes))
    return doc


def _node_entries(
    arch: Architecture, parts: list[str], wired_modes: dict[str, dict[str, Any]]
) -> dict[str, Any]:
    """Each node: ``__DEFAULT__`` (nominal values), a mode per parameter update, its wiring."""
    updates: dict[str, dict[str, dict[str, Any]]] = {}
    for a in arch.actions:
        if a.kind == "parameter_update" and a.set and a.module in parts:
            updates.setdefault(a.module, {})[_mode_name(a.id)] = {
                "ros__parameters": {k: _ros_value(v) for k, v in a.set.items()}}
    doc: dict[str, Any] = {}
    for name in parts:
        nominal = {k: _ros_value(p.value) for k, p in arch.modules[name].params.items()}
        extra = dict(wired_modes.get(name, {}))
        if DEFAULT_MODE in extra:
            nominal["archself_inputs"] = extra.pop(DEFAULT_MODE)
        node_modes: dict[str, Any] = {DEFAULT_MODE: {"ros__parameters": nominal}}
        node_modes.update(updates.get(name, {}))
        node_modes.update(extra)
        doc[name] = {"ros__parameters": {"type": "node", "modes": node_modes}}
    return doc


def export(
    arch: Architecture, fmt: str, *, nodes: list[str] | None = None, flat: bool = False
) -> str:
    """The text of ``arch`` in format ``fmt`` (one of :data:`FORMATS`).

    ``nodes``: for ``ros2-modes``, the modules that run as nodes (:func:`node_modules`);
    ``flat``: for ``ros2-modes``, no subsystems (every node a part of the system).

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
        parts = node_modules(arch, nodes)
        out.write(f"# ROS 2 system_modes mode file exported by archself from '{arch.name}'\n")
        out.write(f"# parts (nodes): {' '.join(parts)}\n")
        inside = _inside(arch, parts, flat)
        if inside:
            out.write("# subsystems (parts with their own modes): " + ", ".join(
                f"{s} ({' '.join(held)})" for s, held in inside.items()) + "\n")
        _, not_rules = ros2_rules(arch, parts, flat=flat)
        if not_rules:
            out.write("# not rules (a mode manager cannot watch their module; the MAPE-K loop "
                      f"takes them): {', '.join(not_rules)}\n")
        out.write("---\n")
        yaml.dump(ros2_modes(arch, parts, flat=flat), out)
        return out.getvalue()
    raise ValueError(f"unknown export format {fmt!r}; choose one of {', '.join(FORMATS)}")
