"""``landmarks.shape.edit``: each slider moves the face the way its name says, measured with the project's own measures."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.shape.edit import edit_landmarks
from landmarks.shape.expression import eye_opening, mouth_opening
from landmarks.motion.head_pose import estimate_head_pose, project_canonical

SIZE = (256, 256)


@pytest.fixture
def face() -> np.ndarray:
    return project_canonical(0.0, 0.0, 0.0, SIZE).astype(np.float64)


def test_defaults_change_nothing(face):
    np.testing.assert_allclose(edit_landmarks(face), face)


def test_mouth_eyes_smile_brows(face):
    assert mouth_opening(edit_landmarks(face, mouth=0.3)) == pytest.approx(mouth_opening(face) + 0.3, abs=0.02)
    assert eye_opening(edit_landmarks(face, eyes=0.0)) == pytest.approx(0.0, abs=1e-9)
    assert eye_opening(edit_landmarks(face, eyes=1.5)) == pytest.approx(1.5 * eye_opening(face), rel=1e-6)
    smiling = edit_landmarks(face, smile=0.1)
    assert smiling[48, 1] < face[48, 1] and smiling[54, 1] < face[54, 1]  # corners up
    assert smiling[54, 0] - smiling[48, 0] > face[54, 0] - face[48, 0]  # and apart
    raised = edit_landmarks(face, brows=0.1)
    assert (raised[17:27, 1] < face[17:27, 1]).all() and (raised[:17] == face[:17]).all()
    with pytest.raises(ValueError, match="eyes"):
        edit_landmarks(face, eyes=-1)


@pytest.mark.parametrize(("yaw", "pitch", "roll"), [(15, 0, 0), (0, 10, 0), (0, 0, 12), (-10, -8, 5)])
def test_head_pose_follows_the_angles(face, yaw, pitch, roll):
    measured = estimate_head_pose(edit_landmarks(face, yaw=yaw, pitch=pitch, roll=roll), SIZE)
    np.testing.assert_allclose(measured, [yaw, pitch, roll], atol=3.0)
