#!/usr/bin/env python3
"""Screenshots of a run report and a campaign report, rendered by headless Chromium.

    python tools/screenshot_reports.py --out /tmp/shots     # reports and PNGs in /tmp/shots

Builds, with the ``archself`` command line of this interpreter:

- the run report of the paper's robot under IMU drift, fixed beside adaptive::

      archself simulate architectures/diffdrive.yaml --scenario imu_drift --compare \\
          --report OUT/run

- a small campaign of the process plant (its scenarios shortened to 300 s; 3 scenarios ×
  2 thresholds × 2 seeds × fixed and adaptive = 24 runs) and its report::

      archself campaign plant.yaml -s nominal -s level_drift -s valve_loss --seeds 2 \\
          --sweep runtime.threshold=0.8,1.2 -o OUT/campaign.parquet
      archself campaign-report OUT/campaign.parquet -o OUT/campaign --expect nominal=p1 \\
          --expect level_drift=p2 --expect valve_loss=p3

and renders each report's ``index.html`` to ``OUT/run.png`` and ``OUT/campaign.png``:
a window ``--width`` pixels wide and tall enough for the page, the blank space under
the page cropped. Chromium is ``--chromium``, else ``$CHROMIUM``, else the first of
``chromium``, ``chromium-browser``, ``google-chrome`` on PATH. docs/screenshots.md says
what the pictures show and what was checked on them; tests/test_screenshots.py runs
this script (in CI: .ci/run installs chromium).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "architectures" / "diffdrive.yaml"
PLANT = ROOT / "architectures" / "process_plant.yaml"
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
#: window height: taller than any of the two pages; the blank rest is cropped
HEIGHT = 6000


def find_chromium(explicit: str | None = None) -> str | None:
    """The Chromium binary: ``explicit``, ``$CHROMIUM`` or the first of :data:`BROWSERS`."""
    for name in (explicit, os.environ.get("CHROMIUM"), *BROWSERS):
        if name and (found := shutil.which(name)):
            return found
    return None


def _archself(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "archself", *args], check=True,
                   stdout=subprocess.DEVNULL)


def build_reports(out: Path, workers: int = 2) -> dict[str, Path]:
    """Write the run and the campaign report under ``out``; name → its ``index.html``."""
    out.mkdir(parents=True, exist_ok=True)
    _archself("simulate", str(ROBOT), "--scenario", "imu_drift", "--compare",
              "--report", str(out / "run"))
    plant = out / "plant.yaml"
    plant.write_text(PLANT.read_text(encoding="utf-8").replace("duration_s: 600",
                                                               "duration_s: 300"),
                     encoding="utf-8")
    results = out / "campaign.parquet"
    _archself("campaign", str(plant), "-s", "nominal", "-s", "level_drift", "-s", "valve_loss",
              "--seeds", "2", "--sweep", "runtime.threshold=0.8,1.2", "-o", str(results),
              "--workers", str(workers), "--force")
    _archself("campaign-report", str(results), "-o", str(out / "campaign"),
              "--expect", "nominal=p1", "--expect", "level_drift=p2",
              "--expect", "valve_loss=p3")
    return {"run": out / "run" / "index.html", "campaign": out / "campaign" / "index.html"}


def screenshot(chromium: str, page: Path, png: Path, width: int = 1280) -> Path:
    """Render ``page`` to ``png`` (``width`` wide, the page's height); return ``png``."""
    with tempfile.TemporaryDirectory(prefix="archself-chromium-") as profile:
        cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
               "--force-device-scale-factor=1", "--no-first-run",
               "--disable-background-networking", "--disable-component-update",
               "--disable-sync", f"--user-data-dir={profile}", f"--screenshot={png}",
               f"--window-size={width},{HEIGHT}", page.resolve().as_uri()]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    if proc.returncode != 0 or not png.is_file():
        raise RuntimeError(f"{chromium} failed on {page}: {proc.stderr[-1000:]}")
    _crop_blank_bottom(png)
    return png


def _crop_blank_bottom(png: Path, margin: int = 24) -> None:
    """Cut the rows under the page that have the colour of the last row (keep a margin)."""
    import numpy as np
    from PIL import Image

    with Image.open(png) as im:
        rgb = im.convert("RGB")
    a = np.asarray(rgb)
    blank = np.all(a == a[-1], axis=(1, 2))
    content = np.flatnonzero(~blank)
    bottom = min(a.shape[0], (int(content[-1]) + 1 + margin) if content.size else a.shape[0])
    rgb.crop((0, 0, a.shape[1], bottom)).save(png, optimize=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="folder for the reports and PNGs")
    ap.add_argument("--chromium", help="the browser binary (default: found on PATH)")
    ap.add_argument("--width", type=int, default=1280, help="window width in pixels")
    ap.add_argument("--workers", type=int, default=2, help="campaign workers")
    args = ap.parse_args(argv)
    chromium = find_chromium(args.chromium)
    if chromium is None:
        print("error: no chromium on PATH (" + ", ".join(BROWSERS) + "); pass --chromium",
              file=sys.stderr)
        return 1
    pages = build_reports(args.out, args.workers)
    for name, page in pages.items():
        print(screenshot(chromium, page, args.out / f"{name}.png", args.width))
    return 0


if __name__ == "__main__":
    sys.exit(main())
