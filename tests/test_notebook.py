"""docs/notebook.ipynb: shipped without outputs, runs as written (nbclient), stays small.

The notebook goes from loading a file to a figure and a campaign table, each code cell at
most six lines; executed, it is under 100 KB, and the PDFs it saves embed no Type 3 font
(``pdffonts``, from poppler-utils; that check is skipped, saying so, where it is missing).
"""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest

from conftest import ROOT

nbformat = pytest.importorskip("nbformat", reason="nbformat is in the test extra")
nbclient = pytest.importorskip("nbclient", reason="nbclient is in the test extra")

NOTEBOOK = ROOT / "docs" / "notebook.ipynb"
MAX_BYTES = 100_000
MAX_LINES = 6


def _code(nb) -> list:
    return [c for c in nb.cells if c.cell_type == "code"]


def test_shipped_notebook_has_no_outputs_and_short_cells() -> None:
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    cells = _code(nb)
    assert len(cells) >= 3
    assert all(c.outputs == [] and c.execution_count is None for c in cells)
    lines = [len(c.source.strip().splitlines()) for c in cells]
    assert max(lines) <= MAX_LINES, lines


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    """The notebook run from a ``docs/`` folder beside the checkout's architectures."""
    root = tmp_path_factory.mktemp("nb")
    (root / "architectures").symlink_to(ROOT / "architectures", target_is_directory=True)
    docs = root / "docs"
    docs.mkdir()
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(docs)}})
    # the kernel is this interpreter (its venv has archself), whatever kernels are installed
    client.kernel_manager_class = nbclient.client.KernelManager
    client.kernel_manager_kwargs = {"kernel_cmd": [sys.executable, "-m", "ipykernel_launcher",
                                                    "-f", "{connection_file}"]}
    client.execute()
    return nb, docs


def test_notebook_runs_to_a_figure_and_a_campaign_table(executed) -> None:
    nb, docs = executed
    outputs = [o for c in _code(nb) for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    html = [o.data["text/html"] for o in outputs if "text/html" in o.get("data", {})]
    # the run's card, the campaign table (pandas) and the campaign's card
    assert any("archself-run" in h and "a1 → a3" in h for h in html)
    assert any("actuator_fault" in h and "adaptive" in h and "fixed" in h for h in html)
    assert any("campaign" in h and "4 in the file" in h for h in html)
    assert any("image/png" in o.get("data", {}) for o in outputs)
    for name in ("error.pdf", "max_error.pdf", "results.parquet"):
        assert (docs / name).stat().st_size > 1000, name


def test_executed_notebook_is_small(executed) -> None:
    nb, _ = executed
    size = len(nbformat.writes(nb).encode("utf-8"))
    assert 5_000 < size < MAX_BYTES, size


def test_saved_pdfs_have_no_type3_font(executed) -> None:
    _, docs = executed
    exe = shutil.which("pdffonts")
    if exe is None:
        pytest.skip("pdffonts is not installed (apt-get install poppler-utils)")
    for name in ("error.pdf", "max_error.pdf"):
        out = subprocess.run([exe, str(docs / name)], capture_output=True, text=True,
                             check=True).stdout
        fonts = out.splitlines()[2:]
        assert fonts, (name, out)  # text is embedded as fonts, not drawn as paths
        assert all("TrueType" in f and "Type 3" not in f for f in fonts), (name, out)
