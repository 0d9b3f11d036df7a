"""The package's layers (docs/develop.md, "Layers"): imports go one way, and no circle.

Every ``import archself…`` counts: at module level, inside functions and under
``TYPE_CHECKING``.
"""

from __future__ import annotations

import ast

import networkx as nx

from conftest import ROOT

PKG = ROOT / "archself"

#: low to high; a layer imports only layers before it (or itself)
LAYERS = [
    {"errors", "findings", "resources"},
    {"modules", "registry"},
    {"io"},
    {"model"},
    {"linear"},
    {"contracts"},
    {"system"},
    {"sim"},
    {"runtime"},
    {"check"},
    {"reports"},
    {"lanes", "live"},
    {"ros2"},
    {"campaign", "calibration"},
    {"testing"},
    {"cli", "__main__", "__init__"},
]
#: imports that go up, each named in docs/develop.md (Known exceptions) with its way out
KNOWN = {
    ("linear.wiring", "model.loader"),
    ("modules.base", "model.architecture"),
}


def _module_name(path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    name = ".".join(rel.parts)
    return name.removesuffix(".__init__")


def _graph() -> nx.DiGraph:
    modules = {_module_name(p): p for p in PKG.rglob("*.py")}
    g = nx.DiGraph()
    for name, path in modules.items():
        g.add_node(name)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                subs = [f"{node.module}.{a.name}" for a in node.names
                        if f"{node.module}.{a.name}" in modules]
                targets = subs or [node.module]
            for t in targets:
                while t and t not in modules:
                    t = t.rpartition(".")[0]
                if t and t != name and t != "archself":
                    g.add_edge(name, t)
    return g


def _layer(module: str) -> int:
    parts = module.split(".")
    top = parts[1] if len(parts) > 1 else "__init__"
    return next(i for i, names in enumerate(LAYERS) if top in names)


def test_no_import_circle() -> None:
    circles = [sorted(c) for c in nx.strongly_connected_components(_graph()) if len(c) > 1]
    assert circles == []


def test_imports_go_down_the_layers() -> None:
    up = set()
    for a, b in _graph().edges:
        if _layer(b) > _layer(a):
            up.add((a.removeprefix("archself."), b.removeprefix("archself.")))
    assert up <= KNOWN, sorted(up - KNOWN)


def test_the_package_root_is_its_public_surface() -> None:
    root_files = sorted(p.name for p in PKG.glob("*.py"))
    assert len(root_files) <= 12, root_files
