"""Documentation that must stay in step with the code."""

from __future__ import annotations

from conftest import ROOT


def test_develop_md_lists_every_module() -> None:
    text = (ROOT / "docs" / "develop.md").read_text(encoding="utf-8")
    missing = [
        str(p.relative_to(ROOT))
        for p in sorted((ROOT / "archself").rglob("*.py"))
        if f"`{p.relative_to(ROOT)}`" not in text
    ]
    assert not missing, f"docs/develop.md does not describe: {missing}"
