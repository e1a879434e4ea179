"""The app in a real browser (Playwright driving Debian's Chromium): upload, run, the video plays, the layout shows.

Skips when /usr/bin/chromium or the ``playwright`` package is missing (.ci/run installs Chromium for CI).
A screenshot of the finished page is kept under the test's tmp dir and, when $LSR_ARTIFACTS is set, there.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from lsr.bench.bench_live import CHROMIUM, HEADLESS_ARGS

pytestmark = pytest.mark.slow

WAIT_MS = 300_000  # generous: a failure bound on shared CPUs, not a speed check
VIDEO_PLAYABLE = """() => {
    const video = document.querySelector('#result-video video');
    return video !== null && video.readyState >= 2 && video.duration > 0;
}"""
PANEL_SHOWN = """() => {
    const image = document.querySelector('#layout-panel img');
    return image !== null && image.complete && image.naturalWidth > 0;
}"""


@pytest.fixture(scope="module")
def browser():
    if not CHROMIUM.is_file():
        pytest.skip(f"{CHROMIUM} not found: install Debian's chromium (apt-get install chromium) to run browser tests")
    sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")
    with sync_api.sync_playwright() as playwright:
        chromium = playwright.chromium.launch(executable_path=str(CHROMIUM), args=HEADLESS_ARGS)
        yield chromium
        chromium.close()


@pytest.fixture
def page(browser, app_server):
    context = browser.new_context(viewport={"width": 1400, "height": 1000})
    page = context.new_page()
    page.set_default_timeout(WAIT_MS)
    page.goto(app_server)
    page.wait_for_selector("#run")
    yield page
    context.close()


def upload(page, elem_id: str, path: Path) -> None:
    page.locator(f"#{elem_id} input[type=file]").set_input_files(str(path))
    page.locator(f"#{elem_id} td.filename[aria-label='{path.name}']").wait_for()


def expect_toast(page, text: str) -> None:
    page.locator(".toast-body", has_text=text).first.wait_for()


def dismiss_toasts(page) -> None:
    for close in page.locator(".toast-close").all():
        if close.is_visible():
            close.click()


def keep_screenshot(page, tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    page.screenshot(path=str(path), full_page=True)
    artifacts = os.environ.get("LSR_ARTIFACTS")
    if artifacts:
        Path(artifacts).mkdir(parents=True, exist_ok=True)
        shutil.copy2(path, Path(artifacts) / name)
    return path


def run_and_wait_for_video(page) -> None:
    page.locator("#run").click()
    page.wait_for_function(VIDEO_PLAYABLE, timeout=WAIT_MS)


def test_upload_run_video_plays_and_layout_shows(page, app_inputs, tmp_path):
    upload(page, "source-files", app_inputs["source"])
    page.locator("#shots img").first.wait_for()  # the shot gallery with landmarks drawn
    upload(page, "driver-file", app_inputs["driver"])
    run_and_wait_for_video(page)
    duration = page.evaluate("() => document.querySelector('#result-video video').duration")
    assert duration > 0
    page.wait_for_function(PANEL_SHOWN)
    page.locator("#averaging img").first.wait_for()
    page.locator("#coverage img").first.wait_for()  # what the shots cover of the driver, as a picture
    assert "frame(s)" in page.locator("#run-summary").inner_text()
    assert keep_screenshot(page, tmp_path, "app_uploaded.png").stat().st_size > 0


def test_the_real_example_person_driven_by_the_bundled_example(page, tmp_path):
    import re

    page.get_by_role("button", name=re.compile("Use the example person")).click()
    page.locator("#shots img").first.wait_for()
    page.locator("#driver-example input").click()
    page.get_by_role("option", name=re.compile("real person B .*: video")).click()
    page.locator("#driver-file td.filename").wait_for()  # the example driver is in place before running
    run_and_wait_for_video(page)
    page.wait_for_function(PANEL_SHOWN)
    page.locator("#coverage img").first.wait_for()
    assert "frame(s)" in page.locator("#run-summary").inner_text()
    assert keep_screenshot(page, tmp_path, "app_reenacted.png").stat().st_size > 0  # README's picture of the app


def test_source_without_face_shows_message_and_app_stays_usable(page, app_inputs, tmp_path):
    upload(page, "source-files", app_inputs["no_face"])
    expect_toast(page, "no face found")  # shown as soon as the shots are read
    upload(page, "driver-file", app_inputs["driver"])
    dismiss_toasts(page)
    page.locator("#run").click()
    expect_toast(page, "no face found")  # and again when run anyway
    keep_screenshot(page, tmp_path, "app_no_face_error.png")
    dismiss_toasts(page)
    page.locator("#source-files button[aria-label='Clear']").click()
    upload(page, "source-files", app_inputs["source"])
    run_and_wait_for_video(page)
    page.wait_for_function(PANEL_SHOWN)
