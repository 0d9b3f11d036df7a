"""Generate the JSON Schema of architecture files from the pydantic model."""

from __future__ import annotations

import json
from functools import cache
from typing import Any

from archself.registry import _points

SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
SCHEMA_ID = "https://archself.dev/schemas/architecture.schema.json"


#: The distribution whose module types are "built in" (the packs shipped with archself).
BUILTIN_DIST = "archself"

#: ``examples`` of key fields, for editors' completion: ($def, property) -> values.
FIELD_EXAMPLES: dict[tuple[str, str], list[Any]] = {
    ("Edge", "weight"): [0.5, 0.3, 0.1],
    ("Edge", "carries"): ["pose", "heading", "wheel_speeds", "command"],
    ("Parameter", "unit"): ["m", "s", "Hz", "rad/s", "m/s", "K"],
    ("Objective", "unit"): ["m", "K", "rad", "m/s"],
    ("Objective", "actual"): ["chassis.pose", "tank.level"],
    ("Objective", "reference"): ["planner.reference", "setpoint.reference"],
    ("Runtime", "step_s"): [0.05, 0.01],
    ("Runtime", "period_s"): [0.5, 1.0],
    ("Runtime", "threshold"): [0.55, 0.5],
    ("Runtime", "dwell_s"): [10, 30],
    ("Runtime", "cost_weight"): [0.5],
    ("Runtime", "warmup_s"): [0, 30],
    ("Fault", "onset_s"): [10, 20],
    ("Fault", "magnitude"): [0.4, 7e-4],
    ("Action", "cost"): [0.2, 0.3],
    ("Scenario", "duration_s"): [200, 400],
}


def module_types(installed: bool = True) -> list[str]:
    """The module types for the schema: the built-in packs', and installed plugins' too.

    Read from the ``archself.modules`` entry points (names only, nothing imported).
    With ``installed=False`` only the types of the archself distribution itself (the
    checked-in schema, the same on every machine).
    """

    return sorted(name for name, ep in _points().items()
                  if installed or getattr(ep.dist, "name", None) == BUILTIN_DIST)


@cache
def architecture_schema(installed: bool = True) -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of an architecture file.

    A module's ``type`` lists the registered types as ``examples`` (what editors offer
    for completion; another type still validates, it may come from a plugin installed
    later): the built-in packs' and, with ``installed`` (``archself schema``), those of the
    installed plugins. Key fields carry ``examples`` too (:data:`FIELD_EXAMPLES`).

    Examples
    --------
    >>> s = architecture_schema(installed=False)
    >>> s["$schema"], sorted(s["required"])[:2]
    ('https://json-schema.org/draft/2020-12/schema', ['archself', 'configurations'])
    >>> "sensor.imu" in s["$defs"]["Module"]["properties"]["type"]["examples"]
    True
    """
    from archself.model.architecture import Architecture

    body = Architecture.model_json_schema(by_alias=True, mode="validation")
    defs = body.get("$defs", {})
    prop = defs.get("Module", {}).get("properties", {}).get("type")
    if prop is not None:
        types = module_types(installed)
        prop["examples"] = types
        prop["description"] = (
            "τ_i: key of a registered module type: a built-in one (the examples) or an "
            "installed plugin's (`archself schema` adds those to the examples)."
        )
    for (name, field), values in FIELD_EXAMPLES.items():
        target = defs.get(name, {}).get("properties", {}).get(field)
        if target is not None:
            target["examples"] = values
    return {"$schema": SCHEMA_DIALECT, "$id": SCHEMA_ID, **body}


def schema_text(installed: bool = True) -> str:
    """The schema as JSON text; ``installed=False`` is the checked-in
    ``schemas/architecture.schema.json`` (built-in module types only)."""
    return json.dumps(architecture_schema(installed), indent=2, ensure_ascii=False,
                      sort_keys=False) + "\n"
