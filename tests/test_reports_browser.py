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
