"""Named ports: what a module type takes and gives, and edges that name them.

A module type declares its ports once, next to its parameters::

    ports = (
        Input("q_in", "W", "heat delivered by the heaters", multi=True),
        Input("setpoint", "K", required=False),
        Output("temperature", "K", "air temperature of the zone"),
    )

(a sequence, not a mapping: a plant may take ``u`` and publish the ``u`` it applied)

from which :class:`~archself.modules.base.RuntimeModule` derives ``inputs``,
``optional_inputs``, ``multi_inputs``, ``outputs`` and ``output_sizes`` (the
tuples every other part of archself reads; a type may still set those directly).

An edge names its ends' ports as ``module.port``::

    - {from: heater.q_out, to: zone.q_in, weight: 0.6}

``carries`` is then the source port (``from: heater.q_out`` is ``from: heater``
with ``carries: q_out``) and the target receives the value under its own port name
(``into``). Without ports an edge works as before: ``carries`` names the signal on
both sides. ``archself validate`` (:func:`check_ports`) reports a port the type
does not have (with "did you mean") and a ``carries`` that contradicts ``from``;
the ``double-input`` and ``incomplete`` rules of :mod:`archself.check` count
inputs by the target's port, so a port driven twice in one configuration and a
required input left undriven are errors there.

Examples
--------
>>> split_ref("heater.q_out", ["heater", "zone"])
('heater', 'q_out')
>>> split_ref("zone", ["heater", "zone"])
('zone', None)
>>> split_ref("cell.1.temp", ["cell.1"])   # module names may hold dots
('cell.1', 'temp')
"""

from __future__ import annotations

import dataclasses
import difflib
import operator
from collections.abc import Iterable, Mapping, Sequence
from typing import Any


@dataclasses.dataclass(frozen=True)
class Input:
    """An input port of a module type.

    Parameters
    ----------
    name : str
        The signal name edges deliver it under (``to: module.name``).
    unit : str, optional
        Unit of the value (documentation).
    doc : str, optional
        One line on what the module does with it.
    required : bool, optional
        True (default): a configuration in which no active edge drives it is
        incomplete. False: the module uses it when present.
    multi : bool, optional
        The port takes several edges; the module receives a list, one value per
        edge (file order). Any other port driven by two active edges is an error.
    """

    name: str
    unit: str = ""
    doc: str = ""
    required: bool = True
    multi: bool = False


@dataclasses.dataclass(frozen=True)
class Output:
    """An output port of a module type.

    Parameters
    ----------
    name : str
        The signal name the module publishes it under (``from: module.name``).
    unit : str, optional
        Unit of the value (documentation).
    doc : str, optional
        One line on what it is.
    size : int, optional
        Length of a vector value (lets ``validate`` check objective components).
    elements : tuple of str, optional
        Names of a vector value's elements, in order (``("x", "y", "theta")``): a
        run's table names its columns by them (``actual_x``), not by index.
    """

    name: str
    unit: str = ""
    doc: str = ""
    size: int | None = None
    elements: tuple[str, ...] = ()


def declare(cls: Any) -> None:
    """Derive the signal tuples of ``cls`` from its own ``ports``, if it declares them.

    Raises
    ------
    TypeError
        For an entry that is not an :class:`Input` or :class:`Output`, or a name
        declared twice on the same side.
    """
    ports = cls.__dict__.get("ports")
    if not ports:
        return
    odd = [p for p in ports if not isinstance(p, (Input, Output))]
    if odd:
        raise TypeError(f"{cls.__name__}.ports: {odd[0]!r} is neither an Input nor an Output")
    ins = [p for p in ports if isinstance(p, Input)]
    outs = [p for p in ports if isinstance(p, Output)]
    for side in (ins, outs):
        names = [p.name for p in side]
        twice = next((n for n in names if names.count(n) > 1), None)
        if twice is not None:
            raise TypeError(f"{cls.__name__}.ports: {type(side[0]).__name__} '{twice}' twice")
    cls.inputs = tuple(p.name for p in ins if p.required)
    cls.optional_inputs = tuple(p.name for p in ins if not p.required)
    cls.multi_inputs = tuple(p.name for p in ins if p.multi)
    cls.outputs = tuple(p.name for p in outs)
    cls.output_sizes = {p.name: p.size for p in outs if p.size is not None}
    cls.output_elements = {p.name: tuple(p.elements) for p in outs if p.elements}


def split_ref(ref: str, modules: Iterable[str]) -> tuple[str, str | None]:
    """``module.port`` → ``(module, port)``; a plain module name → ``(module, None)``.

    The module is the longest declared name ``ref`` starts with (followed by a
    dot), so module names with dots work; an undeclared module splits at the first
    dot (the ``reference`` rule then names the unknown module).
    """
    names = modules if isinstance(modules, (set, frozenset, dict)) else set(modules)
    if ref in names:
        return ref, None
    cut = len(ref)
    while (cut := ref.rfind(".", 0, cut)) > 0:  # the longest prefix first: O(dots), not O(M)
        if ref[:cut] in names and cut + 1 < len(ref):
            return ref[:cut], ref[cut + 1 :]
    mod, dot, port = ref.partition(".")
    return (mod, port) if dot and mod and port else (ref, None)


@dataclasses.dataclass(frozen=True)
class EdgePorts:
    """The ports the edges of an architecture name, by edge index (``arch.edge_ports``).

    One plain table per architecture, made once by :func:`resolve_edges`, so the
    loops over 10^5 edges (``validate``, the executor's routes) index tuples instead
    of reading per-edge state off the pydantic models.

    Attributes
    ----------
    edges : tuple of Edge
        The edges it describes, in file order (``arch.edge_ports`` rebuilds the table
        when ``arch.edges`` no longer holds these objects).
    from_port : tuple of str or None
        The output port ``from`` names (``module.port``), else None.
    to_port : tuple of str or None
        The input port ``to`` names (``module.port``), else None.
    """

    edges: tuple[Any, ...]
    from_port: tuple[str | None, ...]
    to_port: tuple[str | None, ...]

    def into(self, i: int) -> str:
        """The input of edge ``i``'s target the value arrives at: the port in ``to``, else
        ``carries``."""
        return self.to_port[i] or self.edges[i].carries

    def describes(self, edges: Sequence[Any]) -> bool:
        """True when ``edges`` are exactly the edge objects of this table, in order."""
        return len(edges) == len(self.edges) and all(map(operator.is_, edges, self.edges))


def resolve_edges(modules: Mapping[str, Any], edges: Iterable[Any],
                  known: EdgePorts | None = None) -> EdgePorts:
    """Split ``from``/``to`` of every edge into module and port: the :class:`EdgePorts`.

    ``carries`` defaults to the source port, else to the target port; an edge's
    ``source``/``target`` are module names afterwards, whatever the file wrote (the
    edges are changed in place). Edges ``known`` describes keep their ports (they
    were split before).
    """
    names = modules if isinstance(modules, (set, frozenset, dict)) else set(modules)
    edges = tuple(edges)
    from_ports: list[str | None] = [None] * len(edges)
    to_ports: list[str | None] = [None] * len(edges)
    before: dict[int, int] = {}  # id of a known edge -> its index in known
    if known is not None:  # known holds its edges, so their ids are not reused meanwhile
        before = {id(e): j for j, e in enumerate(known.edges)}
        for i, e in enumerate(edges):
            j = before.get(id(e))
            if j is not None:
                from_ports[i], to_ports[i] = known.from_port[j], known.to_port[j]
    # the common case, both ends module names, in one comprehension; the rest split here
    for i in [i for i, e in enumerate(edges) if e.source not in names or e.target not in names]:
        e = edges[i]
        if id(e) in before:  # split before (an undeclared module stays one)
            continue
        if e.source not in names:
            e.source, from_ports[i] = split_ref(e.source, names)
        if e.target not in names:
            e.target, to_ports[i] = split_ref(e.target, names)
        if not e.carries and (from_ports[i] or to_ports[i]):
            e.carries = from_ports[i] or to_ports[i]
    return EdgePorts(edges, tuple(from_ports), tuple(to_ports))


def _hint(word: str, options: Iterable[str]) -> str:
    options = list(options)
    close = difflib.get_close_matches(word, options, n=1)
    if close:
        return f"did you mean '{close[0]}'?"
    return f"it has: {', '.join(options) or 'none'}"


def port_findings(arch: Any, types: Mapping[str, Any]) -> Iterable[tuple[str, str, tuple]]:
    """``(code, message, path)`` of every port problem of ``arch``'s edges.

    ``types`` maps module name → its runtime class (or None when unknown). Checked:
    an edge that names no signal, ``carries`` against the port in ``from``, and
    named ports against the ports the types declare. (Ports driven twice and
    undriven required inputs are the ``double-input`` and ``incomplete`` rules.)
    """
    ports = arch.edge_ports
    for i, (e, from_port, to_port) in enumerate(zip(arch.edges, ports.from_port, ports.to_port,
                                                          strict=True)):
        if not e.carries:
            yield ("port", "the edge names no signal: give 'carries', or the ports as "
                   "'from: module.port' / 'to: module.port'", ("edges", i))
            continue
        if from_port is None and to_port is None:  # the common case: nothing more to check
            continue
        if from_port is not None and e.carries != from_port:
            yield ("port", f"'carries: {e.carries}' contradicts the port in 'from' "
                   f"('{e.source}.{from_port}'); give one of them", ("edges", i, "carries"))
        src, dst = types.get(e.source), types.get(e.target)
        if from_port is not None and src is not None and src.outputs \
                and from_port not in src.outputs:
            yield ("port", f"'{e.source}' ({arch.modules[e.source].type}) has no output port "
                   f"'{from_port}'; {_hint(from_port, src.outputs)}", ("edges", i, "from"))
        takes = (dst.inputs + dst.optional_inputs) if dst is not None else ()
        if to_port is not None and takes and to_port not in takes:
            yield ("port", f"'{e.target}' ({arch.modules[e.target].type}) has no input port "
                   f"'{to_port}'; {_hint(to_port, takes)}", ("edges", i, "to"))
