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


def test_plugin_guide_shows_the_real_code() -> None:
    guide = (ROOT / "docs" / "plugins.md").read_text(encoding="utf-8")
    code = (ROOT / "plugins" / "archself-example" / "archself_example" / "level.py").read_text(
        encoding="utf-8"
    )
    assert f"```python\n{code}```" in guide


def test_docs_links_resolve() -> None:
    import re

    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    broken = []
    for page in pages:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text(encoding="utf-8")):
            if "://" in target:
                continue
            if not (page.parent / target).exists():
                broken.append(f"{page.name}: {target}")
    assert not broken, broken
