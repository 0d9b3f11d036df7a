"""Physically meaningful ranges of module parameters (``Param(min=, max=)``).

Declared once by the module types; refused by ``validate`` (located finding, see the
``out_of_declared_range`` fixture), by a campaign's sweep, by the planner (a
parameter update outside the range is a ``limit`` rejection in the decision log)
and by ``set_params``.
"""

from __future__ import annotations

import importlib.metadata
import math
from pathlib import Path

import pytest

from archself import registry
from archself.errors import SimulationError
from archself.model.loader import load_architecture, load_text
from archself.modules.base import REQUIRED, Param
from archself.runtime import MapeK, explain
from archself.sim.run import simulate

from conftest import FIXTURES

PACKS = ("archself_blocks", "archself_diffdrive", "archself_process")

#: Parameters of the block library whose numbers have no range of their own: matrices,
#: gains and offsets in the units of whatever they are wired to, signs either way (the
#: global cap |x| ≤ 1e9 of every file number still holds).
UNBOUNDED = {
    "generic.actuator": {"gain", "scale", "u_min", "u_max", "initial"},
    "generic.ekf": {"Q", "R", "P0", "x0"},  # covariance matrices: off-diagonals of any sign
    "generic.kalman": {"Q", "R", "P0", "x0"},
    "generic.expression": {"expression"},  # text: parsed and checked by the type
    "generic.gain": {"gain", "offset"},
    "generic.lti_model": {"A", "B", "C", "D"},
    "generic.luenberger": {"gain", "poles", "x0"},
    "generic.pid": {"kp", "ki", "kd", "ff_gain", "ff_rate_gain", "ff_offset", "u_min", "u_max",
                    "initial_integral"},
    "generic.reference": {"table"},
    "generic.relay": {"gain"},
    "generic.sensor": {"gain", "bias", "drift_per_s", "min", "max"},
    "generic.state_space": {"A", "B", "C", "D", "x0"},
    "generic.sum": {"weights"},
    "generic.transfer_function": {"num", "den", "x0"},
}


def _shipped_types() -> list[tuple[str, type]]:
    points = importlib.metadata.entry_points(group="archself.modules")
    return sorted(
        (ep.name, registry.lookup(ep.name)) for ep in points
        if ep.value.split(".")[0].split(":")[0] in PACKS
    )


def _numeric(p: Param) -> bool:
    d = p.default
    if d is REQUIRED or d is None:
        return True  # a number the file gives, or a None that stands for "none"
    return isinstance(d, (int, float, list)) and not isinstance(d, bool)


@pytest.mark.parametrize("key, cls", _shipped_types(), ids=[k for k, _ in _shipped_types()])
def test_shipped_parameters_declare_ranges_that_hold_their_defaults(key: str, cls: type) -> None:
    for name, p in (cls.parameters or {}).items():
        if isinstance(p.default, float) and not math.isfinite(p.default):
            pass  # inf: "no limit", never a file value (the schema takes finite numbers)
        elif not p.required and p.default is not None:
            assert p.outside(p.default) is None, f"{key}.{name}: default {p.default!r}"
        if p.min is not None and p.max is not None:
            assert p.min < p.max, f"{key}.{name}"
        if not _numeric(p) or name in UNBOUNDED.get(key, ()):
            continue
        assert p.min is not None or p.max is not None, f"{key}.{name} declares no range"


def test_param_outside_names_the_first_number_outside() -> None:
    p = Param(0.5, "m", "wheel base", min=0.01, max=100.0)
    assert p.outside(0.5) is None and p.outside([[0.5, 3.0]]) is None
    assert p.outside([0.5, -2.0, 1e8]) == "-2 is outside [0.01, 100] m"
    assert Param(0.0, min=0.0).outside(-1e-3) == "-0.001 is outside [0, ∞]"
    assert Param(0.0).outside(1e300) is None  # no range declared
    assert Param(True, min=0.0).outside(False) is None  # booleans are not numbers here


def _limit_blocks(monkeypatch: pytest.MonkeyPatch) -> str:
    """The limit fixture with ``generic.actuator``'s gain given the range [0, 2] for the test."""
    cls = registry.lookup("generic.actuator")
    params = dict(cls.parameters)
    params["gain"] = Param(1.0, "", "effectiveness", min=0.0, max=2.0)
    monkeypatch.setattr(cls, "parameters", params)
    return (FIXTURES / "valid" / "limit_blocks.yaml").read_text(encoding="utf-8")


def test_the_planner_rejects_an_update_outside_the_declared_range(monkeypatch) -> None:
    """An architecture that was never validated: the planner judges θ by the type's range."""
    arch = load_text(_limit_blocks(monkeypatch), "x.yaml").arch
    loop = MapeK(arch)
    simulate(arch, "main_loss", seed=1, adapt=loop)
    d = next(d for d in loop.decisions if abs(d.t - 10.5) < 1e-9)
    ev = {e.action: (e.rejected, e.detail) for e in d.evaluations}
    # the file's max_gain 3 is judged first, then the type's range
    assert ev["boost_main_hard"] == ("limit", "θ: main.gain = 4 would break max_gain 3")
    assert ev["boost_main"] == (
        "limit", "θ: main.gain = 2.5 is outside [0, 2], the range type 'generic.actuator' declares")
    assert loop.updates == []
    assert "rejected (limit: θ: main.gain = 2.5 is outside [0, 2]" in explain(loop.decisions)


def test_set_params_refuses_a_value_outside_the_declared_range() -> None:
    from archself.system.live import compile_system

    arch = load_architecture(FIXTURES / "valid" / "minimal.yaml").arch
    system = compile_system(arch, arch.initial_configuration(), seed=0)
    with pytest.raises(SimulationError, match=r"encoders.noise_rad_s: 500 is outside \[0, 100\] "
                       r"rad/s, the range type 'sensor.encoders' declares"):
        system.set_params("encoders", {"noise_rad_s": 500.0})
    system.set_params("encoders", {"noise_rad_s": 0.1})  # inside: applied
    assert system.pool()["encoders"].params["noise_rad_s"] == 0.1


def test_a_sweep_outside_the_declared_range_is_refused(tmp_path: Path) -> None:
    from archself.campaign.driver import plan_campaign
    from archself.campaign.sweep import CampaignError, parse_sweep

    text = (FIXTURES / "valid" / "minimal.yaml").read_text(encoding="utf-8").replace(
        "type: model.diffdrive_kinematics}",
        "type: model.diffdrive_kinematics, params: {wheel_base_m: {value: 0.5}}}")
    path = tmp_path / "m.yaml"
    path.write_text(text, encoding="utf-8")
    sweep = parse_sweep("modules.kinematics.params.wheel_base_m.value=0.5,1e8")
    expected = (r"wheel_base_m.value=100000000: .*value: 1e\+08 is outside \[0.01, 100\] m, "
                r"the range type 'model.diffdrive_kinematics'")
    with pytest.raises(CampaignError, match=expected):
        plan_campaign(path, ["calm"], 1, [sweep])
