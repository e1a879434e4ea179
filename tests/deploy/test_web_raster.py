"""The web runtime's landmark image (deploy/web/src/raster.ts) against landmarks.shape.raster.draw_landmarks."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from landmarks.motion.head_pose import project_canonical
from landmarks.shape.raster import draw_landmarks


@pytest.mark.parametrize("size", [64, 256])
def test_the_landmark_image_is_pythons_up_to_its_strokes_edges(web, size):
    faces = [project_canonical(yaw, pitch, roll, (size, size)).astype(np.float64)
             for yaw, pitch, roll in ((0, 0, 0), (25, -10, 8), (-35, 15, -12))]
    drawn = web.calls(*(("drawLandmarks", [points, size]) for points in faces))
    for points, image in zip(faces, drawn):
        expected = draw_landmarks(points, size)
        assert image.shape == expected.shape and image.dtype == np.uint8
        ink, expected_ink = image.reshape(-1, 3).sum(0), expected.reshape(-1, 3).sum(0)  # each colour's ink
        np.testing.assert_allclose(ink, expected_ink, rtol=0.2)
        soft, expected_soft = (cv2.GaussianBlur(picture.astype(np.float32), (0, 0), 1.0) for picture in (image, expected))
        assert np.corrcoef(soft.ravel(), expected_soft.ravel())[0, 1] > 0.9  # in the same places


def test_a_missing_face_draws_nothing(web):
    assert not web.call("drawLandmarks", np.full((68, 2), np.nan), 64).any()
