"""Write docs/json.md's JSON Schemas from the pydantic models.

Each generated block sits between ``<!-- schema: module:Model -->`` and
``<!-- end schema -->``; ``python tools/json_docs.py`` rewrites every such block from
``Model.model_json_schema()`` (without pydantic's automatic titles; a value on one line
when it fits, else one item per line). tests/test_json_shapes.py fails when a block and
its model differ.
"""

from __future__ import annotations

import importlib
import json
import re
import sys
from pathlib import Path
from typing import Any

PAGE = Path(__file__).resolve().parent.parent / "docs" / "json.md"
BLOCK = re.compile(r"(<!-- schema: ([\w.]+):(\w+) -->\n).*?(<!-- end schema -->)", re.S)


def _untitled(s: Any, name: str = "") -> Any:
    """``s`` without the titles pydantic makes up (a field's or a class's name)."""
    if isinstance(s, list):
        return [_untitled(v) for v in s]
    if not isinstance(s, dict):
        return s
    auto = {name.replace("_", " ").title(), name}
    return {k: (_untitled(v, k if isinstance(v, dict) else "") if k != "properties" else
                {p: _untitled(ps, p) for p, ps in v.items()})
            for k, v in s.items() if not (k == "title" and v in auto)}


def _render(v: Any, pad: str = "", width: int = 92) -> str:
    """JSON: a value on one line when it fits in ``width``, else one item per line."""
    flat = json.dumps(v, ensure_ascii=False)
    if len(pad) + len(flat) <= width or not isinstance(v, dict | list) or not v:
        return flat
    inner = pad + "  "
    items = ([_render(x, inner, width) for x in v] if isinstance(v, list) else
             [f"{json.dumps(k)}: {_render(x, inner, width)}" for k, x in v.items()])
    ends = "[]" if isinstance(v, list) else "{}"
    return ends[0] + "\n" + ",\n".join(inner + i for i in items) + "\n" + pad + ends[1]


def model(module: str, name: str) -> Any:
    """The model ``module:name``."""
    return getattr(importlib.import_module(module), name)


def schema_block(module: str, name: str) -> str:
    """The ```json block of the model ``module:name``."""
    schema = _untitled(model(module, name).model_json_schema(), name)
    return f"```json\n{_render(schema)}\n```\n"


def render(text: str) -> str:
    """``text`` with every generated block rewritten."""
    return BLOCK.sub(lambda m: m[1] + schema_block(m[2], m[3]) + m[4], text)


def main() -> int:
    text = PAGE.read_text(encoding="utf-8")
    new = render(text)
    if new != text:
        PAGE.write_text(new, encoding="utf-8")
    print(f"docs/json.md: {'rewritten' if new != text else 'up to date'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
