"""Reports: quoting filters, the DSM and graph models, golden DSM/DOT, escaping, CLI."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from archself.cli import app
from archself.model.loader import load_architecture
from archself.reports.architecture import write_architecture_report
from archself.reports.dsm import build_dsm, cluster, orderings, sequence
from archself.reports.graph import config_diff, diff_pairs
from archself.reports.render import csv_field, dot_label, dot_quote, md_cell, slug, unique_slugs

from conftest import DIFFDRIVE, FIXTURES, ROOT, compare_golden

MINIMAL = FIXTURES / "valid" / "minimal.yaml"
HOSTILE = FIXTURES / "valid" / "hostile_names.yaml"
GOLDEN = ROOT / "tests" / "golden"
DOT = shutil.which("dot")
needs_dot = pytest.mark.skipif(DOT is None, reason="Graphviz `dot` is not installed")
runner = CliRunner()


@pytest.fixture(scope="module")
def diffdrive():
    return load_architecture(DIFFDRIVE).arch


@pytest.fixture(scope="module")
def hostile():
    return load_architecture(HOSTILE).arch


@pytest.fixture(scope="module")
def hostile_report(tmp_path_factory, hostile):
    out = tmp_path_factory.mktemp("hostile-report")
    write_architecture_report(hostile, out, dot=True)
    return out


# --------------------------------------------------------------------------- filters
@pytest.mark.parametrize(
    ("value", "expected"),
    [
        ("plain", '"plain"'),
        ('say "hi"', '"say \\"hi\\""'),
        ("back\\slash", '"back\\\\slash"'),
        ('end\\"', '"end\\\\\\""'),  # a backslash before a quote cannot un-escape it
        ("two\nlines", '"two\\nlines"'),
        ("cr\r\nlf", '"cr\\nlf"'),
        ("bell\x07x", '"bellx"'),
        ("<script>&", '"<script>&"'),
        ("caméra", '"caméra"'),
        ("", '""'),
    ],
)
def test_dot_quote(value: str, expected: str) -> None:
    assert dot_quote(value) == expected


def test_dot_quote_never_ends_the_string_early() -> None:
    for value in ['"', '\\', '\\"', '"\\', 'a"; evil=1 "', "x\\\n"]:
        q = dot_quote(value)
        body = q[1:-1]
        # every quote inside is escaped by an odd run of backslashes
        for m in re.finditer(r'(\\*)"', body):
            assert len(m.group(1)) % 2 == 1, (value, q)
        assert not re.search(r'(?<!\\)(\\\\)*\\$', body), (value, q)


def test_dot_label_escapes_entities() -> None:
    assert dot_label("a & b") == '"a &amp; b"'
    assert dot_label("&lt;") == '"&amp;lt;"'


def test_md_cell() -> None:
    assert md_cell("a|b") == "a\\|b"
    assert md_cell("<script>&") == "&lt;script&gt;&amp;"
    assert md_cell("wheel_left *x*") == "wheel\\_left \\*x\\*"
    assert md_cell("two\nlines") == "two lines"


def test_csv_field() -> None:
    assert csv_field("plain") == "plain"
    assert csv_field('a,"b"') == '"a,""b"""'
    assert csv_field("=cmd()") == "'=cmd()"
    assert csv_field("-x") == "'-x"
    assert csv_field(0.25) == "0.25"
    assert csv_field(0) == "0"


def test_slugs() -> None:
    assert slug('fusion "GPS" & <i>') == "fusion-GPS-i"
    assert slug("contrôle") == "controle"
    assert slug("../../etc") == "etc"
    assert unique_slugs(["a b", "a-b", "A_b"]) == {"a b": "a-b", "a-b": "a-b-2", "A_b": "A_b"}


# --------------------------------------------------------------------------- models
def test_dsm_convention_row_influences_column(diffdrive) -> None:
    dsm = build_dsm(diffdrive)
    assert dsm.weight("imu", "odometry") == 0.6  # edge imu -> odometry: row imu, column odometry
    assert dsm.weight("odometry", "imu") == 0.0
    kind, seq, _ = orderings(dsm)
    rows = {m.name: cells for m, _b, cells in seq.rows(dsm)}
    cell = next(c for c in rows["imu"] if c.col == "odometry")
    assert cell.weight == 0.6 and cell.carries == ("heading",)


def test_dsm_of_configuration_drops_inactive_and_disabled(diffdrive, hostile) -> None:
    dsm = build_dsm(diffdrive, "a1")
    assert "ekf" not in dsm.names and len(dsm.names) == 12
    conf = 'fusion "GPS" & <i>'
    assert build_dsm(hostile, conf).weight("encoders", "left") == 0.0  # disabled edge
    assert build_dsm(hostile, "base").weight("encoders", "left") == 0.2


@pytest.mark.parametrize("conf", [None, "a1", "a2", "a3"])
def test_orderings_are_permutations_and_feedback_stays_in_coupled_blocks(diffdrive, conf) -> None:
    dsm = build_dsm(diffdrive, conf)
    for o in orderings(dsm):
        assert sorted(o.order) == sorted(dsm.names)
        assert sorted(n for b in o.blocks for n in b.members) == sorted(dsm.names)
    seq = sequence(dsm)
    where = seq.block_of()
    pos = {n: k for k, n in enumerate(seq.order)}
    for (s, t) in dsm.weights:
        if pos[s] > pos[t]:  # feedback mark
            assert where[s] == where[t] and seq.blocks[where[s]].coupled
    assert seq.feedback_marks(dsm) <= orderings(dsm)[0].feedback_marks(dsm)



@pytest.mark.parametrize("conf", [None, "a1", "a2", "a3"])
def test_only_strongly_connected_pairs_are_marked_coupled(diffdrive, conf) -> None:
    """The coupled shading means "in one strongly connected component", in every view."""
    import networkx as nx

    dsm = build_dsm(diffdrive, conf)
    scc = {n: k for k, c in enumerate(nx.strongly_connected_components(dsm.digraph()))
           for n in c}
    size = {k: sum(1 for v in scc.values() if v == k) for k in set(scc.values())}
    for o in orderings(dsm):
        for module, block, cells in o.rows(dsm):
            in_scc = size[scc[module.name]] > 1
            assert bool(o.coupled_block(module.name)) == in_scc
            assert not block.coupled or set(block.members) <= {
                n for n in dsm.names if scc[n] == scc[module.name]}
            for c in cells:
                assert c.coupled == (in_scc and scc[c.row] == scc[c.col]), (o.key, c)
    clustered = cluster(dsm)
    loose = [n for n in dsm.names if size[scc[n]] == 1]
    assert loose and not any(b.coupled for b in clustered.blocks)
    if conf == "a1":  # a cluster mixes loose and coupled modules; the loose are not shaded
        assert any(set(b.members) & set(loose) and set(b.members) - set(loose)
                   for b in clustered.blocks)

def test_clustering_is_deterministic(diffdrive) -> None:
    dsm = build_dsm(diffdrive)
    assert cluster(dsm) == cluster(dsm)


def test_diff_pairs_and_diff(diffdrive) -> None:
    pairs = diff_pairs(diffdrive)
    assert pairs[:2] == [("a1", "a2"), ("a1", "a3")] and ("a2", "a3") in pairs
    for a, b in pairs:  # every pair is a move some structural action makes
        assert any(act.to == b and (act.applies_in is None or a in act.applies_in)
                   for act in diffdrive.actions)
    d = config_diff(diffdrive, "a2", "a3")
    assert d.added_modules == ("asym_lqr",) and d.removed_modules == ("lqr_fused",)
    assert ("ekf", "asym_lqr", "pose_estimate") in d.added_edges
    assert ("ekf", "lqr_fused", "pose_estimate") in d.removed_edges
    assert d.actions[:2] == ("compensate_left_wheel", "compensate_right_wheel")


def test_diff_pairs_fall_back_to_consecutive(hostile) -> None:
    arch = hostile.model_copy(update={"actions": []})
    assert diff_pairs(arch) == [("base", 'fusion "GPS" & <i>')]


# --------------------------------------------------------------------------- golden
GOLDEN_FILES = {
    "minimal": ["dsm-architecture.md", "dsm-architecture.sequenced.csv",
                "dsm-architecture.clustered.csv", "graph-architecture.dot"],
    "hostile": ["dsm-architecture.md", "dsm-architecture.kind.csv", "graph-architecture.dot",
                "diff-base--fusion-GPS-i.dot"],
}


@pytest.mark.parametrize(("fixture", "name"),
                         [(f, n) for f, names in GOLDEN_FILES.items() for n in names])
def test_golden_dsm_and_dot(tmp_path, regen, fixture, name) -> None:
    arch = load_architecture(MINIMAL if fixture == "minimal" else HOSTILE).arch
    write_architecture_report(arch, tmp_path, dot=False)
    (GOLDEN / fixture).mkdir(parents=True, exist_ok=True)
    compare_golden(GOLDEN / fixture / name, (tmp_path / name).read_text(encoding="utf-8"), regen)


# --------------------------------------------------------------------------- escaping
HOSTILE_NAMES = ['caméra "avant" <script>alert(1)</script> &', 'GPS & <b>bold</b>',
                 'Körper "base"', "ekf \\ back\\slash", "dead reckoning $5", "modèle {x}|y"]


def _html_files(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.html"))


def test_html_escapes_hostile_names(hostile_report) -> None:
    pages = _html_files(hostile_report)
    assert {p.name for p in pages} >= {"index.html", "dsm-architecture.html",
                                       "dsm-config-base.html", "dsm-config-fusion-GPS-i.html"}
    for page in pages:
        html = page.read_text(encoding="utf-8")
        assert "<script" not in html.lower(), page.name
        assert "<b>bold" not in html and "<img src=x" not in html and "<i>" not in html
        assert "&lt;script&gt;alert(1)&lt;/script&gt;" in html, page.name
    dsm = (hostile_report / "dsm-architecture.html").read_text(encoding="utf-8")
    assert "caméra &#34;avant&#34; &lt;script&gt;alert(1)&lt;/script&gt; &amp;" in dsm
    assert "Körper &#34;base&#34;" in dsm
    # tooltips: attribute values stay inside their quotes
    for title in re.findall(r'title="([^"]*)"', dsm):
        assert "<" not in title and ">" not in title


def test_markdown_and_csv_escape_hostile_names(hostile_report) -> None:
    md = (hostile_report / "dsm-architecture.md").read_text(encoding="utf-8")
    assert "<script" not in md and "<b>" not in md
    assert "modèle {x}\\|y" in md
    import csv

    with open(hostile_report / "dsm-architecture.kind.csv", encoding="utf-8", newline="") as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    for name in HOSTILE_NAMES:
        assert name in header
    assert all(len(r) == len(header) for r in rows)


def test_dot_files_keep_hostile_names_in_their_strings(hostile_report) -> None:
    text = (hostile_report / "graph-architecture.dot").read_text(encoding="utf-8")
    assert '"caméra \\"avant\\" <script>alert(1)</script> &"' in text
    assert '"ekf \\\\ back\\\\slash"' in text


def test_dot_attribute_lists_name_each_attribute_once(hostile_report) -> None:
    """A diff restyles nodes and edges by replacing attributes, never by repeating them."""
    files = sorted(hostile_report.glob("*.dot"))
    assert any(f.name.startswith("diff-") for f in files)
    for f in files:
        for line in f.read_text(encoding="utf-8").splitlines():
            bare = re.sub(r'"(?:[^"\\]|\\.)*"', '""', line)  # quoted strings out of the way
            for attrs in re.findall(r"\[([^\]]*)\]", bare):
                names = re.findall(r"(\w+)\s*=", attrs)
                assert len(names) == len(set(names)), f"{f.name}: {line}"


@needs_dot
def test_dot_parses_every_generated_file_and_names_round_trip(hostile_report, hostile) -> None:
    # Graphviz keeps ``\\`` literally in ids (only labels are escStrings), so an id with a
    # backslash comes back doubled; labels show it once (checked in the SVG below).
    ids = {n.replace("\\", "\\\\") for n in hostile.modules}
    dots = sorted(hostile_report.glob("*.dot"))
    assert len(dots) == 4
    for f in dots:
        proc = subprocess.run([DOT, "-Tjson", str(f)], capture_output=True, text=True)
        assert proc.returncode == 0 and not proc.stderr.strip(), (f.name, proc.stderr)
        doc = json.loads(proc.stdout)
        names = {o["name"] for o in doc.get("objects", []) if "nodes" not in o}
        assert names <= ids, f.name
    doc = json.loads(subprocess.run([DOT, "-Tjson", str(hostile_report / "graph-architecture.dot")],
                                    capture_output=True, text=True).stdout)
    names = {o["name"] for o in doc["objects"] if "nodes" not in o}
    assert names == ids
    assert len(doc["edges"]) == len(hostile.edges)
    labels = {o["label"] for o in doc["objects"] if "nodes" not in o}
    assert "ekf \\\\ back\\\\slash\\nestimator.ekf" in labels  # escString, shown as one \
    for f in ("graph-architecture.svg", "graph-architecture.png", "diff-base--fusion-GPS-i.svg"):
        assert (hostile_report / f).stat().st_size > 1000
    svg = (hostile_report / "graph-architecture.svg").read_text(encoding="utf-8")
    assert "<script" not in svg
    assert ">ekf \\ back\\slash</text>" in svg
    assert ">caméra &quot;avant&quot; &lt;script&gt;alert(1)&lt;/script&gt; &amp;</text>" in svg


@needs_dot
def test_dot_parses_the_diffdrive_report(tmp_path, diffdrive) -> None:
    rep = write_architecture_report(diffdrive, tmp_path, dot=False)
    assert not rep.rendered and rep.note
    for f in sorted(tmp_path.glob("*.dot")):
        proc = subprocess.run([DOT, "-Tcanon", str(f)], capture_output=True, text=True)
        assert proc.returncode == 0 and not proc.stderr.strip(), (f.name, proc.stderr)


def test_local_links_resolve(hostile_report) -> None:
    for page in _html_files(hostile_report):
        html = page.read_text(encoding="utf-8")
        for ref in re.findall(r'(?:href|src)="([^"#:]+)"', html):
            assert (hostile_report / ref).is_file(), (page.name, ref)


# --------------------------------------------------------------------------- CLI
def test_cli_report(tmp_path) -> None:
    out = tmp_path / "deep" / "rep"
    res = runner.invoke(app, ["report", str(MINIMAL), "-o", str(out), "--no-render"])
    assert res.exit_code == 0, res.output
    assert res.stdout.strip() == str(out / "index.html")
    assert not list(out.glob("*.svg"))
    index = (out / "index.html").read_text(encoding="utf-8")
    assert "dsm-config-only.html" in index and "graph-config-only.dot" in index


def test_cli_report_notes_missing_dot(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))  # no dot here
    res = runner.invoke(app, ["report", str(MINIMAL), "-o", str(tmp_path / "r")])
    assert res.exit_code == 0
    assert "note: Graphviz `dot` was not found" in res.stderr
    assert "only the DOT sources were written" in (tmp_path / "r" / "index.html").read_text()


def test_cli_report_errors_are_one_line(tmp_path) -> None:
    res = runner.invoke(app, ["report", str(tmp_path / "nope.yaml"), "-o", str(tmp_path)])
    assert res.exit_code == 1 and len(res.stderr.strip().splitlines()) == 1
    (tmp_path / "file").write_text("x")
    res = runner.invoke(app, ["report", str(MINIMAL), "-o", str(tmp_path / "file" / "sub")])
    assert res.exit_code == 1 and "cannot create folder" in res.stderr
    res = runner.invoke(app, ["report", "--help"])
    assert res.exit_code == 0 and "DSM" in res.stdout


def test_report_modules_do_not_import_matplotlib_at_start_up() -> None:
    code = ("import sys; from archself.cli import app;"
            "import archself.reports.architecture, archself.reports.run_report;"
            "assert 'matplotlib' not in sys.modules, 'matplotlib imported'")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize(
    "payload",
    [
        "{{ ''.__class__.__mro__[1].__subclasses__() }}",
        "{{ ''.__class__ }}",
        "{{ cycler.__init__.__globals__ }}",
    ],
)
def test_templates_render_in_a_sandbox(payload: str) -> None:
    """Issue 7 item 5: a template cannot reach Python internals through attributes."""
    from jinja2.exceptions import SecurityError
    from jinja2.sandbox import SandboxedEnvironment

    from archself.reports.render import environment

    env = environment()
    assert isinstance(env, SandboxedEnvironment)
    template = env.from_string(payload)
    with pytest.raises(SecurityError):
        template.render()


def test_a_large_architecture_is_reported_between_its_communities(tmp_path) -> None:
    """400 modules: the DSMs hold at most FULL_MATRIX_MAX clusters, every module in one."""
    from archself.model.generate import generate_architecture
    from archself.model.loader import load_text
    from archself.reports.dsm import FULL_MATRIX_MAX, condense

    arch = load_text(generate_architecture(400, seed=3, feedback=4), "big.yaml").arch
    dsm = build_dsm(arch)
    small = condense(dsm)
    assert 1 < len(small.modules) <= FULL_MATRIX_MAX
    sizes = [int(m.type.split()[0]) for m in small.modules]
    assert sum(sizes) == 400
    between = sum(w for (s, t), w in dsm.weights.items())
    inside = sum(float(m.description.rsplit("weight inside ", 1)[1]) for m in small.modules)
    assert sum(small.weights.values()) + inside == pytest.approx(between, rel=1e-9)
    diffdrive = build_dsm(load_architecture(DIFFDRIVE).arch)
    assert condense(diffdrive) is diffdrive  # small files keep their full matrix
    rep = write_architecture_report(arch, tmp_path / "big", dot=False)
    html = (tmp_path / "big" / "dsm-architecture.html").read_text()
    assert "400 modules condensed into" in html and "cluster 1" in html
    rows = (tmp_path / "big" / "dsm-architecture.kind.csv").read_text().splitlines()
    assert len(rows) == len(small.modules) + 1 and rep.files


def test_condense_keeps_every_module_of_unconnected_graphs() -> None:
    """300 modules without edges: 300 communities at any resolution; none is dropped."""
    from archself.reports.dsm import Dsm, DsmModule, condense

    mods = tuple(DsmModule(f"m{k}", "functional", "t") for k in range(300))
    small = condense(Dsm("architecture", "loose", mods, {}, {}, 0.0), max_modules=20)
    assert len(small.modules) == 20
    assert sum(int(m.type.split()[0]) for m in small.modules) == 300


@pytest.mark.skipif(shutil.which("dot") is None, reason="Graphviz `dot` is not installed")
def test_configuration_graph_is_cropped_to_what_it_shows(tmp_path):
    """a1's graph keeps the whole architecture's positions but not its empty band: the
    drawing is cropped to its visible modules, edges and title (issue 40), and every module
    of a1 lies inside the crop."""
    from archself.reports.architecture import visible_viewport

    dot = shutil.which("dot")
    arch = load_architecture(DIFFDRIVE).arch
    write_architecture_report(arch, tmp_path / "r", dot=True)
    out = tmp_path / "r"

    def height(name: str) -> float:
        m = re.search(r'<svg width="[\d.]+pt" height="([\d.]+)pt"',
                      (out / name).read_text(encoding="utf-8"))
        assert m, name
        return float(m.group(1))

    whole, a1 = height("graph-architecture.svg"), height("graph-config-a1.svg")
    assert a1 < 0.9 * whole
    view = visible_viewport(out / "graph-config-a1.dot", dot)
    assert view is not None
    w, h, zoom, cx, cy = (float(v) for v in view.split(","))
    assert zoom == 1.0 and abs(h - a1) <= 1.0
    layout = json.loads(subprocess.run([dot, "-Tjson", str(out / "graph-config-a1.dot")],
                                       capture_output=True, text=True, check=True).stdout)
    active = set(arch.configurations["a1"].modules)
    seen = 0
    for obj in layout["objects"]:
        if obj.get("name") in active:
            x, y = (float(v) for v in obj["pos"].split(","))
            assert abs(x - cx) <= w / 2 and abs(y - cy) <= h / 2, obj["name"]
            seen += 1
    assert seen == len(active)
    # the architecture's own graph is not cropped (nothing in it is invisible)
    assert visible_viewport(out / "graph-architecture.dot", dot) is None
