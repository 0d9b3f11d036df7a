"""Which module types run in lanes, and the lane class of a type.

A type batches when it names a :class:`~archself.lanes.module.LaneModule` in its
``lanes`` attribute; every other type runs lane by lane
(:class:`~archself.lanes.module.PerLane`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from archself import registry
from archself.errors import SimulationError
from archself.lanes.module import LaneModule, PerLane

__all__ = ["batched_types", "lane_module", "lane_module_class"]


def batched_types(arch: Any) -> bool:
    """Whether every module type of ``arch`` has a batched class (none runs as PerLane).

    Lanes of types that run one by one gain nothing over separate runs (before their
    packs were batched, the tank's and the motor drive's campaigns took as long either
    way) and hold more memory, so campaigns and calibrations batch by default only files
    for which this holds (all three shipped files do).
    """

    return all(
        getattr(registry.get(spec.type), "lanes", None) is not None
        for spec in arch.modules.values()
    )


def lane_module_class(module: Any) -> type[LaneModule]:
    """The lane class of a per-run instance's type: its ``lanes`` class or PerLane.

    ``lanes`` is a :class:`~archself.lanes.module.LaneModule` subclass or its
    ``"package.module:Class"`` path (imported on first use: a pack's batched code
    costs nothing to a run that does not batch).
    """
    kind = type(module)
    cls = getattr(kind, "lanes", None)
    if isinstance(cls, str):
        import importlib

        where, _, attr = cls.partition(":")
        try:
            cls = getattr(importlib.import_module(where), attr)
        except (ImportError, AttributeError) as exc:
            raise SimulationError(
                f"module type {kind.__name__}: its lanes class {kind.lanes!r} "
                f"cannot be imported: {exc}"
            ) from None
    return cls if cls is not None else PerLane


def lane_module(modules: Sequence[Any]) -> LaneModule:
    """The batched module of N per-run instances (:func:`lane_module_class`)."""
    return lane_module_class(modules[0])(modules)
