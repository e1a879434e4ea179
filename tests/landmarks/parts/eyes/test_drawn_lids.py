"""The subject's own lids drawn down where the target shuts its eyes (landmarks.parts.eyes.drawn_lids): how far, where, with
what, and that nothing else moves."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from landmarks.parts.eyes.drawn_lids import draw_lids, lash_line, lid_strength, shot_lid_gaps
from landmarks.parts.eyes.driver_lids import EYES, SHUT
from landmarks.parts.eyes.lids import closed_gaps, lid_gaps, set_lid_gaps
from landmarks.motion.head_pose import project_canonical

SIDE = 256
SKIN = np.array([200, 150, 130])
WHITE, IRIS = (245, 245, 245), (40, 80, 160)


def _points(yaw: float = 0.0, scale: float = 0.5) -> np.ndarray:
    return project_canonical(yaw, 0, 0, (SIDE, SIDE), scale=scale).astype(np.float64)


def _shut(points: np.ndarray, share: float) -> np.ndarray:
    """The face with its lids at ``share`` of the aperture between their closed and their present gaps."""
    rest = lid_gaps(points)
    return set_lid_gaps(points, closed_gaps(rest) + share * (rest - closed_gaps(rest)))


def _open_face(points: np.ndarray, iris: bool = True) -> np.ndarray:
    """A flat face with its eyes open as ``points`` draw them: white eyes, a blue iris in each, skin with a gentle
    gradient (so that the filled-in lid has something to follow)."""
    rows = np.linspace(-12, 12, SIDE)[:, None, None]
    image = np.clip(SKIN + rows, 0, 255).astype(np.uint8).repeat(SIDE, axis=1)
    for eye in EYES:
        cv2.fillPoly(image, [np.round(points[eye]).astype(np.int32)], WHITE)
        if not iris:
            continue
        centre = np.round(points[eye].mean(axis=0)).astype(int)
        cv2.circle(image, (int(centre[0]), int(centre[1])), 4, IRIS, -1)
    return image


def _eye_box(points: np.ndarray, eye: slice, margin: int = 3) -> tuple[slice, slice]:
    low, high = np.floor(points[eye].min(axis=0)).astype(int) - margin, np.ceil(points[eye].max(axis=0)).astype(int)
    return slice(low[1], high[1] + margin + 1), slice(low[0], high[0] + margin + 1)


def test_the_strength_follows_the_target_lids_against_the_shots():
    points = _points()
    rest = lid_gaps(points)
    assert lid_strength(points, rest) == 0.0
    assert lid_strength(_shut(points, SHUT[1] + 0.05), rest) == 0.0
    assert lid_strength(_shut(points, np.mean(SHUT)), rest) == pytest.approx(0.5, abs=1e-6)
    assert lid_strength(_shut(points, SHUT[0]), rest) == pytest.approx(1.0)
    assert lid_strength(_shut(points, 0.0), rest) == 1.0
    assert lid_strength(_shut(points, 0.0), np.full(2, np.nan), ) == 0.0
    shots = np.stack([points, _shut(points, 0.0), points])  # one blinking shot does not move the lids at rest
    np.testing.assert_allclose(shot_lid_gaps(shots), rest)


def test_open_eyes_are_left_as_they_are():
    points = _points()
    image = _open_face(points)
    assert draw_lids(image, points, lid_gaps(points)) is image
    assert draw_lids(image, _shut(points, 0.0), np.full(2, np.nan)) is image


def test_shut_lids_hide_the_white_and_the_iris_and_nothing_else_moves():
    points = _points()
    rest = lid_gaps(points)
    image = _open_face(points)  # the warps show the shots' open eyes
    target = _shut(points, 0.1)  # where the target's lids have shut
    drawn = draw_lids(image, target, rest)
    changed = np.abs(drawn.astype(int) - image.astype(int)).max(axis=2) > 0
    for eye in EYES:
        rows, cols = _eye_box(points, eye)
        inside = drawn[rows, cols].astype(int)
        assert inside.min(axis=(0, 1))[2] > 0.5 * SKIN[2] - 15  # no blue iris left (the lash line halves the skin)
        assert (inside.sum(axis=2) < 3 * 230).all()  # no white
        skin = np.clip(SKIN + np.linspace(-12, 12, SIDE)[rows.start:rows.stop, None], 0, 255)
        assert np.median(np.abs(inside - skin[:, None]).max(axis=2)) < 25  # skin filled in, lit as around it
    ys, xs = np.nonzero(changed)
    scale = np.linalg.norm(points[36:42].mean(axis=0) - points[42:48].mean(axis=0))
    assert ys.max() < points[30, 1] and ys.min() > points[17:27, 1].min() - 0.5 * scale  # the lids, not the face
    assert xs.min() > points[0, 0] and xs.max() < points[16, 0]


def test_a_half_shut_eye_keeps_the_lower_part_of_its_opening():
    points = _points(scale=1.2)  # eyes 34 px wide, 12 px open
    rest = lid_gaps(points)
    image = _open_face(points, iris=False)
    target = _shut(points, np.mean(SHUT) - 0.05)  # strength 0.7: the drawn margin at 0.3 of the target's gap
    drawn = draw_lids(image, target, rest)
    for eye in EYES:
        corners = points[eye][[0, 3]].mean(axis=0)
        above = np.round(corners + 0.7 * (points[eye][[1, 2]].mean(axis=0) - corners)).astype(int)  # the lid's now
        lower = points[eye][[4, 5]].mean(axis=0)
        column = [drawn[int(round(y)), int(round(lower[0]))].astype(int).sum()
                  for y in np.linspace(target[eye][[1, 2], 1].mean(), lower[1], 8)]
        assert drawn[above[1], above[0]].astype(int).sum() < 3 * 200  # skin, not white
        assert max(column) > (SKIN + 12).sum()  # brighter than any skin: the white shows (in the lashes' shade)


def test_the_lash_line_peaks_on_the_polyline():
    line = lash_line(np.array([[2.0, 5.0], [12.0, 5.0]]), 1.5, (10, 16))
    assert line[5, 2:13].min() == pytest.approx(1.0)
    assert line[5 + 3, 7] == pytest.approx(np.exp(-9 / (2 * 1.5 ** 2)), rel=1e-5)
    assert line[0, 15] < 0.01


def test_a_turned_face_far_eye_is_drawn_without_error():
    points = _points(yaw=40)
    target = _shut(points, 0.0)
    drawn = draw_lids(_open_face(points), target, lid_gaps(points))
    assert drawn.shape == (SIDE, SIDE, 3) and drawn.dtype == np.uint8
