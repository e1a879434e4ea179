"""``lsr bench live``: the live tab in a real browser, its camera a video file; frame rate and camera-to-screen latency.

The app is served in-process on 127.0.0.1 with the shipped default (or ``--weights``); Playwright drives Debian's
Chromium with a fake camera (``--use-file-for-fake-video-capture``, a .y4m written here: a synthetic person by
default, ``--camera-video`` for a real clip) and starts the live tab's stream. In the page, a hook records when
Gradio grabs each camera frame (its ``toDataURL('image/jpeg')``), when each result arrives (the status line
changes) and when its picture has loaded; the server notes when its handler takes each frame up. Per frame shown:

    latency = its picture loaded - the last camera grab before the handler took it up

(the page sends frames at the camera's pace; the server keeps only the newest, so that grab is the frame shown, to
within one camera frame). The rate is distinct frames shown per second over the measured window (after a warm-up). The table gives medians with the processing
time per frame that the server reports, and a screenshot of the tab is written with ``--screenshot``. Over the
window every thread's CPU time of the app and of Chromium is read too (``lsr.bench.thread_cpu``): how many of the
cores each kept busy.
"""

from __future__ import annotations

import contextlib
import dataclasses
import statistics
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from app.ui import LIVE_CAMERA_SIZE

if TYPE_CHECKING:
    from lsr.config import BenchLiveConfig

SECTION = "live"
CHROMIUM = Path("/usr/bin/chromium")  # Debian's (`playwright install` cannot download one here)
HEADLESS_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--no-first-run"]  # the browser tests' too
CHROMIUM_ARGS = [*HEADLESS_ARGS, "--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
                 "--autoplay-policy=no-user-gesture-required"]
CAMERA_SIZE = (640, 480)  # (width, height) of the fake camera
CAMERA_FPS = 25
START_TIMEOUT_MS = 300_000  # a failure bound on shared CPUs (the first frame exports and loads the model)
WARMUP_CALLS = 5
SLIDER_UPDATES = 20

RECORDER = """() => {
  window.__live = {grabs: [], results: [], shown: []};
  const toDataURL = HTMLCanvasElement.prototype.toDataURL;
  HTMLCanvasElement.prototype.toDataURL = function (type, ...rest) {
    if (type === 'image/jpeg') window.__live.grabs.push(Date.now());
    return toDataURL.call(this, type, ...rest);
  };
  const watch = () => {
    const status = document.querySelector('#live-status');
    const output = document.querySelector('#live-output');
    if (!status || !output) { setTimeout(watch, 200); return; }
    let last = null;
    new MutationObserver(() => {
      const text = status.innerText;  // one result per new status line (a change makes several mutations)
      if (text !== last) { last = text; window.__live.results.push([Date.now(), text]); }
    }).observe(status, {childList: true, subtree: true, characterData: true});
    output.addEventListener('load', (event) => {
      if (event.target.tagName === 'IMG') window.__live.shown.push(Date.now());
    }, true);
  };
  watch();
}"""


@dataclasses.dataclass
class LiveMeasure:
    frames: int
    """Results shown in the measured window."""
    seconds: float
    fps: float
    latency_ms: list[float]
    processing_ms: list[float]
    screenshot: Path | None = None
    output: np.ndarray | None = None
    """(H, W, 3) uint8 RGB: the last re-enacted picture on the page."""
    cores: dict[str, float] | None = None
    """Cores kept busy over the window by the app (this process) and by Chromium (``lsr.bench.thread_cpu``; {}: /proc
    unreadable)."""


def write_y4m(path: Path, frames: np.ndarray, fps: int = CAMERA_FPS) -> Path:
    """(N, H, W, 3) uint8 RGB, H and W even -> a raw YUV 4:2:0 .y4m (Chromium's fake-camera file format)."""
    import cv2

    count, height, width = frames.shape[:3]
    if height % 2 or width % 2:
        raise ValueError(f"y4m frames need an even size, got {width}x{height}")
    with open(path, "wb") as handle:
        handle.write(f"YUV4MPEG2 W{width} H{height} F{fps}:1 Ip A1:1 C420jpeg\n".encode())
        for frame in frames:
            handle.write(b"FRAME\n")
            handle.write(cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2YUV_I420).tobytes())
    return path


def camera_frames(video: Path | None, count: int, seed: int = 7) -> np.ndarray:
    """(count, 480, 640, 3) uint8: the first frames of ``video`` letterboxed, else a synthetic talking person."""
    import cv2

    width, height = CAMERA_SIZE
    if video is None:
        from lsr.data.synth import render_video

        frames = render_video(seed, count, height).frames  # (N, 480, 480, 3)
        pad = (width - height) // 2
        return np.pad(frames, ((0, 0), (0, 0), (pad, width - height - pad), (0, 0)), mode="edge")
    from landmarks.io.video import iter_frames

    out = []
    for frame in iter_frames(video):
        scale = min(width / frame.shape[1], height / frame.shape[0])
        resized = cv2.resize(frame, (round(frame.shape[1] * scale) // 2 * 2, round(frame.shape[0] * scale) // 2 * 2),
                             interpolation=cv2.INTER_AREA)
        canvas = np.zeros((height, width, 3), np.uint8)
        top, left = (height - resized.shape[0]) // 2, (width - resized.shape[1]) // 2
        canvas[top : top + resized.shape[0], left : left + resized.shape[1]] = resized
        out.append(canvas)
        if len(out) == count:
            break
    if not out:
        from lsr.errors import ConfigError

        raise ConfigError(f"--camera-video {video}: no frames could be read")
    return np.stack(out)


def start_stream(page, camera_id: str = "live-camera") -> None:
    """Open the live tab and start its camera stream (Gradio's webcam: pick the camera, then record); another
    ``camera_id`` starts that webcam instead, on whatever tab shows it."""
    if camera_id == "live-camera":
        page.get_by_role("tab", name="Live: your webcam drives the person").click()
    camera = page.locator(f"#{camera_id}")
    camera.wait_for()
    for label in ("Click to Access Webcam", "Webcam"):  # the source button, where it shows
        button = camera.get_by_role("button", name=label)
        if button.count() and button.first.is_visible():
            button.first.click()
            break
    camera.locator("video").wait_for()
    camera.locator("button.record-button, button[aria-label*='ecord'], button:has-text('Record')").first.click()


def wait_for_first_result(page) -> None:
    """Until the live tab shows its first re-enacted picture (the first frame loads the model and exports it)."""
    page.wait_for_function("() => window.__live && window.__live.shown.length > 0", timeout=START_TIMEOUT_MS)


def measure(page, seconds: float, warmup: float, trace: list[tuple[int, float]]) -> LiveMeasure:
    """Wait for the first result, warm up, then measure ``seconds`` of the running stream (and the cores the app,
    served by this process, and Chromium kept busy meanwhile)."""
    from lsr.bench.thread_cpu import core_shares, thread_times

    wait_for_first_result(page)
    time.sleep(warmup)
    begin = page.evaluate("() => Date.now()")
    app_before, browser_before = time.process_time(), thread_times(CHROMIUM.name)
    time.sleep(seconds)
    end = page.evaluate("() => Date.now()")
    app_after, browser_after = time.process_time(), thread_times(CHROMIUM.name)
    result = summarise(page.evaluate("() => window.__live"), trace, begin, end)
    window = (end - begin) / 1000
    browser = core_shares(browser_before, browser_after, window)
    if browser and window > 0:  # the app's threads come and go: its process's time counts those that ended too
        app = (app_after - app_before) / window
        result.cores = {"the app": app, "Chromium": browser["all"], "all": app + browser["all"]}
    else:
        result.cores = {}
    return result


def _status_line(text: str) -> tuple[int, float | None] | None:
    """The status line's (frame index, server ms per frame) (None: not a frame's line, e.g. Gradio's timer)."""
    for line in text.splitlines():
        if " fps · " in line and "frame " in line:
            parts = [part.strip() for part in line.split("·")]
            index = next(int(p.split()[1]) for p in parts if p.startswith("frame "))
            ms = next((float(p.split()[0]) for p in parts if p.endswith("ms per frame")), None)
            return index, ms
    return None


def summarise(record: dict[str, Any], trace: list[tuple[int, float]], begin: float, end: float) -> LiveMeasure:
    """The page's timestamps and the server's (ms since the epoch, one clock on loopback) -> rate, latencies and
    processing times of the frames shown inside [begin, end]: a frame's latency runs from the camera grab the
    server took it from (the last grab before the handler took it up: the server keeps only the newest frame) to
    the load of its picture after its status line arrived."""
    grabs = np.asarray(record["grabs"], np.float64)
    shown = np.asarray(record["shown"], np.float64)
    taken_up = dict(trace)
    latency, processing, seen = [], [], set()
    for arrived, text in record["results"]:
        line = _status_line(text)
        if line is None or line[0] in seen or not begin <= arrived <= end:
            continue
        index, ms = line
        seen.add(index)
        loaded = shown[shown >= arrived]
        start = taken_up.get(index)
        if start is not None and len(loaded):
            grabbed = grabs[grabs <= start]
            if len(grabbed):
                latency.append(float(loaded[0] - grabbed[-1]))
        if ms is not None:
            processing.append(ms)
    seconds = (end - begin) / 1000
    return LiveMeasure(len(seen), seconds, len(seen) / seconds if seconds > 0 else 0.0, latency, processing)


SHOWN_PICTURE = """async () => {
  const copy = new Image();
  copy.src = document.querySelector('#live-output img').src;
  await copy.decode();  // the whole picture, not one caught half-loaded while the stream replaces it
  const canvas = document.createElement('canvas');
  canvas.width = copy.naturalWidth; canvas.height = copy.naturalHeight;
  canvas.getContext('2d').drawImage(copy, 0, 0);
  return canvas.toDataURL('image/png');
}"""


def shown_picture(page) -> np.ndarray:
    """(H, W, 3) uint8 RGB: the live tab's current re-enacted picture, decoded whole."""
    import base64

    import cv2

    png = base64.b64decode(page.evaluate(SHOWN_PICTURE).split(",", 1)[1])
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _median(values: list[float]) -> str:
    return f"{statistics.median(values):.0f}" if values else "–"


def handler_loop(weights: Path | None, frames: np.ndarray, examples_dir: Path, bank: str | None = None) -> LiveMeasure:
    """The live handler called back to back on camera frames in this process, no browser: what a browser on
    another machine gets from these 2 cores, minus the network (rate; per-call time as the latency floor). bank: the
    live reenactor's ``bank`` (``lsr.core.finish.BANKS``; None: its default, the shipped one)."""
    import cv2

    from app import handlers
    from app import live_tab as live
    from lsr.weights import resolve_weights

    store = handlers.ModelStore(resolve_weights(weights), "cpu")
    if bank is not None:
        store.live_reenactor().bank = bank
    small = [cv2.resize(frame, LIVE_CAMERA_SIZE, interpolation=cv2.INTER_AREA) for frame in frames]
    stream, calls, processing = None, [], []
    for frame in small[:WARMUP_CALLS]:
        _, _, _, stream = live.live_frame(store, handlers.Limits(), stream, frame, None, 4, examples_dir)
    started = time.perf_counter()
    for frame in small[WARMUP_CALLS:]:
        tick = time.perf_counter()
        _, _, status, stream = live.live_frame(store, handlers.Limits(), stream, frame, None, 4, examples_dir)
        calls.append(1000 * (time.perf_counter() - tick))
        line = _status_line(status)
        if line is not None and line[1] is not None:
            processing.append(line[1])
    seconds = time.perf_counter() - started
    stream.close()
    return LiveMeasure(len(calls), seconds, len(calls) / seconds, calls, processing)


def slider_updates(weights: Path | None, examples_dir: Path, count: int = SLIDER_UPDATES) -> list[float]:
    """ms of each expression-slider update (``app.live_tab.edit_frame``: edit, synthesise, composite, layout) as
    the sliders sweep, after one update that encodes the person."""
    from app import handlers
    from app import live_tab as live
    from lsr.weights import resolve_weights

    store = handlers.ModelStore(resolve_weights(weights), "cpu")
    state, times = None, []
    for step in range(count + 1):
        values = [neutral + (high - neutral) * (step % 10) / 10 for _, low, high, neutral, _, _ in live.EDIT_SLIDERS]
        started = time.perf_counter()
        _, _, _, state = live.edit_frame(store, handlers.Limits(), state, None, 4, values, examples_dir)
        times.append(1000 * (time.perf_counter() - started))
    return times[1:]


def live_markdown(browser: LiveMeasure, server: LiveMeasure | None, label: str, camera: str, machine: str,
                  sliders: list[float] | None = None, no_bank: LiveMeasure | None = None) -> str:
    from lsr.eval.machine import usable_cores

    def row(what: str, result: LiveMeasure, latency: str) -> str:
        p90 = f"{np.percentile(result.latency_ms, 90):.0f}" if result.latency_ms else "–"
        return (f"| {what} | {result.frames} | {result.seconds:.1f} | {result.fps:.1f} | {_median(result.latency_ms)} "
                f"({latency}) | {p90} | {_median(result.processing_ms)} |")

    lines = [f"Model {label}; camera: {camera}, {CAMERA_SIZE[0]}x{CAMERA_SIZE[1]} at {CAMERA_FPS} fps (Chromium's fake "
             f"camera; the tab asks for {LIVE_CAMERA_SIZE[0]}x{LIVE_CAMERA_SIZE[1]}).", "",
             "| where | frames shown | seconds | fps | latency ms, median | latency ms, 90th percentile | server ms per "
             "frame, median |", "|---|---|---|---|---|---|---|",
             row("browser and app on these 2 cores (loopback)", browser, "camera grab to picture loaded")]
    if server is not None:
        lines.append(row("the app alone: its handler back to back, no browser", server, "one call"))
    if no_bank is not None:
        lines.append(row("the same, without the eye bank (`bank` none)", no_bank, "one call"))
        if server is not None and no_bank.fps > 0:
            lines += ["", f"**The eye bank's cost, same run:** the handler's rate with it {server.fps / no_bank.fps:.2f}x "
                          "its rate without it (issue 63's bar: >= 0.9x)."]
    if sliders:
        lines += ["", f"Expression sliders: one update (edit the anchor's landmarks, synthesise, composite, colour the "
                      f"layout) takes {statistics.median(sliders):.0f} ms, median of {len(sliders)} (goal: <= 100 ms)."]
    if browser.cores:
        cores = browser.cores
        lines += ["", f"Over the window the app kept {cores['the app']:.2f} cores busy and Chromium "
                      f"{cores['Chromium']:.2f}, {cores['all']:.2f} of {usable_cores()} (CPU time: the app's process, "
                      "Chromium's threads from /proc)."]
    lines += ["",
              "Server ms per frame: tracking, retargeting, the warps, the network (onnxruntime, one thread) and the "
              "composite, of one frame (the handler overlaps one frame's network with the next one's tracking and "
              "warps, so calls come faster than this).",
              "Goals: >= 15 fps and <= 200 ms (beyond: 20 fps, 150 ms).", "", machine]
    return "\n".join(lines)


@contextlib.contextmanager
def camera_page(y4m: Path, viewport: tuple[int, int] = (1400, 1000), init_script: str | None = None):
    """A page of Chromium (Playwright) with ``y4m`` as its fake camera, the camera allowed and ``init_script`` run
    before any page script: yields the page, not yet on any URL; the browser closes after."""
    from lsr.errors import ConfigError

    if not CHROMIUM.is_file():
        raise ConfigError(f"{CHROMIUM} not found: install Debian's chromium (apt-get install chromium)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError as exc:
        raise ConfigError("the browser benchmarks need the playwright package: pip install -e '.[test]'") from exc
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM),
                                             args=[*CHROMIUM_ARGS, f"--use-file-for-fake-video-capture={y4m}"])
        try:
            width, height = viewport
            page = browser.new_context(viewport={"width": width, "height": height}, permissions=["camera"]).new_page()
            page.set_default_timeout(START_TIMEOUT_MS)
            if init_script is not None:
                page.add_init_script(init_script)
            yield page
        finally:
            browser.close()


@contextlib.contextmanager
def live_page(url: str, y4m: Path):
    """Chromium with ``y4m`` as its camera (``camera_page``), on ``url``'s live tab with the stream started and the
    page's timestamp hooks (``RECORDER``) in place: yields the page; the browser closes after."""
    with camera_page(y4m, init_script=f"({RECORDER})()") as page:
        page.goto(url)
        start_stream(page)
        yield page


def run_live(url: str, y4m: Path, seconds: float, warmup: float, screenshot: Path | None) -> LiveMeasure:
    """Open ``url`` (an app served by this process) in Chromium with ``y4m`` as its camera, start the live stream and
    measure it."""
    from app import live_tab as live

    trace: list[tuple[int, float]] = []
    live.LIVE_TRACE = trace
    try:
        with live_page(url, y4m) as page:
            result = measure(page, seconds, warmup, trace)
            result.output = shown_picture(page)
            if screenshot is not None:
                from landmarks.io.image_files import atomic_output

                with atomic_output(Path(screenshot)) as temp:
                    page.screenshot(path=str(temp), full_page=False)
                result.screenshot = Path(screenshot)
            return result
    finally:
        live.LIVE_TRACE = None


def camera_file(path: Path, video: Path | None, seconds: float, fps: int = CAMERA_FPS) -> Path:
    """The fake camera's .y4m at ``fps``: ``seconds`` of ``video`` (letterboxed, its frames played at ``fps``), or
    4 s of a synthetic talking person on loop."""
    count = int(seconds * fps) if video is not None else 4 * fps
    return write_y4m(path, camera_frames(video, count), fps)


def live_tab(weights: Path | None, y4m: Path, seconds: float, warmup: float, screenshot: Path | None,
             examples_dir: Path, port: int = 0) -> LiveMeasure:
    """The app served in this process, its live tab in Chromium with ``y4m`` as the camera, measured."""
    from app.ui import build_app, launch
    from lsr.config import AppConfig

    app_cfg = AppConfig(weights=weights, port=port or _free_port(), device="cpu", examples_dir=examples_dir)
    app_cfg.validate()
    demo, store, files = build_app(app_cfg)
    url = launch(demo, app_cfg, files, block=False)
    try:
        return run_live(url, y4m, seconds, warmup, screenshot)
    finally:
        demo.close()
        files.drop_all()


def run_bench_live(cfg: BenchLiveConfig) -> LiveMeasure:
    """Entry point of ``lsr bench live``."""
    from lsr.eval import sections
    from lsr.eval.machine import machine_markdown, shown_path

    with tempfile.TemporaryDirectory(prefix="lsr-bench-live-") as temp:
        temp = Path(temp)
        y4m = camera_file(temp / "camera.y4m", cfg.camera_video, cfg.seconds + cfg.warmup)
        result = live_tab(cfg.weights, y4m, cfg.seconds, cfg.warmup, cfg.screenshot, temp / "examples", cfg.port)
        frames = camera_frames(cfg.camera_video, 5 * CAMERA_FPS)
        server = handler_loop(cfg.weights, frames, temp / "examples")
        no_bank = handler_loop(cfg.weights, frames, temp / "examples", bank="none")
        sliders = slider_updates(cfg.weights, temp / "examples")
    label = "the shipped default" if cfg.weights is None else f"`{shown_path(cfg.weights)}`"
    camera = ("a synthetic talking person (lsr.data.synth)" if cfg.camera_video is None
              else f"`{shown_path(cfg.camera_video)}`")
    text = live_markdown(result, server, label + " driving the example person", camera, machine_markdown(), sliders,
                         no_bank)
    sections.publish(cfg, "lsr bench live", SECTION, "Live: the webcam tab in a browser (`lsr bench live`)", text)
    return result


def _free_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]
