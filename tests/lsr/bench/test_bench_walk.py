"""lsr bench walk: one frame's path through `lsr reenact --paste-back`, room by room."""

from __future__ import annotations

import pytest

from lsr.bench.bench_walk import _one_frame, walk, walk_markdown


def test_one_frame_keeps_the_first_whole_frame_and_merges_repeats():
    entered = ["a", "|", "b", "b", "c", "b", "|", "d", "|"]
    assert _one_frame(entered) == ["b", "c", "b"]
    assert _one_frame(["|", "x", "x"]) == ["x"]
    assert "| 2 | 1 |" in walk_markdown({"MainThread": ["b", "c", "b"]})  # 2 modules, 1 re-entry


@pytest.mark.slow
def test_the_walk_of_the_bundled_example_enters_each_stage_room_in_order():
    from lsr.examples import REAL_DRIVER, REAL_SOURCE

    walked = walk(REAL_SOURCE, REAL_DRIVER, frame=6)
    network = walked["MainThread"]
    assert network.index("lsr.pipeline") < network.index("lsr.core.finish")  # the networks, then the parts
    assert all(len(modules) == len(set(modules)) for modules in walked.values()), walked  # no room entered twice
    assert any(thread.startswith("lsr-finish") and modules == ["lsr.core.scene"] for thread, modules in walked.items())
    preparing = walked["lsr-prefetch"]
    assert preparing.index("landmarks.align") < preparing.index("landmarks.warp.piecewise_affine")  # crop, then warps
