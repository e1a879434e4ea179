"""``lsr bench soak`` in miniature: a live stream and a batch run through one served app, memory sampled throughout.

The real soak (10 minutes, 50 runs, the +-10 % bound) is `lsr bench soak --out-md BENCHMARKS.md`; here only that it
runs, serves both at once and measures (no bound asserted on a 20-second run)."""

from __future__ import annotations

import pytest

from .test_app_browser import CHROMIUM

pytestmark = pytest.mark.slow


def test_live_stream_and_batch_runs_are_served_together(app_server, app_inputs, tmp_path):
    if not CHROMIUM.is_file():
        pytest.skip(f"{CHROMIUM} not found: install Debian's chromium (apt-get install chromium) to run browser tests")
    pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")
    from lsr.bench.bench_live import camera_frames, write_y4m
    from lsr.bench.bench_soak import soak, soak_markdown

    y4m = write_y4m(tmp_path / "camera.y4m", camera_frames(None, 25))
    result = soak(app_server, y4m, minutes=0.35, runs=1, warmup_minutes=0.1, source=app_inputs["source"],
                  driver=app_inputs["driver"])
    assert result.runs_ok == 1 and result.runs_failed == 0
    assert result.live_frames > 0 and len(result.samples) >= 3 and all(mb > 0 for _, mb in result.samples)
    assert "| yes |" in soak_markdown(result, "tiny", "") or "| no |" in soak_markdown(result, "tiny", "")
