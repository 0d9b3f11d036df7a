"""Screenshots of a run report and a campaign report (tools/screenshot_reports.py).

Headless Chromium renders both reports' pages to PNG; each must be a picture of a
page, not a blank or an error page: big enough, of the page's width, with contrast
and with the figures' colours in it. Skipped when no chromium is on PATH (CI installs
it: .ci/run). docs/screenshots.md describes what the pictures show.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT

SPEC = importlib.util.spec_from_file_location("screenshot_reports",
                                              ROOT / "tools" / "screenshot_reports.py")
assert SPEC is not None and SPEC.loader is not None
shots = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(shots)

pytestmark = pytest.mark.skipif(
    shots.find_chromium() is None,
    reason="no headless browser: none of chromium, chromium-browser, google-chrome on PATH "
    "(CI installs chromium, .ci/run)",
)
#: the run report's blue (adaptive) and red (fixed), the campaign's blue and orange
FIGURE_COLOURS = {"run": ("#1f77b4", "#c0392b"), "campaign": ("#1f77b4", "#ff7f0e")}


@pytest.fixture(scope="module")
def pictures(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("shots")
    assert shots.main(["--out", str(out), "--workers", "2"]) == 0
    return {name: out / f"{name}.png" for name in ("run", "campaign")}


def _near(rgb: np.ndarray, colour: str, tol: int = 40) -> float:
    """Share of the pixels within ``tol`` of ``colour`` (#rrggbb) in every channel."""
    target = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)])
    return float(np.mean(np.all(np.abs(rgb.astype(int) - target) <= tol, axis=-1)))


@pytest.mark.parametrize("name", ["run", "campaign"])
def test_the_screenshot_is_the_page_not_a_blank(pictures, name: str) -> None:
    from PIL import Image

    png = pictures[name]
    assert png.stat().st_size > 50_000, png.stat().st_size  # a blank page is ~5 kB
    with Image.open(png) as im:
        rgb = np.asarray(im.convert("RGB"))
    height, width, _ = rgb.shape
    assert width == 1280 and height > 1500  # cropped to the page, which is long
    grey = rgb.mean(axis=-1)
    assert grey.std() > 25  # text and figures on white, not one colour
    assert 0.03 < float(np.mean(grey < 200)) < 0.6  # ink, but mostly paper
    for colour in FIGURE_COLOURS[name]:  # the figures were loaded, not broken images
        assert _near(rgb, colour) > 5e-5, (name, colour)  # a few hundred pixels at least
    # the page starts at the top (its title), and nothing but margin is cut at the bottom
    assert np.mean(grey[:120] < 128) > 0.002
    assert np.all(rgb[-10:] == rgb[-1])
