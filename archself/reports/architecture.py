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

The report is written into a temporary folder beside ``out_dir`` and swapped in
when complete (one ``renameat2(RENAME_EXCHANGE)`` on Linux, two renames
elsewhere): an interrupted or failed report leaves the old folder as it was, and
a new report never keeps stale files of an old one. An existing folder that is
not empty is replaced only with ``force`` and only if it holds a report (an
``index.html``).
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from archself.errors import OutputError
from archself.io.files import write_bytes, write_text
from archself.model.architecture import Architecture
from archself.reports.dsm import KIND_TITLES, KINDS, build_dsm, condense, orderings
from archself.reports.graph import build_graph, config_diff, diff_graph, diff_pairs
from archself.reports.render import render, unique_slugs

__all__ = [
    "MAX_FILES",
    "ArchitectureReport",
    "count_report_files",
    "render_dot",
    "swap_in",
    "write_architecture_report",
]

#: ``archself report`` refuses to write more files than this without ``--yes``.
MAX_FILES = 2000


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


@contextmanager
def new_folder(path: Path) -> Iterator[Path]:
    """:func:`ensure_dir` for the block; if the block fails, remove the folders it made.

    A report that fails half-way (a full disk, Ctrl-C) into a folder that did not
    exist leaves no folder behind, empty or half-written; an existing folder is
    left as the failure left it (each file written atomically).

    Examples
    --------
    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> try:
    ...     with new_folder(d / "a" / "report") as out:
    ...         _ = (out / "index.html").write_text("half")
    ...         raise OutputError("disk full")
    ... except OutputError:
    ...     pass
    >>> list(d.iterdir())
    []
    """
    made = None
    p = path
    while not os.path.lexists(p) and p != p.parent:
        made, p = p, p.parent  # the outermost folder that does not exist yet
    ensure_dir(path)
    try:
        yield path
    except BaseException:
        if made is not None:
            shutil.rmtree(made, ignore_errors=True)
        raise


#: architectures with more modules get DOT sources only (no Graphviz layout)
LAYOUT_MAX = 500


def render_dot(dot_file: Path, fmt: str, dot: str, *args: str) -> tuple[bytes | None, str]:
    """Run ``dot -T<fmt> ARGS`` on ``dot_file``; ``(output, "")`` or ``(None, error text)``."""
    try:
        proc = subprocess.run([dot, f"-T{fmt}", *args, str(dot_file)], capture_output=True,
                              timeout=120, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return None, f"{type(exc).__name__}: {exc}"
    if proc.returncode != 0:
        lines = proc.stderr.decode("utf-8", "replace").strip().splitlines()
        return None, lines[-1] if lines else f"dot exited with {proc.returncode}"
    return proc.stdout, ""


#: Margin kept around what a cropped drawing shows (points).
CROP_MARGIN = 8.0


def visible_viewport(dot_file: Path, dot: str) -> str | None:
    """A Graphviz ``viewport`` that crops a drawing to what it shows, or None.

    A configuration's graph keeps the whole architecture's positions (its inactive modules
    and edges are drawn invisible, so drawings and diffs line up); where the invisible part
    lies at an edge of the drawing it leaves an empty band. The box of the visible
    elements (``dot -Tjson``: every node, cluster and edge not ``invis``, and the graph's
    label) plus :data:`CROP_MARGIN` is the viewport, when it is at least 5 % smaller
    than the drawing in one direction; positions inside it are unchanged.
    """
    data, _err = render_dot(dot_file, "json", dot)
    if data is None:
        return None
    j = json.loads(data)
    xs: list[float] = []
    ys: list[float] = []

    def take(el: dict[str, Any]) -> None:
        if "invis" in str(el.get("style", "")):
            return
        for key in ("_draw_", "_ldraw_", "_hdraw_", "_tdraw_", "_hldraw_", "_tldraw_"):
            for op in el.get(key, ()):
                if "points" in op:
                    xs.extend(x for x, _ in op["points"])
                    ys.extend(y for _, y in op["points"])
                elif "rect" in op:
                    cx, cy, rx, ry = op["rect"]
                    xs.extend((cx - rx, cx + rx))
                    ys.extend((cy - ry, cy + ry))
                elif "pt" in op:
                    (x, y), w = op["pt"], float(op.get("width", 0.0))
                    lo = {"l": x, "r": x - w}.get(op.get("align", "c"), x - w / 2)
                    xs.extend((lo, lo + w))
                    ys.extend((y - 0.3 * op.get("size", 14.0), y + op.get("size", 14.0)))

    take({"_ldraw_": j.get("_ldraw_", ())})
    for el in (*j.get("objects", ()), *j.get("edges", ())):
        take(el)
    x0, y0, x1, y1 = (float(v) for v in j["bb"].split(","))
    if not xs:
        return None
    lo_x, hi_x = max(x0, min(xs) - CROP_MARGIN), min(x1, max(xs) + CROP_MARGIN)
    lo_y, hi_y = max(y0, min(ys) - CROP_MARGIN), min(y1, max(ys) + CROP_MARGIN)
    w, h = hi_x - lo_x, hi_y - lo_y
    if w > 0.95 * (x1 - x0) and h > 0.95 * (y1 - y0):
        return None
    return f"{w:.2f},{h:.2f},1,{(lo_x + hi_x) / 2:.2f},{(lo_y + hi_y) / 2:.2f}"


def count_report_files(arch: Architecture, rendered: bool) -> int:
    """How many files the report of ``arch`` has (the estimate shown before writing)."""
    scopes = 1 + len(arch.configurations)
    per_dot = 3 if rendered else 1
    return scopes * (5 + per_dot) + len(diff_pairs(arch)) * per_dot + 1


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False if unsupported."""
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    rc = fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (38, 22, 95):  # ENOSYS, EINVAL, EOPNOTSUPP: the file system cannot; fall back
        return False
    raise OSError(err, os.strerror(err), str(b))


def swap_in(new: Path, out: Path) -> None:
    """Put the folder ``new`` at ``out``, replacing a folder there, then delete the old one."""
    try:
        if not out.exists():
            os.rename(new, out)
            return
        if _exchange(new, out):
            shutil.rmtree(new, ignore_errors=True)  # ``new`` now holds the old report
            return
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
        os.rename(out, old / "report")
        os.rename(new, out)
        shutil.rmtree(old, ignore_errors=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot replace the folder: {exc.strerror or exc}") from None


def _prepare(out: Path, force: bool, shown: Path) -> Path:
    """Check ``out`` and name the temporary folder the report is written into.

    The folder is named here and made by the caller inside its clean-up block: a signal
    between making it and entering that block would leave it behind (seen under load).
    """
    if out.exists() and not out.is_dir():
        raise OutputError(f"{shown}: not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise OutputError(
                f"{shown}: error: exists and is not empty; pass --force to replace the report in it"
            )
        if not (out / "index.html").is_file():
            raise OutputError(
                f"{shown}: error: holds files that are not an archself report (no index.html); "
                "even --force does not replace it: choose another folder"
            )
    parent = out.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{shown}: cannot create folder: {exc.strerror or exc}") from None
    return parent / f".{out.name}.{secrets.token_hex(8)}.tmp"


def write_architecture_report(
    arch: Architecture,
    out_dir: str | Path,
    *,
    dot: str | None | bool = True,
    force: bool = False,
) -> ArchitectureReport:
    """Write the architecture report of ``arch`` into ``out_dir`` (created if missing).

    The files are written into a temporary folder beside ``out_dir``, which is
    swapped in at the end (see the module's documentation).

    Parameters
    ----------
    arch : Architecture
    out_dir : path
    dot : str, bool or None
        Path of Graphviz ``dot``; True (default) looks it up on PATH; False or None
        writes the DOT sources only.
    force : bool
        Replace an existing, non-empty report folder.

    Returns
    -------
    ArchitectureReport

    Raises
    ------
    OutputError
        If a file cannot be written, or ``out_dir`` is not empty (without ``force``).
    """
    final = Path(os.path.abspath(out_dir))
    tmp = _prepare(final, force, Path(out_dir))
    ours: Path | None = tmp  # what the clean-up may delete
    try:
        try:
            tmp.mkdir()  # mode 0777 less the umask, like any new folder
        except OSError as exc:
            if isinstance(exc, FileExistsError):
                ours = None  # someone else's
            raise OutputError(f"{out_dir}: cannot write: {exc.strerror or exc}") from None
        rep = _write(arch, tmp, dot)
        swap_in(tmp, final)
    except BaseException:
        if ours is not None:
            shutil.rmtree(ours, ignore_errors=True)
        raise
    rep.out_dir = Path(out_dir)
    return rep


def _write(arch: Architecture, out: Path, dot: str | None | bool) -> ArchitectureReport:
    """Every file of the report into ``out``: the DSMs and graphs of the architecture and
    of each configuration, the configurations' diffs, the graphs rendered, the index."""
    rep = ArchitectureReport(out)
    dot_exe = shutil.which("dot") if dot is True else (dot or None)

    def put(name: str, text: str) -> None:
        write_text(out / name, text)
        rep.files.append(name)

    cslug = unique_slugs(list(arch.configurations))
    dsm_rows, graphs = _scopes(arch, cslug, put)
    diffs = []
    for a, b in diff_pairs(arch):
        d = config_diff(arch, a, b)
        stem = f"diff-{cslug[a]}--{cslug[b]}"
        put(f"{stem}.dot", render("graph.dot.j2", graph=diff_graph(arch, d)))
        diffs.append({"diff": d, "stem": stem})
    _render_graphs(rep, out, dot_exe, len(arch.modules))
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
        actions=arch.actions,
    ))
    return rep


def _scopes(
    arch: Architecture, cslug: dict[str, str], put: Callable[[str, str], None]
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The DSM (HTML, Markdown, a CSV per ordering) and the graph (DOT) of the whole
    architecture and of each configuration; their rows in the index."""
    scopes: list[tuple[str | None, str]] = [(None, "architecture")]
    scopes += [(c, f"config-{cslug[c]}") for c in arch.configurations]
    dsm_rows = []
    graphs = []
    for conf, stem in scopes:
        dsm = condense(build_dsm(arch, conf))
        views = [(o, o.rows(dsm)) for o in orderings(dsm)]
        put(f"dsm-{stem}.html", render("dsm.html.j2", dsm=dsm, views=views))
        put(f"dsm-{stem}.md", render("dsm.md.j2", dsm=dsm, views=views))
        csvs = []
        for o, rows in views:
            name = f"dsm-{stem}.{o.key}.csv"
            put(name, render("dsm.csv.j2", ordering=o, rows=rows))
            csvs.append((o.title, name))
        seq = views[1][0]
        scope = "whole architecture" if conf is None else conf
        dsm_rows.append({
            "scope": scope,
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
        graphs.append({"scope": scope, "subtitle": g.subtitle, "stem": f"graph-{stem}",
                       "nodes": sum(n.status != "hidden" for n in g.nodes),
                       "edges": sum(e.status != "hidden" for e in g.edges)})
    return dsm_rows, graphs


def _render_graphs(rep: ArchitectureReport, out: Path, dot_exe: str | None, n: int) -> None:
    """Every DOT file of ``rep`` as SVG and PNG with Graphviz, or the note why not.

    An architecture of more than :data:`LAYOUT_MAX` modules is not laid out (``dot``
    takes minutes to hours there, and the drawing is unreadable): its DOT sources are
    written and the note says so.
    """
    failures: list[str] = []
    if dot_exe and n > LAYOUT_MAX:
        rep.note = (f"{n} modules: Graphviz layout is skipped past {LAYOUT_MAX} modules; only "
                    "the DOT sources were written (render one with `sfdp -Tsvg FILE.dot -o "
                    "FILE.svg` if you need it).")
    elif dot_exe:
        for name in [f for f in rep.files if f.endswith(".dot")]:
            view = (visible_viewport(out / name, dot_exe) if name.startswith("graph-config-")
                    else None)
            args = (f"-Gviewport={view}",) if view else ()
            for fmt in ("svg", "png"):
                data, err = render_dot(out / name, fmt, dot_exe, *args)
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
