"""landmarks.parts.appearance: the iris's place and contrast and the mouth's inside, read from pixels, on drawn faces
whose answer is known (and on a real photo)."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.parts.appearance import gaze, iris_contrast, iris_offset, mouth_interior

SKIN = (190, 150, 130)


@pytest.mark.parametrize("offset", [-0.15, 0.0, 0.15])
def test_iris_offset_finds_a_drawn_iris(drawn_face, offset):
    image, points = drawn_face((offset,))
    found = iris_offset(image, points)
    np.testing.assert_allclose(found[:, 0], offset, atol=0.03)
    np.testing.assert_allclose(found[:, 1], 0.0, atol=0.05)
    assert gaze(image, points)[0] == pytest.approx(offset, abs=0.03)


def test_a_doubled_iris_loses_about_half_its_contrast(drawn_face):
    single = iris_contrast(*drawn_face((0.0,)))
    doubled = iris_contrast(*drawn_face((-0.15, 0.15)))
    assert single > 0.7 and doubled < 0.65 * single


def test_closed_eyes_have_no_iris_and_missing_landmarks_give_nan(drawn_face):
    image, points = drawn_face(eyes=0.1)
    assert np.isnan(iris_offset(image, points)).all() and np.isnan(iris_contrast(image, points))
    assert np.isnan(gaze(image, points)).all()
    assert np.isnan(iris_offset(image, np.full((68, 2), np.nan))).all()
    with pytest.raises(ValueError, match="uint8"):
        iris_offset(image.astype(np.float32), points)
    with pytest.raises(ValueError, match="68, 2"):
        iris_contrast(image, points[:10])


def test_mouth_interior_tells_a_cavity_from_teeth_and_lips(drawn_face):
    cavity, teeth = mouth_interior(*drawn_face(mouth=0.3, inside=(30, 20, 20)))
    grey = lambda rgb: 0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]  # noqa: E731
    assert cavity == pytest.approx(grey((30, 20, 20)) / grey(SKIN), abs=0.03) and teeth == 0.0
    _, white = mouth_interior(*drawn_face(mouth=0.3, inside=(240, 240, 235)))
    assert white > 0.9
    lips, red = mouth_interior(*drawn_face(mouth=0.3, inside=(200, 60, 70)))
    assert lips > 2 * cavity and red == 0.0
    assert np.isnan(mouth_interior(*drawn_face(mouth=0.0))).all()  # closed: no inside to look at


def test_a_real_photo_reads_as_open_eyes_looking_ahead(drawn_face, astronaut, mesh_detector):
    points = mesh_detector.detect(astronaut)[0].landmarks
    offsets = iris_offset(astronaut, points)
    assert np.isfinite(offsets).all() and (np.abs(offsets[:, 0]) < 0.15).all()
    assert 0.5 < iris_contrast(astronaut, points) < 1.0
