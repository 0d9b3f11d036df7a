"""Documentation that must stay in step with the code."""

from __future__ import annotations

from conftest import ROOT


def test_develop_md_lists_every_module_once() -> None:
    text = (ROOT / "docs" / "develop.md").read_text(encoding="utf-8")
    rows = [line.split("|")[1].strip(" `") for line in text.splitlines()
            if line.startswith(("| `archself/", "| `packs/"))]
    modules = sorted(str(p.relative_to(ROOT)) for top in ("archself", "packs")
                     for p in (ROOT / top).rglob("*.py"))
    missing = [m for m in modules if m not in rows]
    assert not missing, f"docs/develop.md does not describe: {missing}"
    twice = sorted({r for r in rows if rows.count(r) > 1})
    assert not twice, f"docs/develop.md describes these more than once: {twice}"


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
