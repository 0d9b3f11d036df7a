"""The typed doors, checked by ``mypy --strict`` (tests/test_static.py): each class that plays a
role of :mod:`archself.contracts` is assignable to its protocol. Not a pytest module."""

from __future__ import annotations

from archself.contracts import BatchedModule, LoopSystem, ManagedSystem, SystemSnapshot
from archself.lanes.module import LaneModule, PerLane
from archself.lanes.view import LaneView
from archself.live.system import MeasuredSystem, ModelSnapshot
from archself.system.live import LiveSystem
from archself_blocks.lanes_control import PidLanes
from archself_diffdrive.lanes_estimators import EkfLanes
from archself_process.lanes_tank import TankPlantLanes


def live_system(s: LiveSystem) -> ManagedSystem:
    return s


def lane_view(s: LaneView) -> ManagedSystem:
    return s


def live_system_loop(s: LiveSystem) -> LoopSystem:
    return s


def lane_view_loop(s: LaneView) -> LoopSystem:
    return s


def measured_system(s: MeasuredSystem) -> ManagedSystem:
    return s


def model_snapshot(s: ModelSnapshot) -> SystemSnapshot:
    return s


def lane_module(m: LaneModule) -> BatchedModule:
    return m


def per_lane(m: PerLane) -> BatchedModule:
    return m


def packs(a: PidLanes, b: EkfLanes, c: TankPlantLanes) -> list[BatchedModule]:
    return [a, b, c]
