"""``archself report``: the architecture report (DSMs, Fig. 1 graphs, diffs, index page).

Files written to the output folder (``<s>`` is a file-name-safe form of a
configuration name, see :func:`archself.reports.render.slug`):

==============================================  =========================================
file                                            content
==============================================  =========================================
``index.html``                                  links to everything below
``dsm-architecture.{html,md}``                  DSM of all modules, three orderings
``dsm-architecture.{kind,sequenced,clustered}.csv``  one CSV per ordering
``dsm-config-<s>.*``                            the same per configuration
``graph-architecture.dot``, ``graph-config-<s>.dot``  Fig. 1 style graph
``diff-<a>--<b>.dot``                           what configuration b adds to / removes from a
``*.svg``, ``*.png``                            the DOT files rendered, when ``dot`` is on PATH
==============================================  =========================================

Everything but the SVG/PNG images is a deterministic function of the
architecture file (no dates, fixed orderings, a fixed clustering seed).
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from archself.atomic import write_bytes, write_text
from archself.errors import OutputError
from archself.model import Architecture
from archself.reports.dsm import KIND_TITLES, KINDS, build_dsm, orderings
from archself.reports.graph import build_graph, config_diff, diff_graph, diff_pairs
from archself.reports.render import render, unique_slugs

__all__ = ["ArchitectureReport", "render_dot", "write_architecture_report"]


@dataclass
class ArchitectureReport:
    """What :func:`write_architecture_report` wrote."""

    out_dir: Path
    files: list[str] = field(default_factory=list)
    rendered: bool = False
    note: str = ""

    @property
    def index(self) -> Path:
        return self.out_dir / "index.html"


def ensure_dir(path: Path) -> None:
    """Create the output folder (and parents); an OutputError if that fails."""
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path}: not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{path}: cannot create folder: {exc.strerror}") from None
    if not path.is_dir():
        raise OutputError(f"{path}: not a folder")


def render_dot(dot_file: Path, fmt: str, dot: str) -> tuple[bytes | None, str]:
    """Run ``dot -T<fmt>`` on ``dot_file``; ``(output, "")`` or ``(None, error text)``."""
    try:
        proc = subprocess.run([dot, f"-T{fmt}", str(dot_file)], capture_output=True, timeout=120,
                              check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return None, f"{type(exc).__name__}: {exc}"
    if proc.returncode != 0:
        lines = proc.stderr.decode("utf-8", "replace").strip().splitlines()
        return None, lines[-1] if lines else f"dot exited with {proc.returncode}"
    return proc.stdout, ""


def write_architecture_report(
    arch: Architecture, out_dir: str | Path, *, dot: str | None | bool = True
) -> ArchitectureReport:
    """Write the architecture report of ``arch`` into ``out_dir`` (created if missing).

    Parameters
    ----------
    arch : Architecture
    out_dir : path
    dot : str, bool or None
        Path of Graphviz ``dot``; True (default) looks it up on PATH; False or None
        writes the DOT sources only.

    Returns
    -------
    ArchitectureReport

    Raises
    ------
    OutputError
        If a file cannot be written.
    """
    out = Path(out_dir)
    ensure_dir(out)
    rep = ArchitectureReport(out)
    dot_exe = shutil.which("dot") if dot is True else (dot or None)

    def put(name: str, text: str) -> None:
        write_text(out / name, text)
        rep.files.append(name)

    confs = list(arch.configurations)
    cslug = unique_slugs(confs)
    scopes: list[tuple[str | None, str]] = [(None, "architecture")]
    scopes += [(c, f"config-{cslug[c]}") for c in confs]

    dsm_rows = []
    graphs = []
    for conf, stem in scopes:
        dsm = build_dsm(arch, conf)
        views = [(o, o.rows(dsm)) for o in orderings(dsm)]
        put(f"dsm-{stem}.html", render("dsm.html.j2", dsm=dsm, views=views))
        put(f"dsm-{stem}.md", render("dsm.md.j2", dsm=dsm, views=views))
        csvs = []
        for o, rows in views:
            name = f"dsm-{stem}.{o.key}.csv"
            put(name, render("dsm.csv.j2", ordering=o, rows=rows))
            csvs.append((o.title, name))
        seq = views[1][0]
        dsm_rows.append({
            "scope": "whole architecture" if conf is None else conf,
            "description": dsm.description,
            "modules": len(dsm.modules),
            "edges": len(dsm.weights),
            "coupled": [b.members for b in seq.blocks if b.coupled],
            "feedback": seq.feedback_marks(dsm),
            "html": f"dsm-{stem}.html",
            "md": f"dsm-{stem}.md",
            "csv": csvs,
        })
        g = build_graph(arch, conf)
        put(f"graph-{stem}.dot", render("graph.dot.j2", graph=g))
        graphs.append({"scope": "whole architecture" if conf is None else conf,
                       "subtitle": g.subtitle, "stem": f"graph-{stem}",
                       "nodes": len(g.nodes), "edges": len(g.edges)})

    diffs = []
    for a, b in diff_pairs(arch):
        d = config_diff(arch, a, b)
        stem = f"diff-{cslug[a]}--{cslug[b]}"
        put(f"{stem}.dot", render("graph.dot.j2", graph=diff_graph(arch, d)))
        diffs.append({"diff": d, "stem": stem})

    failures: list[str] = []
    if dot_exe:
        for name in [f for f in rep.files if f.endswith(".dot")]:
            for fmt in ("svg", "png"):
                data, err = render_dot(out / name, fmt, dot_exe)
                if data is None:
                    failures.append(f"{name} → {fmt}: {err}")
                    continue
                target = name[:-4] + "." + fmt
                write_bytes(out / target, data)
                rep.files.append(target)
        rep.rendered = not failures
        if failures:
            rep.note = "Graphviz failed on some files: " + "; ".join(failures)
    else:
        rep.note = ("Graphviz `dot` was not found on PATH: only the DOT sources were written. "
                    "Install Graphviz and re-run, or render one with `dot -Tsvg FILE.dot -o "
                    "FILE.svg`.")
    images = {f for f in rep.files if f.endswith((".svg", ".png"))}

    put("index.html", render(
        "report_index.html.j2",
        arch=arch,
        kinds=[(k, KIND_TITLES[k], sum(1 for m in arch.modules.values() if m.kind == k))
               for k in KINDS],
        dsms=dsm_rows,
        graphs=graphs,
        diffs=diffs,
        images=images,
        note=rep.note,
        actions=[a for a in arch.actions],
    ))
    return rep
