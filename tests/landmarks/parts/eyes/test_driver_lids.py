"""The driver's shut eyes over the target's (landmarks.parts.eyes.driver_lids): when they are cut, where they go, their light,
and that nothing else moves."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from landmarks.parts.eyes.driver_lids import (EYES, SHUT, aperture_share, cut_driver_eyes, paste_eyes, shut_strength,
                                   similarity)
from landmarks.parts.eyes.lids import closed_gaps, lid_gaps, set_lid_gaps
from landmarks.motion.head_pose import project_canonical

SIDE = 256
SKIN = (200, 150, 130)


def _points(scale: float = 0.5, shift=(0.0, 0.0), yaw: float = 0.0) -> np.ndarray:
    return project_canonical(yaw, 0, 0, (SIDE, SIDE), scale=scale).astype(np.float64) + shift


def _shut(points: np.ndarray, share: float) -> np.ndarray:
    """The face with its lids at ``share`` of the aperture between their closed and their present gaps."""
    rest = lid_gaps(points)
    return set_lid_gaps(points, closed_gaps(rest) + share * (rest - closed_gaps(rest)))


def _face(points: np.ndarray, skin=SKIN, shut: bool = False) -> np.ndarray:
    """A flat face: skin, and per eye either a white eye with a blue iris (open) or a dark lash line along the
    lower lid (shut)."""
    image = np.zeros((SIDE, SIDE, 3), np.uint8)
    image[:] = skin
    for eye in EYES:
        contour = np.round(points[eye]).astype(np.int32)
        if shut:
            cv2.polylines(image, [contour[[0, 5, 4, 3]]], False, (40, 30, 30), 2)
        else:
            cv2.fillPoly(image, [contour], (245, 245, 245))
            centre = np.round(points[eye].mean(axis=0)).astype(int)
            cv2.circle(image, tuple(int(v) for v in centre), 4, (40, 80, 160), -1)
    return image


def test_the_share_and_strength_follow_the_driver_lids_against_its_own_at_rest():
    points = _points()
    rest = lid_gaps(points)
    assert aperture_share(points, rest) == pytest.approx(1.0)
    assert aperture_share(_shut(points, 0.0), rest) == pytest.approx(0.0, abs=1e-9)
    assert shut_strength(points, rest, 0.0) == 0.0  # open: nothing laid in
    assert shut_strength(_shut(points, SHUT[0]), rest, 0.0) == pytest.approx(1.0)
    assert shut_strength(_shut(points, np.mean(SHUT)), rest, 0.0) == pytest.approx(0.5, abs=1e-6)
    assert shut_strength(_shut(points, 0.0), rest, 60.0) == 0.0  # a head turned past TURN
    assert shut_strength(_shut(points, 0.0), np.full(2, np.nan), 0.0) == 0.0


def test_open_eyes_are_not_cut_and_shut_ones_are():
    points = _points()
    rest = lid_gaps(points)
    assert cut_driver_eyes(_face(points), points, rest) is None
    shut = _shut(points, 0.1)
    eyes = cut_driver_eyes(_face(shut, shut=True), shut, rest)
    assert eyes is not None and eyes.strength == pytest.approx(1.0)
    assert eyes.patch.shape[0] < SIDE / 2 and eyes.corners.shape == (2, 2, 2)
    assert cut_driver_eyes(_face(shut), np.full((68, 2), np.nan), rest) is None
    with pytest.raises(ValueError):
        cut_driver_eyes(_face(shut)[..., 0], shut, rest)


def test_the_similarity_takes_the_corners_exactly():
    source, target = np.array([[10.0, 20.0], [30.0, 25.0]]), np.array([[100.0, 50.0], [90.0, 80.0]])
    matrix = similarity(source, target)
    np.testing.assert_allclose(source @ matrix[:, :2].T + matrix[:, 2], target, atol=1e-9)
    assert matrix[0, 0] == pytest.approx(matrix[1, 1]) and matrix[0, 1] == pytest.approx(-matrix[1, 0])


def test_shut_lids_cover_the_target_eyes_and_nothing_else_moves():
    driver_points = _shut(_points(scale=0.4, shift=(-20, 10)), 0.0)
    driver = _face(driver_points, shut=True)
    eyes = cut_driver_eyes(driver, driver_points, lid_gaps(_points(scale=0.4, shift=(-20, 10))))
    target_points = _points(scale=0.55)
    target = _face(target_points)  # open: white eyes, blue irises
    result = paste_eyes(target, target_points, eyes)
    for eye in EYES:
        inside = np.zeros((SIDE, SIDE), np.uint8)
        cv2.fillPoly(inside, [np.round(target_points[eye]).astype(np.int32)], 1)
        pixels = result[inside > 0].astype(int)
        assert (pixels[:, 2] < pixels[:, 0] + 20).all() and pixels.min(axis=-1).max() < 180  # no iris, no white
        x, y = np.round(target_points[eye][[0, 3]].mean(axis=0)).astype(int)  # the lash line, on the corner line
        assert result[y - 3:y + 4, x].max(axis=-1).min() < 120
    changed = np.abs(result.astype(int) - target.astype(int)).max(axis=-1) > 0
    assert changed.any()
    mouth_and_jaw = np.zeros((SIDE, SIDE), bool)
    top = int(target_points[31:36, 1].min())  # from the nostrils down nothing moves
    mouth_and_jaw[top:] = True
    assert not (changed & mouth_and_jaw).any()
    assert paste_eyes(target, target_points, None) is target


@pytest.mark.parametrize("skin", [tuple(int(0.7 * c) for c in SKIN), (150, 150, 175)])  # darker; bluish grey
def test_the_lids_take_the_target_light_and_colour(skin):
    driver_points = _shut(_points(), 0.0)
    eyes = cut_driver_eyes(_face(driver_points, skin=skin, shut=True), driver_points, lid_gaps(_points()))
    target_points = _points()
    result = paste_eyes(_face(target_points), target_points, eyes)
    for eye in EYES:
        corners = target_points[eye][[0, 3]]
        x, y = np.round(corners.mean(axis=0) - (0, 0.4 * np.ptp(corners[:, 0]))).astype(int)  # the upper lid's skin
        assert np.abs(result[y, x].astype(int) - SKIN).max() <= 6  # skin laid on skin: the whole colour cast
