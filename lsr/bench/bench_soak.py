"""``lsr bench soak``: the app under a long live stream and many batch runs at once; does its memory hold?

The app is served in this process on 127.0.0.1 (loopback only) with the shipped default (or ``--weights``).
Chromium streams its fake camera into the live tab for ``--minutes`` while a client thread sends ``--batch-runs``
re-enactments over HTTP (gradio_client, the ``/reenact`` API: the example person driven by a bundled example).
The process's resident memory is sampled every few seconds; after the warm-up (``--warmup-minutes``) it should
stay within +-10 % of its first post-warm-up sample. The table gives the samples' range, the runs served and the
live frames shown, with machine info; it is bounded in time (minutes) and count (runs).
"""

from __future__ import annotations

import dataclasses
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from lsr.config import BenchSoakConfig

SECTION = "soak"
SAMPLE_SECONDS = 5.0
BOUND = 0.10  # resident memory after the warm-up stays within +-10 % of its first sample then


def resident_mb() -> float:
    """This process's resident memory in MB (Linux /proc; ru_maxrss elsewhere is a peak, not a level)."""
    status = Path("/proc/self/status")
    if status.is_file():
        for line in status.read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


@dataclasses.dataclass
class SoakResult:
    seconds: float
    live_frames: int
    runs_ok: int
    runs_failed: int
    samples: list[tuple[float, float]]
    """(seconds since the start, resident MB)."""
    warmup_seconds: float
    first_error: str | None = None

    @property
    def after_warmup(self) -> list[float]:
        return [mb for at, mb in self.samples if at >= self.warmup_seconds]

    @property
    def drift(self) -> tuple[float, float]:
        """(lowest, highest) post-warm-up sample relative to the first post-warm-up one (-0.05 = 5 % below)."""
        values = self.after_warmup
        if len(values) < 2:
            return float("nan"), float("nan")
        return min(values) / values[0] - 1, max(values) / values[0] - 1


def batch_runs(url: str, count: int, source: Path, driver: Path, stop: threading.Event, result: dict) -> None:
    """``count`` re-enactments through the app's /reenact API, one after another (the queue serves one at a time)."""
    from gradio_client import Client, handle_file

    client = Client(url, verbose=False)
    for _ in range(count):
        if stop.is_set():
            return
        try:
            client.predict([handle_file(str(source))], 4, handle_file(str(driver)), "relative", True, True, 0, "onnx",
                           True, api_name="/reenact")
            result["ok"] += 1
        except Exception as error:  # noqa: BLE001 - counted and named; the soak goes on
            result["failed"] += 1
            result.setdefault("first_error", f"{type(error).__name__}: {error}"[:300])


def soak(url: str, y4m: Path, minutes: float, runs: int, warmup_minutes: float, source: Path, driver: Path) -> SoakResult:
    """Stream ``y4m`` into the live tab of ``url`` for ``minutes`` while ``runs`` batch runs go through the API."""
    from lsr.bench.bench_live import live_page, wait_for_first_result

    started = time.perf_counter()
    samples: list[tuple[float, float]] = []
    counts = {"ok": 0, "failed": 0}
    stop = threading.Event()
    with live_page(url, y4m) as page:
        try:
            wait_for_first_result(page)
            worker = threading.Thread(target=batch_runs, args=(url, runs, source, driver, stop, counts), daemon=True)
            worker.start()
            while time.perf_counter() - started < minutes * 60:
                samples.append((time.perf_counter() - started, resident_mb()))
                page.wait_for_timeout(SAMPLE_SECONDS * 1000)
            frames = page.evaluate("() => window.__live.shown.length")
            stop.set()
            worker.join()
        finally:
            stop.set()
    return SoakResult(time.perf_counter() - started, int(frames), counts["ok"], counts["failed"], samples,
                      warmup_minutes * 60, counts.get("first_error"))


def soak_markdown(result: SoakResult, label: str, machine: str) -> str:
    low, high = result.drift
    values = result.after_warmup
    within = "yes" if values and -BOUND <= low and high <= BOUND else "no"
    return "\n".join([
        f"Model {label}; the live tab streamed a synthetic person from Chromium's fake camera while a client sent batch "
        "re-enactments (the example person, a bundled driver, paste-back, onnx) through /reenact, all on 127.0.0.1.",
        "",
        "| minutes | live frames shown | batch runs served / failed | resident MB after warm-up: first / min / max "
        "| drift after warm-up | within +-10 % |",
        "|---|---|---|---|---|---|",
        f"| {result.seconds / 60:.1f} | {result.live_frames} | {result.runs_ok} / {result.runs_failed} | "
        f"{values[0]:.0f} / {min(values):.0f} / {max(values):.0f} | {100 * low:+.1f} % .. {100 * high:+.1f} % | "
        f"{within} |" if values else "| – | – | – | – | – | – |",
        "",
        f"Resident memory sampled every {SAMPLE_SECONDS:g} s; warm-up: the first {result.warmup_seconds / 60:g} "
        "minutes (the model, the ONNX export, the first runs' caches)."
        + (f" First failed run: {result.first_error}" if result.first_error else ""),
        "", machine,
    ])


def run_bench_soak(cfg: BenchSoakConfig) -> SoakResult:
    """Entry point of ``lsr bench soak``."""
    from app import examples as ex
    from lsr.bench.bench_live import _free_port, camera_frames, write_y4m
    from app.ui import build_app, launch
    from lsr.config import AppConfig
    from lsr.eval import sections
    from lsr.eval.machine import machine_markdown, shown_path

    with tempfile.TemporaryDirectory(prefix="lsr-bench-soak-") as temp:
        temp = Path(temp)
        y4m = write_y4m(temp / "camera.y4m", camera_frames(None, 100))
        examples = ex.ensure_examples(temp / "examples")
        app_cfg = AppConfig(weights=cfg.weights, port=_free_port(), device="cpu", examples_dir=temp / "examples")
        app_cfg.validate()
        demo, _, files = build_app(app_cfg)
        url = launch(demo, app_cfg, files, block=False)
        try:
            result = soak(url, y4m, cfg.minutes, cfg.batch_runs, cfg.warmup_minutes, examples.source_images[0],
                          examples.driver(ex.DRIVER_EXAMPLE_VIDEO))
        finally:
            demo.close()
            files.drop_all()
    label = "the shipped default" if cfg.weights is None else f"`{shown_path(cfg.weights)}`"
    sections.publish(cfg, "lsr bench soak", SECTION, "Soak: a long live stream and batch runs (`lsr bench soak`)",
                     soak_markdown(result, label, machine_markdown()))
    return result
