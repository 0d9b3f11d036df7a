"""The report pages render in headless Chromium without console errors (screenshots kept).

Skipped when /usr/bin/chromium is absent (CI installs it: see .ci/run).
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from archself.cli import app

from conftest import FIXTURES, ROOT

CHROMIUM = Path("/usr/bin/chromium")
pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason="chromium is not installed")
HOSTILE = FIXTURES / "valid" / "hostile_names.yaml"
BAD = ("CONSOLE", "Uncaught", "Refused to", "Content Security Policy")


@pytest.fixture(scope="module")
def pages(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("pages")
    runner = CliRunner()
    res = runner.invoke(app, ["report", str(HOSTILE), "-o", str(root / "arch")])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["simulate", str(HOSTILE), "-s", "drift <script>", "--compare",
                              "--report", str(root / "run")])
    assert res.exit_code == 0, res.output
    results = ROOT / "docs" / "campaign" / "campaign.parquet"
    res = runner.invoke(app, ["campaign-report", str(results), "-o", str(root / "campaign"),
                              "--expect", "imu_drift=a2"])
    assert res.exit_code == 0, res.output
    return sorted((root / "arch").glob("*.html")) + [root / "run" / "index.html",
                                                     root / "campaign" / "index.html"]


def _screenshot(page: Path, tmp: Path) -> tuple[Path, str]:
    shot = tmp / f"{page.parent.name}-{page.stem}.png"
    cmd = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={tmp / 'profile'}", "--enable-logging=stderr",
           "--v=0", f"--screenshot={shot}", "--window-size=1280,900", page.as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return shot, proc.stderr


def test_pages_render_without_console_errors(pages, tmp_path) -> None:
    assert len(pages) == 6
    for page in pages:
        shot, log = _screenshot(page, tmp_path)
        assert shot.is_file() and shot.stat().st_size > 5000, page
        bad = [line for line in log.splitlines() if any(b in line for b in BAD)]
        assert not bad, (page.name, bad)


#: Measures every text of an inline SVG as the browser lays it out (its own fonts, not
#: matplotlib's metrics): how far each one's box stays inside the canvas, in CSS px.
_MEASURE = """<script>
const svg = document.querySelector('svg'), c = svg.getBoundingClientRect(), out = [];
for (const t of svg.querySelectorAll('text')) {
  const b = t.getBoundingClientRect();
  if (b.width === 0) continue;
  out.push([t.textContent, Math.min(b.left - c.left, c.right - b.right,
                                    b.top - c.top, c.bottom - b.bottom)]);
}
document.getElementById('out').textContent = JSON.stringify(out);
</script>"""


def test_campaign_figures_keep_their_text_inside_the_canvas(pages, tmp_path) -> None:
    """Chromium clipped the y label of max.svg: its box touched the canvas's edge.

    Each figure is measured in the browser; every text (labels, ticks, legends) stays at
    least 5 px inside the canvas (the committed figures before the padding: 1.2–2.1 px;
    now ≥ 6.7 px).
    """
    import json
    import re

    svgs = sorted((pages[-1].parent).glob("*.svg"))
    assert {p.stem for p in svgs} >= {"delays", "max", "rms", "tau"}
    for svg in svgs:
        body = re.sub(r"^<\?xml[^>]*>\s*(<!DOCTYPE[^>]*>)?", "", svg.read_text(encoding="utf-8"))
        page = tmp_path / f"{svg.stem}.html"
        page.write_text(f"<!DOCTYPE html><html><body style='margin:20px'>{body}"
                        f"<pre id='out'></pre>{_MEASURE}</body></html>", encoding="utf-8")
        cmd = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu",
               "--no-first-run", f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom",
               page.as_uri()]
        dom = subprocess.run(cmd, capture_output=True, text=True, timeout=120).stdout
        found = re.search(r"<pre id=\"out\">(.*?)</pre>", dom, re.S)
        assert found, (svg.name, dom[-500:])
        texts = json.loads(found.group(1).replace("&amp;", "&").replace("&lt;", "<")
                           .replace("&gt;", ">"))
        assert len(texts) > 5, svg.name
        worst = min(texts, key=lambda t: t[1])
        assert worst[1] >= 5.0, (svg.name, worst)
