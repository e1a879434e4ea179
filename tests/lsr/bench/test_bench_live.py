"""lsr bench live's table: the handler's rate with and without the eye bank, and their ratio (issue 63's speed bar)."""

from __future__ import annotations

import pytest

from lsr.bench.bench_live import LiveMeasure, live_markdown


def measure(fps: float) -> LiveMeasure:
    return LiveMeasure(frames=int(fps * 3), seconds=3.0, fps=fps, latency_ms=[20.0, 30.0], processing_ms=[25.0])


def test_the_table_gives_the_bank_less_row_and_the_banks_cost_as_a_ratio():
    text = live_markdown(measure(10.0), measure(30.0), "the shipped default", "a camera", "machine", [40.0],
                         no_bank=measure(40.0))
    assert "| the same, without the eye bank (`bank` none) | 120 | 3.0 | 40.0 |" in text
    assert "with it 0.75x its rate without it" in text


@pytest.mark.parametrize("server", [None, measure(30.0)])
def test_without_the_bank_less_measure_the_table_has_no_ratio(server):
    text = live_markdown(measure(10.0), server, "the shipped default", "a camera", "machine")
    assert "without the eye bank" not in text and "The eye bank's cost" not in text


def test_the_cores_the_app_and_chromium_kept_busy_are_given_when_measured():
    browser = measure(20.0)
    browser.cores = {"the app": 0.95, "Chromium": 0.85, "all": 1.80}
    text = live_markdown(browser, None, "the shipped default", "a camera", "machine")
    assert "Over the window the app kept 0.95 cores busy and Chromium 0.85, 1.80 of " in text
    for cores in (None, {}):  # not measured, or /proc unreadable
        browser.cores = cores
        assert "cores busy" not in live_markdown(browser, None, "the shipped default", "a camera", "machine")
