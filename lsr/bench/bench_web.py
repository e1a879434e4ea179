"""``lsr bench web``: the static web site (``lsr export --web``) in Chromium with a fake camera, against the app's
live tab (``lsr bench live``) in the same run on the same machine and camera: frame rate, camera-to-screen latency
and the time per frame, with the ratios (issue 42's bar: the site at >= 0.8x the live tab's rate, its latency no
worse).

The site is served by a plain static server (``deploy.web_serve``); the page runs everything itself on
onnxruntime-web (the frame generator on WebGPU or WebNN where the browser has them, else WASM with SIMD and threads
through its service worker's cross-origin isolation). In the page, per frame
shown:

    latency = the picture drawn on its canvas - the camera frame grabbed from the video element

and the rate is the frames shown per second over the measured window (after a warm-up). The live tab is measured as
``lsr bench live`` does (camera grab to picture loaded; the browser and the app's server share these cores).
Over the site's window every Chromium thread's CPU time is read too (``lsr.bench.thread_cpu``): how many of the
cores the page kept busy, and where, which tells a page bound by the CPU from one held by its own waits.
"""

from __future__ import annotations

import statistics
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lsr.bench.bench_live import CAMERA_FPS, CHROMIUM, LiveMeasure, camera_file, camera_page, live_tab

if TYPE_CHECKING:
    from lsr.config import BenchWebConfig

SECTION = "web"
STAGES = ("track", "retarget", "warps", "network", "mouth", "composite")


def measure_site(folder: Path, y4m: Path, seconds: float, warmup: float, screenshot: Path | None
                 ) -> tuple[LiveMeasure, dict[str, float], int, str, dict[str, float], int]:
    """The site in ``folder`` served statically and opened in Chromium with ``y4m`` as the camera, its stream
    measured: (the measure, median ms of each stage, WASM threads, the frame generator's backend as the page names it:
    WASM, WebGPU or WebNN, ``deploy/web/src/backend.ts``, the cores Chromium's threads kept busy over the window,
    ``lsr.bench.thread_cpu.core_shares``: {} where /proc cannot be read, the camera frames that came over the
    window)."""
    from deploy.web_serve import serve_folder
    from landmarks.io.image_files import atomic_output
    from lsr.bench.thread_cpu import core_shares, thread_times
    from lsr.errors import LsrError

    with serve_folder(folder) as url, camera_page(y4m, viewport=(1300, 900)) as page:
        page.goto(url)
        page.wait_for_function("document.body.dataset.ready === '1' || document.body.dataset.failed !== undefined")
        failed = page.evaluate("document.body.dataset.failed")
        if failed is not None:
            raise LsrError(f"the web site failed to start: {failed}")
        page.click("#start")
        page.wait_for_function("window.lsr.stats.faces >= 1")
        page.wait_for_timeout(warmup * 1000)
        begin, cpu_before = page.evaluate("performance.now()"), thread_times(CHROMIUM.name)
        page.wait_for_timeout(seconds * 1000)
        end, cpu_after = page.evaluate("performance.now()"), thread_times(CHROMIUM.name)
        stats = page.evaluate("window.lsr.stats")
        threads = int(page.evaluate("window.lsr.threads"))
        backend = str(page.evaluate("window.lsr.backend"))
        backend = {"wasm": "WASM", "webgpu": "WebGPU", "webnn": "WebNN"}.get(backend, backend)
        if screenshot is not None:
            with atomic_output(Path(screenshot)) as temp:
                page.screenshot(path=str(temp))
    window = [i for i, shown in enumerate(stats["shown"]) if begin <= shown <= end]
    span = (end - begin) / 1000
    result = LiveMeasure(len(window), span, len(window) / span if span > 0 else 0.0,
                         [stats["latency"][i] for i in window], [stats["ms"][i] for i in window])
    stages = {name: statistics.median(values) for name in STAGES
              if (values := [stats["stages"][i][name] for i in window if name in stats["stages"][i]])}
    seen = [count for came, count in zip(stats["cameraTimes"], stats["cameraFrames"]) if came <= end]
    before = [count for came, count in zip(stats["cameraTimes"], stats["cameraFrames"]) if came < begin]
    offered = (seen[-1] - before[-1]) if seen and before else 0
    return result, stages, threads, backend, core_shares(cpu_before, cpu_after, (end - begin) / 1000), offered


def web_markdown(web: LiveMeasure, live: LiveMeasure, stages: dict[str, float], threads: int, backend: str, camera: str,
                 site_mib: float, machine: str, cpu: dict[str, float] | None = None, cores: int | None = None, *,
                 camera_fps: int = CAMERA_FPS, offered: int | None = None) -> str:
    """The section's text. cpu: the cores Chromium kept busy while the site ran (``measure_site``); {} or None: no
    such line. offered: the camera frames that came while the site was measured (None: no such line)."""
    from lsr.bench.thread_cpu import shares_line

    def row(what: str, result: LiveMeasure, latency: str) -> str:
        p90 = f"{np.percentile(result.latency_ms, 90):.0f}" if result.latency_ms else "–"
        median = lambda values: f"{statistics.median(values):.0f}" if values else "–"  # noqa: E731
        return (f"| {what} | {result.frames} | {result.seconds:.1f} | {result.fps:.1f} | {median(result.latency_ms)} "
                f"({latency}) | {p90} | {median(result.processing_ms)} |")

    fps_ratio = web.fps / live.fps if live.fps > 0 else float("nan")
    web_latency = statistics.median(web.latency_ms) if web.latency_ms else float("nan")
    live_latency = statistics.median(live.latency_ms) if live.latency_ms else float("nan")
    lines = [f"The shipped default driving the example person; camera: {camera} at {camera_fps} fps (Chromium's "
             "fake camera; both ask for 320x240). The site: `lsr export --web`, served by a plain static server, "
             f"onnxruntime-web (the frame generator on {backend}; WASM with SIMD and {threads} threads); {site_mib:.0f} MiB.", "",
             "| where | frames shown | seconds | fps | latency ms, median | latency ms, 90th percentile | ms per frame, "
             "median |", "|---|---|---|---|---|---|---|",
             row("the web site: everything in the browser", web, "camera grab to picture drawn"),
             row("the app's live tab (`lsr bench live`), same run", live, "camera grab to picture loaded"), "",
             f"**Ratios, same run:** frame rate {fps_ratio:.2f}x the live tab's (goal >= 0.8x); median latency "
             f"{web_latency / live_latency:.2f}x (goal <= 1x).", ""]
    if offered:
        lines += [f"The page showed {web.frames} of the {offered} frames the camera sent over its window "
                  f"({web.frames / offered:.0%}): the camera's {camera_fps} fps is the most it can show.", ""]
    lines += ["In the browser, median ms per frame of each stage: " +
              ", ".join(f"{name} {ms:.1f}" for name, ms in stages.items()) + ".", ""]
    if line := shares_line(cpu or {}, cores):
        lines += [line, ""]
    return "\n".join([*lines, machine])


def run_bench_web(cfg: BenchWebConfig) -> tuple[LiveMeasure, LiveMeasure]:
    """Entry point of ``lsr bench web``."""
    from lsr.errors import ConfigError
    from lsr.eval import sections
    from lsr.export.web_site import write_site
    from lsr.eval.machine import machine_markdown, shown_path, usable_cores
    from lsr.weights import resolve_weights

    if not CHROMIUM.is_file():
        raise ConfigError(f"{CHROMIUM} not found: install Debian's chromium (apt-get install chromium)")
    with tempfile.TemporaryDirectory(prefix="lsr-bench-web-") as temp:
        temp = Path(temp)
        site = write_site(resolve_weights(cfg.weights), temp / "site")
        site_mib = sum(path.stat().st_size for path in site.files) / 2**20
        y4m = camera_file(temp / "camera.y4m", cfg.camera_video, cfg.seconds + cfg.warmup, cfg.camera_fps)
        web, stages, threads, backend, cpu, offered = measure_site(site.folder, y4m, cfg.seconds, cfg.warmup,
                                                                   cfg.screenshot)
        live = live_tab(cfg.weights, y4m, cfg.seconds, cfg.warmup, None, temp / "examples")
    camera = ("a synthetic talking person (lsr.data.synth)" if cfg.camera_video is None
              else f"`{shown_path(cfg.camera_video)}`")
    text = web_markdown(web, live, stages, threads, backend, camera, site_mib, machine_markdown(), cpu, usable_cores(),
                        camera_fps=cfg.camera_fps, offered=offered)
    sections.publish(cfg, "lsr bench web", SECTION, "The web site: everything in the browser (`lsr bench web`)", text)
    return web, live
