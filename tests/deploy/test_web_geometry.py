"""The web runtime's geometry (deploy/web/src/geometry.ts) against landmarks.align and landmarks.motion.retarget_points."""

from __future__ import annotations

import numpy as np

from landmarks.align import crop_transform, invert_affine, transform_landmarks
from landmarks.motion.head_pose import project_canonical
from landmarks.motion.retarget_points import similarity_procrustes


def test_crop_transform_points_and_inverse_match_python(web, rng):
    points = project_canonical(12.0, -8.0, 5.0, (480, 640), scale=0.4, translation=(40, -10)).astype(np.float64)
    matrix = crop_transform(points, 256)
    got, moved, inverse = web.calls(("cropTransform", [points, 256]), ("transformPoints", [points, list(matrix.ravel())]),
                                    ("invertAffine", [list(matrix.ravel())]))
    np.testing.assert_allclose(np.reshape(got, (2, 3)), matrix, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(moved, transform_landmarks(points, matrix), atol=1e-9)
    np.testing.assert_allclose(np.reshape(inverse, (2, 3)), invert_affine(matrix), atol=1e-9)


def test_similarity_procrustes_matches_python(web, rng):
    source = rng.normal(size=(68, 2)) * 40 + 100
    angle, scale = 0.3, 1.7
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    target = scale * source @ rotation.T + [5.0, -9.0] + rng.normal(size=(68, 2))
    expected = similarity_procrustes(source, target)
    got = web.call("similarityProcrustes", source, target)
    assert abs(got["scale"] - expected[0]) < 1e-9
    np.testing.assert_allclose(np.reshape(got["rotation"], (2, 2)), expected[1], atol=1e-12)
    np.testing.assert_allclose(got["translation"], expected[2], atol=1e-9)


def test_errors_come_back_as_python_errors(web):
    import pytest

    with pytest.raises(RuntimeError, match="68, 2"):
        web.call("cropTransform", np.zeros((5, 2)), 256)
