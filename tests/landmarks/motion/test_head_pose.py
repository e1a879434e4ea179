"""Head pose: known rotations of the canonical face are recovered with the documented signs."""

from __future__ import annotations

import numpy as np
import pytest
import skimage.data

from landmarks.shape.ibug68 import MIRROR_INDEX
from landmarks.motion.head_pose import (
    CANONICAL_FACE_3D,
    angles_from_rotation,
    build_canonical_face,
    estimate_head_pose,
    project_canonical,
    rotation_matrix,
)

SIZE = (480, 640)
ANGLES = [
    (0.0, 0.0, 0.0),
    (35.0, 0.0, 0.0),
    (-60.0, 5.0, 0.0),
    (60.0, -10.0, 10.0),
    (0.0, 30.0, 0.0),
    (0.0, -30.0, 0.0),
    (0.0, 0.0, 20.0),
    (-25.0, 20.0, -15.0),
    (45.0, -25.0, 18.0),
    (-40.0, -15.0, -20.0),
]


def test_canonical_face_shape_and_layout():
    face = build_canonical_face()
    assert face.shape == (68, 3) and np.allclose(face, CANONICAL_FACE_3D)
    assert np.allclose(face.mean(axis=0), 0.0)
    assert face[30, 2] == face[:, 2].min()  # the nose tip is closest to the camera
    assert face[0, 0] < face[8, 0] < face[16, 0] and face[8, 1] == face[:, 1].max()


@pytest.mark.parametrize("yaw, pitch, roll", ANGLES)
def test_rotation_round_trip(yaw, pitch, roll):
    assert np.allclose(angles_from_rotation(rotation_matrix(yaw, pitch, roll)), (yaw, pitch, roll), atol=1e-6)


@pytest.mark.parametrize("yaw, pitch, roll", ANGLES)
def test_recovers_known_pose_from_noisy_projection(yaw, pitch, roll, rng):
    points = project_canonical(yaw, pitch, roll, SIZE, translation=(30.0, -20.0))
    noisy = points + rng.normal(0.0, 0.5, points.shape).astype(np.float32)  # dlib-like half-pixel noise
    estimate = estimate_head_pose(noisy, SIZE)
    assert np.abs(estimate - np.array([yaw, pitch, roll])).max() < 2.0


def test_sign_conventions_in_image_terms():
    frontal = project_canonical(0, 0, 0, SIZE)
    assert project_canonical(30, 0, 0, SIZE)[30, 0] > frontal[30, 0] + 10  # yaw > 0: nose to image right
    assert project_canonical(0, 20, 0, SIZE)[30, 1] < frontal[30, 1] - 10  # pitch > 0: nose up
    rolled = project_canonical(0, 0, 15, SIZE)
    assert rolled[45, 1] > rolled[36, 1] + 10  # roll > 0: clockwise, image-right eye drops
    # The mirror image of a face yawed one way is yawed the other way.
    yawed = project_canonical(25, 0, 0, SIZE)
    flipped = yawed[list(MIRROR_INDEX)].copy()
    flipped[:, 0] = SIZE[1] - flipped[:, 0]
    assert estimate_head_pose(flipped, SIZE)[0] == pytest.approx(-25.0, abs=1.0)


def test_missing_landmarks_give_nan_and_bad_shape_raises():
    assert np.isnan(estimate_head_pose(np.full((68, 2), np.nan), SIZE)).all()
    with pytest.raises(ValueError, match="68, 2"):
        estimate_head_pose(np.zeros((5, 2)), SIZE)


def test_astronaut_is_near_frontal():
    from landmarks.detect.registry import make_detector

    image = skimage.data.astronaut()
    yaw, pitch, roll = estimate_head_pose(make_detector().detect_one(image).landmarks, image.shape[:2])
    assert abs(yaw) < 30 and abs(pitch) < 30 and abs(roll) < 15
