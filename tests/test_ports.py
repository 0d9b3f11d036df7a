"""Named ports (archself.model.architecture): declarations, edges that name them, their checks."""

from __future__ import annotations

import pytest

from archself.check import check
from archself.model.architecture import Input, Output, declare, split_ref
from archself.model.loader import load_text
from archself.modules.base import RuntimeModule

from conftest import FIXTURES

MINIMAL = (FIXTURES / "valid" / "minimal.yaml").read_text()
HEADING = "  - {from: compass, to: dead_reckoning, weight: 0.5, carries: heading}"


def _findings(text: str) -> list[tuple[str, str, str]]:
    return [(f.severity, f.code, f.message) for f in check(load_text(text, "m.yaml"))]


def test_split_ref_takes_the_longest_declared_module() -> None:
    names = ["a", "a.b", "zone"]
    assert split_ref("a.b.port", names) == ("a.b", "port")
    assert split_ref("a.port", names) == ("a", "port")
    assert split_ref("a.b", names) == ("a.b", None)
    assert split_ref("nowhere.port", names) == ("nowhere", "port")
    assert split_ref("plain", names) == ("plain", None)


def test_declared_ports_give_the_signal_tuples() -> None:
    class Zone(RuntimeModule):
        ports = (
            Input("q_in", "W", "heat", multi=True),
            Input("setpoint", "K", required=False),
            Output("temperature", "K", size=1),
            Output("state", size=2),
            Output("q_in", "W", "the heat it took (an input and an output of one name)"),
        )

    declare(Zone)  # RuntimeModule.__init_subclass__ does it on class creation
    assert Zone.inputs == ("q_in",)
    assert Zone.optional_inputs == ("setpoint",)
    assert Zone.multi_inputs == ("q_in",)
    assert Zone.outputs == ("temperature", "state", "q_in")
    assert Zone.output_sizes == {"temperature": 1, "state": 2}

    with pytest.raises(TypeError, match="neither an Input nor an Output"):
        class Odd(RuntimeModule):
            ports = (1.0,)
        declare(Odd)
    with pytest.raises(TypeError, match="Output 'y' twice"):
        class Twice(RuntimeModule):
            ports = (Output("y"), Output("y"))
        declare(Twice)


def test_an_edge_with_ports_is_the_edge_with_carries() -> None:
    ported = MINIMAL.replace(HEADING, "  - {from: compass.heading, to: dead_reckoning.heading, "
                             "weight: 0.5}")
    arch = load_text(ported, "m.yaml").arch
    e, ports = arch.edges[7], arch.edge_ports
    assert (e.source, e.target, e.carries, ports.into(7)) == ("compass", "dead_reckoning",
                                                              "heading", "heading")
    assert (ports.from_port[7], ports.to_port[7]) == ("heading", "heading")
    assert _findings(ported) == _findings(MINIMAL)
    # a port in 'to' alone names the signal on both sides
    only_to = MINIMAL.replace(HEADING, "  - {from: compass, to: dead_reckoning.heading, "
                              "weight: 0.5}")
    assert _findings(only_to) == _findings(MINIMAL)
    # a deep copy keeps the ports (campaign workers copy the model)
    assert arch.model_copy(deep=True).edge_ports.from_port[7] == "heading"
    # the table follows the edge list: an edge added after loading is split on first use
    copy = arch.model_copy(deep=True)
    copy.edges.insert(0, copy.edges[7].model_copy(update={"source": "compass.heading",
                                                          "target": "dead_reckoning.heading"}))
    assert copy.edge_ports.to_port[0] == "heading"
    assert copy.edge_ports.from_port[8] == "heading"  # kept for the edges it knew
    assert copy.edges[0].source == "compass"


def test_an_edge_without_a_signal_is_an_error() -> None:
    bare = MINIMAL.replace(HEADING, "  - {from: compass, to: dead_reckoning, weight: 0.5}")
    found = _findings(bare)
    assert ("error", "port", "the edge names no signal: give 'carries', or the ports as "
            "'from: module.port' / 'to: module.port'") in found


def test_a_renamed_port_counts_for_the_target_port() -> None:
    # 'heading' delivered into the optional input 'position': heading is missing now
    renamed = MINIMAL.replace(HEADING, "  - {from: compass.heading, to: dead_reckoning.position,"
                              " weight: 0.5}")
    found = _findings(renamed)
    assert any(c == "incomplete" and "needs 'heading'" in m for _, c, m in found)
    assert not any(c == "signal" for _, c, m in found)



def test_identify_writes_weights_into_edges_that_name_ports() -> None:
    from archself.calibration.identify import set_weights

    ported = MINIMAL.replace(HEADING, "  - {from: compass.heading, to: dead_reckoning.heading, "
                             "weight: 0.5}")
    out = set_weights(ported, "m.yaml", {("compass", "dead_reckoning"): 0.25}, "fitted")
    e = load_text(out, "m.yaml").arch.edges[7]
    assert (e.source, e.target, e.weight) == ("compass", "dead_reckoning", 0.25)
