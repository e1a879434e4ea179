"""lsr bench plate (lsr.bench.bench_plate): the plate's fill beside a person, against the real background."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.motion.head_pose import project_canonical
from landmarks.scene.compositing import PLATE_TRUST, face_side
from lsr.config.bench_options import BenchPlateConfig
from lsr.errors import ConfigError
from lsr.bench import bench_plate


def _person_on_two_walls() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A person (a red ellipse) on a white wall, with a dark doorway across the frame."""
    height, width = 240, 320
    points = project_canonical(0, 0, 0, (height, width), scale=0.55, translation=(30, -5)).astype(np.float64)
    frame = np.full((height, width, 3), 230, np.uint8)
    frame[:, : width // 5] = 40
    rows, cols = np.mgrid[0:height, 0:width]
    centre, side = points.mean(0), face_side(points)
    matte = (np.hypot((cols - centre[0]) / (0.3 * side), (rows - centre[1]) / (0.45 * side)) <= 1).astype(np.float32)
    frame[matte > 0] = (200, 80, 60)
    return frame, points, matte


def test_the_band_beside_the_person_is_guessed_better_with_the_shipped_trust():
    frame, points, matte = _person_on_two_walls()
    errors = bench_plate.band_errors(frame, points, matte, (1.0, PLATE_TRUST))
    assert errors is not None and errors[PLATE_TRUST] < 0.5 * errors[1.0]  # the doorway's grey no longer shows
    assert errors[PLATE_TRUST] < 10.0
    # no background beside the person (the matte covers the frame): nothing to measure
    assert bench_plate.band_errors(frame, points, np.ones_like(matte), (1.0,)) is None


def test_the_table_marks_the_shipped_trust_and_the_config_refuses_what_it_cannot_measure(tmp_path):
    text = bench_plate.plate_markdown({1.0: [18.0, 10.0], PLATE_TRUST: [13.0, 6.0]}, 2,
                                      {"data": "clips", "frame": 10, "side": 384, "band": 0.08}, "| machine | |")
    assert f"| {PLATE_TRUST:g} (shipped) | 2 | 9.50 | 9.50 |" in text and "| 1 | 2 | 14.00 | 14.00 |" in text
    with pytest.raises(ConfigError, match="trusts"):
        BenchPlateConfig(data=tmp_path, trusts=(0.5,)).validate()
    with pytest.raises(ConfigError, match="not a folder"):
        BenchPlateConfig(data=tmp_path / "missing").validate()
    (tmp_path / "a" / "src").mkdir(parents=True)
    (tmp_path / "a" / "src" / "2.mp4").write_bytes(b"")
    (tmp_path / "a" / "src" / "1.mp4").write_bytes(b"")
    (tmp_path / "b").mkdir()
    assert bench_plate.first_clips(tmp_path) == [("a", tmp_path / "a" / "src" / "1.mp4")]
