"""A person's matte (landmarks.scene.person_matte): MediaPipe's selfie segmenter, shipped beside the face models."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.scene.person_matte import person_matte


def test_the_bundled_speaker_is_matted_with_her_hair_against_the_wall():
    from landmarks.detect.registry import make_detector
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_SOURCE

    frame = next(iter(iter_frames(REAL_SOURCE)))
    matte = person_matte(frame)
    assert matte.shape == frame.shape[:2] and matte.dtype == np.float32 and 0.0 <= matte.min() <= matte.max() <= 1.0
    points = make_detector().detect(frame)[0].landmarks
    inside = np.round(points[[30, 8, 19, 24]]).astype(int)  # nose, chin, brows: the person
    assert (matte[inside[:, 1], inside[:, 0]] > 0.9).all()
    top = int(points[:, 1].min()) - 10  # above the brows: her hair, wider than the face
    left, right = int(points[:, 0].min()), int(points[:, 0].max())
    assert matte[top, (left + right) // 2] > 0.9
    assert matte[:15, :15].max() < 0.1 and matte[:15, -15:].max() < 0.1  # the wall behind her
    assert 0.15 < (matte > 0.5).mean() < 0.6


def test_a_frame_of_any_size_and_a_clear_error_otherwise():
    assert person_matte(np.zeros((37, 300, 3), np.uint8)).shape == (37, 300)
    with pytest.raises(ValueError, match="uint8"):
        person_matte(np.zeros((10, 10), np.uint8))
