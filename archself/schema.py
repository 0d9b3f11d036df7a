"""Generate the JSON Schema of architecture files from the pydantic model."""

from __future__ import annotations

import json
from functools import cache
from typing import Any

SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
SCHEMA_ID = "https://archself.dev/schemas/architecture.schema.json"


@cache
def architecture_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of an architecture file.

    Examples
    --------
    >>> s = architecture_schema()
    >>> s["$schema"], sorted(s["required"])[:2]
    ('https://json-schema.org/draft/2020-12/schema', ['archself', 'configurations'])
    """
    from archself.model import Architecture

    body = Architecture.model_json_schema(by_alias=True, mode="validation")
    return {"$schema": SCHEMA_DIALECT, "$id": SCHEMA_ID, **body}


def schema_text() -> str:
    """The schema as the text checked in at ``schemas/architecture.schema.json``."""
    return json.dumps(architecture_schema(), indent=2, ensure_ascii=False, sort_keys=False) + "\n"
