"""Driving expressions: set_mouth_opening, retarget_driving (the mouth as open as the driver's) and quick lips."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.shape.expression import mouth_opening, set_mouth_opening
from landmarks.motion.head_pose import project_canonical
from landmarks.motion.retarget_points import retarget_driving
from landmarks.motion.smooth import EXPRESSIVE_POINTS, OneEuroFilter, driving_cutoffs

SIDE = 128


def _face(opening: float) -> np.ndarray:
    return set_mouth_opening(project_canonical(0, 0, 0, (SIDE, SIDE), scale=0.5).astype(np.float64), opening)


@pytest.mark.parametrize("opening", [0.0, 0.12, 0.4])
def test_set_mouth_opening_reaches_the_opening_and_moves_only_jaw_and_lower_lip(opening):
    face = _face(0.05)
    opened = set_mouth_opening(face, opening)
    assert mouth_opening(opened) == pytest.approx(opening, abs=5e-3)
    moved = np.flatnonzero(np.abs(opened - face).max(1) > 1e-9)
    assert set(moved) <= {*range(3, 14), 48, 54, 55, 56, 57, 58, 59, 60, 64, 65, 66, 67}
    assert mouth_opening(set_mouth_opening(face, -1.0)) == pytest.approx(0.0, abs=5e-3)  # never crossed lips


@pytest.mark.parametrize("opening", [0.0, 0.1, 0.3])
def test_set_mouth_opening_uncrosses_crossed_lips(opening):
    """A relative retargeting can lift the lower lip above the upper one (a source's closed mouth plus a driver's
    closing delta): the distance-based opening reads that as open, and pushing the lip "down" by the difference
    used to drive it further up (openings of 0.57 from a 0.02 target, on real retargeted drives)."""
    from landmarks.shape.expression import signed_mouth_gap

    face = _face(0.05)
    crossed = face.copy()
    crossed[[65, 66, 67], 1] -= 0.25 * np.linalg.norm(face[45] - face[36])  # the lower inner lip 0.2 IOD above the upper
    down = np.array([0.0, 1.0])
    assert signed_mouth_gap(crossed, down) < -0.1 and mouth_opening(crossed) > 0.1
    fixed = set_mouth_opening(crossed, opening)
    assert mouth_opening(fixed) == pytest.approx(opening, abs=5e-3)
    assert signed_mouth_gap(fixed, down) == pytest.approx(opening, abs=5e-3)  # below the upper lip, not above


def test_retarget_driving_opens_the_mouth_as_wide_as_the_driver_even_from_an_open_anchor():
    source = _face(0.15) * 1.1 + 7  # another size and place, mouth open
    driver = np.stack([_face(0.0), _face(0.1), _face(0.3)])
    moved = retarget_driving(driver, driver[1], source)  # the driver's reference frame is half open too
    np.testing.assert_allclose(mouth_opening(moved), mouth_opening(driver), atol=2e-3)


def test_driving_filter_keeps_lips_quick_and_the_head_steady():
    cutoffs = driving_cutoffs()
    assert cutoffs.shape == (68,) and cutoffs[list(EXPRESSIVE_POINTS)].min() > cutoffs[:36].max()
    one_euro = OneEuroFilter(25.0, cutoffs, beta=0.0)
    still = _face(0.0)
    one_euro(still)
    step = one_euro(still + 10.0)  # every point jumps 10 px
    assert np.abs(step[60] - still[60]).max() > 2 * np.abs(step[30] - still[30]).max()


def test_pose_on_rigid_points_ignores_a_dropped_jaw():
    from landmarks.motion.head_pose import estimate_head_pose
    from landmarks.motion.retarget_points import RIGID_INDEX

    face = project_canonical(5, 10, 0, (256, 256)).astype(np.float64)
    opened = set_mouth_opening(face, 0.5)
    rigid = estimate_head_pose(opened, (256, 256), RIGID_INDEX)
    np.testing.assert_allclose(rigid, estimate_head_pose(face, (256, 256), RIGID_INDEX), atol=0.2)
    np.testing.assert_allclose(rigid, [5, 10, 0], atol=1.0)
