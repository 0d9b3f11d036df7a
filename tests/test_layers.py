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


#: files whose functions may import ``archself…`` (docs/develop.md, "Late imports"), with
#: how many such imports they hold at most. Every other file imports at module level.
LATE = {
    # start-up: `import archself`, `archself --help`, `validate` and each command's `--help`
    # load only the command run (PEP 562 names in the __init__s); its work loads on its call
    "__init__": 6, "calibration/__init__": 1, "ros2/__init__": 2, "cli/base": 10,
    "cli/calibration": 12, "cli/campaigns": 6, "cli/files": 21, "cli/live": 13, "cli/reports": 5,
    "cli/runs": 13, "model/architecture": 1, "model/messages": 2, "sim/result": 2,
    # io/jsondata: its printed documents (io/outdocs) by name, PEP 562 (a run prints none)
    "io/jsondata": 1,
    # on demand: one function needs what the file's other users do not load (matplotlib,
    # networkx, scipy, the opt-in stability check, pydantic models, the lanes or a whole run)
    "calibration/report": 4, "calibration/runs": 5, "campaign/figures": 1, "campaign/plan": 1,
    "campaign/report": 2, "campaign/worker": 4, "check/rules": 4, "check/stability": 2,
    "model/loader": 1, "model/schema": 1, "registry": 1, "reports/run": 2,
    "reports/run_report": 1, "ros2/demo": 2, "runtime/stability": 2, "testing": 8,
    # a layer rule: an import that goes up (KNOWN above)
    "modules/base": 1,
}
#: late imports kept as a seam a test patches: (file, module imported)
SEAMS = {("archself.campaign.worker", "archself.model.loader")}  # tests/test_campaign.py


def _late_imports(tree: ast.Module) -> list[ast.Import | ast.ImportFrom]:
    """``import archself…`` statements inside a function."""
    found: list[ast.Import | ast.ImportFrom] = []
    for fn in ast.walk(tree):
        if isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            found += [n for n in ast.walk(fn) if isinstance(n, ast.Import | ast.ImportFrom)
                      and _targets(n)]
    return list({id(n): n for n in found}.values())  # a nested function's once


def _targets(node: ast.Import | ast.ImportFrom) -> set[str]:
    """``archself`` modules an import statement names (with the packages above them)."""
    names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
             [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
             if node.module and node.level == 0 else [])
    return {".".join(n.split(".")[:i]) for n in names if n.startswith("archself")
            for i in range(1, n.count(".") + 2)}


def test_late_imports_only_where_documented() -> None:
    counts = {}
    for path in PKG.rglob("*.py"):
        n = len(_late_imports(ast.parse(path.read_text(encoding="utf-8"))))
        if n:
            counts[path.relative_to(PKG).with_suffix("").as_posix()] = n
    over = {f: n for f, n in counts.items() if n > LATE.get(f, 0)}
    assert over == {}, f"late imports past docs/develop.md's allowance: {over}"


def test_no_late_import_of_what_the_file_already_loads() -> None:
    """A late import whose modules the file's module-level imports already load saves nothing:
    it goes to module level. (A name a package resolves lazily, PEP 562, is not loaded.)"""
    modules = {_module_name(p): p for p in PKG.rglob("*.py")}
    trees = {m: ast.parse(p.read_text(encoding="utf-8")) for m, p in modules.items()}

    def top(node: ast.AST) -> set[str]:
        """What a module body imports when it runs: no function, no ``TYPE_CHECKING``."""
        if isinstance(node, ast.Import | ast.ImportFrom):
            return _targets(node) & set(modules)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) or (
                isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)):
            return set()
        return set().union(*map(top, ast.iter_child_nodes(node)))

    direct = {m: top(t) | {m.rpartition(".")[0]} & set(modules) for m, t in trees.items()}
    graph = nx.DiGraph([(a, b) for a, bs in direct.items() for b in bs])
    graph.add_nodes_from(modules)
    loads = {m: nx.descendants(graph, m) | {m} for m in modules}
    lazy = {m for m, t in trees.items() if _bound(t, "__getattr__")}
    needless = []
    for m, tree in trees.items():
        for node in _late_imports(tree):
            if isinstance(node, ast.ImportFrom) and node.module in lazy and any(
                    f"{node.module}.{a.name}" not in modules
                    and not _bound(trees[node.module], a.name) for a in node.names):
                continue
            if _targets(node) & set(modules) <= loads[m] and (m, getattr(node, "module", None)) \
                    not in SEAMS:
                needless.append(f"{m}:{node.lineno} {ast.unparse(node)}")
    assert needless == []


def _bound(tree: ast.Module, name: str) -> bool:
    """Whether a module's top level binds ``name`` (an assignment, a def, an import)."""
    for node in tree.body:
        if isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(isinstance(t, ast.Name) and t.id == name for t in targets):
                return True
        elif isinstance(node, ast.Import | ast.ImportFrom):
            if any((a.asname or a.name).split(".")[0] == name for a in node.names):
                return True
        elif getattr(node, "name", None) == name:
            return True
    return False
