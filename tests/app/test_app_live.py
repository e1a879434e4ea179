"""The live tab in a real browser: Chromium's fake camera plays a .y4m made here (the shared real driver clip, or a
synthetic person when it is absent), the stream starts and re-enacted frames with a face come back.

Frame rate and latency are recorded (printed; `lsr bench live` writes them to BENCHMARKS.md), never asserted: the
machines are shared. Skips without /usr/bin/chromium or playwright, like the other browser tests."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from .test_app_browser import CHROMIUM

pytestmark = pytest.mark.slow
STREAM_SECONDS = 6.0


@pytest.fixture(scope="module")
def camera_file(tmp_path_factory):
    from lsr.bench.bench_live import camera_frames, write_y4m

    root = Path(__file__).resolve().parents[2]
    clip = Path(os.environ.get("LSR_SHARED_DATA", root.parent / "shared" / "data")) / "clips" / "tpsmm_driving.mp4"
    frames = camera_frames(clip if clip.is_file() else None, 50)
    return write_y4m(tmp_path_factory.mktemp("camera") / "camera.y4m", frames)


def test_the_webcam_drives_the_person_live(app_server, camera_file, tmp_path):
    if not CHROMIUM.is_file():
        pytest.skip(f"{CHROMIUM} not found: install Debian's chromium (apt-get install chromium) to run browser tests")
    pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")
    from lsr.bench.bench_live import run_live
    from landmarks.detect.face_detector import DlibDetector
    from landmarks.io.image_files import read_image

    shot = tmp_path / "live.png"
    result = run_live(app_server, camera_file, STREAM_SECONDS, 1.0, shot)
    print(f"live: {result.frames} frames in {result.seconds:.1f} s ({result.fps:.1f} fps), latency median "
          f"{np.median(result.latency_ms) if result.latency_ms else float('nan'):.0f} ms")
    assert result.frames >= 2 and result.latency_ms and all(ms > 0 for ms in result.latency_ms)
    assert result.output is not None and result.output.ndim == 3
    assert DlibDetector("hog").detect(result.output), "the re-enacted frame shows no face"
    assert read_image(shot).shape[0] > 0  # the README's picture comes from `lsr bench live --screenshot`
