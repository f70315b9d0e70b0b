"""`cdpr replay FILE --web` in a real browser: headless Chromium renders the demo recording."""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import ARTIFACTS, CDPR

pytestmark = pytest.mark.slow

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = [
    "--no-sandbox",
    "--use-gl=angle",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
]


def looks_loaded(png: bytes) -> tuple[bool, dict[str, int]]:
    """The loading screen is a dark, nearly grey page (≈100 colours, no saturated pixel); a loaded
    recording shows white plot panels with coloured curves (thousands of colours and saturated pixels)."""
    import io

    from PIL import Image

    a = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    colourful = int(((a.max(axis=-1) - a.min(axis=-1)) > 100).sum())
    unique = len(np.unique(a.reshape(-1, 3), axis=0))
    bright = int((a.mean(axis=-1) > 200).sum())
    stats = {"colourful": colourful, "unique": unique, "bright": bright}
    return colourful > 3000 and unique > 1000 and bright > a.shape[0] * a.shape[1] // 4, stats


@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason="Debian's chromium is not installed (.ci/run installs it)")
def test_web_replay_renders_the_demo_recording(demo_recording: tuple[dict, Path]) -> None:
    from playwright.sync_api import TimeoutError as PlaywrightTimeout
    from playwright.sync_api import sync_playwright

    _, rrd = demo_recording
    viewer = subprocess.Popen([*CDPR, "replay", str(rrd), "--web"], stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True)
    try:
        url = json.loads(viewer.stdout.readline())["url"]
        assert url.startswith("http://127.0.0.1:")
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            page = browser.new_page(viewport={"width": 1600, "height": 1000})
            page.goto(url)
            deadline = time.monotonic() + 180
            loaded, stats, png = False, {}, b""
            while time.monotonic() < deadline and not loaded:
                time.sleep(3)
                try:  # the software rasterizer can stall a screenshot on a busy machine: try again
                    png = page.screenshot(timeout=60_000)
                except PlaywrightTimeout:
                    continue
                loaded, stats = looks_loaded(png)
            ARTIFACTS.mkdir(exist_ok=True)
            if png:
                (ARTIFACTS / "replay_web.png").write_bytes(png)
            browser.close()
    finally:
        viewer.terminate()
        viewer.wait(timeout=10)
    assert loaded, f"the viewer still shows its loading screen after 180 s: {stats}"


def test_the_loading_screen_is_not_taken_for_a_recording() -> None:
    """The pixel test itself can fail: a dark, grey page is not a loaded recording."""
    import io

    from PIL import Image

    img = Image.new("RGB", (1600, 1000), (26, 28, 30))
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    assert looks_loaded(buf.getvalue())[0] is False


def test_report_on_the_demo_recording(demo_recording: tuple[dict, Path], tmp_path: Path) -> None:
    from PIL import Image

    summary, rrd = demo_recording
    proc = subprocess.run([*CDPR, "report", str(rrd), "-o", str(tmp_path)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    png = tmp_path / "tracking.png"
    with Image.open(png) as img:
        assert img.size == (1200, 800)
        assert len(np.unique(np.asarray(img.convert("RGB")).reshape(-1, 3), axis=0)) > 100  # not blank
    report = json.loads((tmp_path / "summary.json").read_text())
    for key in ("steps", "rms_position_error", "max_position_error", "final_position_error",
                "rms_orientation_error", "tension_min", "tension_max", "state_digest"):
        assert report[key] == pytest.approx(summary[key], rel=1e-9) if isinstance(summary[key], float) \
            else report[key] == summary[key], key
