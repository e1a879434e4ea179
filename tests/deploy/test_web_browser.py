"""The web site in Chromium (Playwright, Debian's chromium, a fake camera): it loads from a plain static server,
re-enacts the fake camera's frames live, and its output for fixed camera frames is the Python live session's
(issue 42's parity, here in the browser itself). Skips without Chromium, playwright, Node or npm."""

from __future__ import annotations

import base64

import numpy as np
import pytest

from lsr.bench.bench_live import CHROMIUM, CHROMIUM_ARGS, camera_frames, write_y4m
from lsr.eval.metrics import psnr

pytestmark = pytest.mark.slow
WAIT_MS = 300_000  # a failure bound on shared CPUs, not a speed check
SHOWN = 8  # live frames to see
FPS = 25.0


@pytest.fixture(scope="module")
def page(site, tmp_path_factory):
    from lsr.examples import REAL_DRIVER
    from deploy.web_serve import serve_folder

    if not CHROMIUM.is_file():
        pytest.skip(f"{CHROMIUM} not found: install Debian's chromium (apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")
    y4m = write_y4m(tmp_path_factory.mktemp("camera") / "camera.y4m", camera_frames(REAL_DRIVER, 50))
    with serve_folder(site.folder) as url, sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM),
                                             args=[*CHROMIUM_ARGS, f"--use-file-for-fake-video-capture={y4m}"])
        try:
            page = browser.new_context(viewport={"width": 1300, "height": 900}, permissions=["camera"]).new_page()
            page.set_default_timeout(WAIT_MS)
            errors: list[str] = []
            page.on("pageerror", lambda error: errors.append(str(error)))
            page.goto(url)
            page.wait_for_function("document.body.dataset.ready === '1' || document.body.dataset.failed !== undefined")
            assert page.evaluate("document.body.dataset.failed") is None, page.inner_text("#status")
            page.errors = errors
            yield page
        finally:
            browser.close()


def test_the_page_is_cross_origin_isolated_and_leaves_cores_to_the_tracker_and_itself(page):
    assert page.evaluate("crossOriginIsolated")  # sw.js added the headers the static server did not send
    cores = page.evaluate("navigator.hardwareConcurrency")
    assert page.evaluate("window.lsr.threads") == max(1, min(4, cores - 2))


def test_the_browser_re_enacts_fixed_camera_frames_as_the_python_live_session(page, python_session, driver_frames):
    frames = driver_frames(6)
    session = python_session()
    expected = [session.step(frame, index / FPS).image for index, frame in enumerate(frames)]
    encoded = base64.b64encode(np.ascontiguousarray(frames).tobytes()).decode()
    reply = page.evaluate("([frames, shape, fps]) => window.lsr.reenactFrames(frames, shape, fps)",
                          [encoded, list(frames.shape), FPS])
    got = np.frombuffer(base64.b64decode(reply), np.uint8).reshape(len(frames), *expected[0].shape)
    scores = psnr(got, np.stack(expected))
    print("browser vs python, dB per frame:", np.round(scores, 1))
    assert min(scores) >= 40.0


def test_the_fake_camera_drives_the_person_live_with_the_mark_and_the_layout(page, tmp_path):
    page.click("#start")
    page.wait_for_function(f"window.lsr.stats.faces >= {SHOWN}")
    stats = page.evaluate("({faces: window.lsr.stats.faces, latency: window.lsr.stats.latency, "
                          "grabbed: window.lsr.stats.grabbed, shown: window.lsr.stats.shown})")
    assert stats["faces"] >= SHOWN and all(ms > 0 for ms in stats["latency"])
    grabbed, shown = np.array(stats["grabbed"]), np.array(stats["shown"])
    assert (np.diff(grabbed) > 0).all(), "the camera's frames are shown in the order they came, each once"
    assert (grabbed[1:] < shown[:-1]).any(), "the next frame is under way before the one before it is shown"
    assert "fps" in page.inner_text("#stats") and "ms per frame" in page.inner_text("#stats")
    assert page.inner_text("#legend").strip()  # the layout panel's legend names its parts
    page.screenshot(path=str(tmp_path / "web.png"))
    assert not page.errors


def test_your_own_photos_become_the_person(page, tmp_path):
    from landmarks.io.image_files import write_image
    from lsr.examples import example_shots

    paths = []
    for index, shot in enumerate(example_shots()):
        paths.append(tmp_path / f"photo_{index}.png")
        write_image(paths[-1], shot)
    page.set_input_files("#photos", [str(path) for path in paths])
    page.wait_for_function("document.querySelector('#status').innerText.startsWith('Your person')")
    assert "4 shots" in page.inner_text("#status")
    assert page.is_enabled("#example")
    page.click("#example")
    assert page.inner_text("#status") == "The example person." and not page.is_enabled("#example")
    assert not page.errors


def _open(page, query: str):
    """A second tab of the page's browser at its address + ``query``, loaded -> (the tab, its console messages)."""
    tab = page.context.new_page()
    messages: list[str] = []
    tab.on("console", lambda message: messages.append(f"{message.type}: {message.text}"))
    tab.set_default_timeout(WAIT_MS)
    tab.goto(page.url.split("?")[0] + query)
    tab.wait_for_function("document.body.dataset.ready === '1' || document.body.dataset.failed !== undefined")
    assert tab.evaluate("document.body.dataset.failed") is None, tab.inner_text("#status")
    return tab, messages


def test_without_a_gpu_adapter_the_page_runs_the_network_on_wasm_and_says_so(page):
    # headless Chromium has navigator.gpu but no adapter (and no navigator.ml): nothing but WASM is tried
    assert page.evaluate("[window.lsr.backend, window.lsr.backends, window.lsr.failures]") == ["wasm", ["wasm"], []]
    assert page.evaluate("document.body.dataset.backend") == "wasm"
    assert page.evaluate("navigator.gpu !== undefined")
    # the status says so until the camera starts, then the stats line beside the frame rate
    assert "the network on WASM" in page.inner_text("#status") or "(WASM)" in page.inner_text("#stats")


@pytest.mark.parametrize("asked", ["wasm", "webgpu"])
def test_the_backend_asked_for_is_tried_and_wasm_takes_over_where_it_fails(page, asked):
    tab, messages = _open(page, f"?backend={asked}")
    try:
        backend, backends, failures = tab.evaluate("[window.lsr.backend, window.lsr.backends, window.lsr.failures]")
        assert backend == "wasm" and backends == ([asked, "wasm"] if asked != "wasm" else ["wasm"])
        assert "lsr: the frame generator runs on WASM" in "\n".join(messages)
        if asked == "webgpu":  # onnxruntime-web finds no adapter: the reason is logged and shown
            (failure,) = failures
            assert failure["backend"] == "webgpu" and "GPU adapter" in failure["reason"]
            assert any(message.startswith("warning: lsr: the frame generator could not run on WebGPU") and
                       "GPU adapter" in message for message in messages)
            assert "WebGPU failed, see the console" in tab.inner_text("#status")
        else:
            assert failures == [] and "failed" not in tab.inner_text("#status")
    finally:
        tab.close()
