"""Recording one's own shots in the first tab, in a real browser: Chromium's fake camera plays the bundled real
source clip; the best frame of each moment is kept, the shots are used, the re-enactment completes and the
coverage view appears. Skips without /usr/bin/chromium or playwright, like the other browser tests."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest

from .test_app_browser import CHROMIUM, PANEL_SHOWN, VIDEO_PLAYABLE, WAIT_MS

pytestmark = pytest.mark.slow


def test_shots_recorded_with_the_webcam_reenact_and_show_their_coverage(app_server, tmp_path):
    if not CHROMIUM.is_file():
        pytest.skip(f"{CHROMIUM} not found: install Debian's chromium (apt-get install chromium) to run browser tests")
    sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")
    from lsr.bench.bench_live import CHROMIUM_ARGS, camera_frames, start_stream, write_y4m
    from lsr.examples import REAL_SOURCE

    camera = write_y4m(tmp_path / "camera.y4m", camera_frames(REAL_SOURCE, 75))
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM),
                                             args=[*CHROMIUM_ARGS, f"--use-file-for-fake-video-capture={camera}"])
        try:
            page = browser.new_context(viewport={"width": 1400, "height": 1000}, permissions=["camera"]).new_page()
            page.set_default_timeout(WAIT_MS)
            page.goto(app_server)
            page.wait_for_selector("#run")
            page.locator("#record").get_by_text("record your own shots").click()  # open the accordion
            start_stream(page, "record-camera")
            page.locator("#recorded-shots img").nth(1).wait_for()  # straight ahead and at least one more moment
            assert "moment(s) kept" in page.locator("#record-status").inner_text()
            page.locator("#record-camera").get_by_text("Stop").click()  # recording done
            page.locator("#use-recorded").click()
            page.locator("#shots img").first.wait_for()  # the recorded shots are now the source person
            page.locator("#driver-example input").click()
            page.get_by_role("option", name=re.compile("real person B .*: video")).click()
            page.locator("#driver-file td.filename").wait_for()  # the example driver is in place before running
            page.locator("#run").click()
            page.wait_for_function(VIDEO_PLAYABLE, timeout=WAIT_MS)
            page.wait_for_function(PANEL_SHOWN)
            page.locator("#coverage img").first.wait_for()  # what the recorded shots cover of the driver
            shot = tmp_path / "app_recorded.png"
            page.screenshot(path=str(shot), full_page=True)
        finally:
            browser.close()
    assert shot.stat().st_size > 0
    artifacts = os.environ.get("LSR_ARTIFACTS")
    if artifacts:
        Path(artifacts).mkdir(parents=True, exist_ok=True)
        shutil.copy2(shot, Path(artifacts) / shot.name)
