"""A part's window (landmarks.parts.part_window): where it sits, what the masks cover, and that pasting back is exact."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from landmarks.shape.expression import set_mouth_opening
from landmarks.parts.part_window import (MOUTH, extract, lip_masks, paste, paste_weight, to_window, window_eye_distance,
                                   window_transform)
from landmarks.motion.head_pose import project_canonical
from landmarks.shape.measures import inter_ocular_distance

SIDE = 256


def _face(opening: float = 0.3, roll: float = 0.0) -> np.ndarray:
    return set_mouth_opening(project_canonical(0, 0, roll, (SIDE, SIDE), scale=0.5).astype(np.float64), opening)


@pytest.mark.parametrize("roll", [0.0, 20.0])
def test_the_window_is_centred_on_the_lips_level_with_the_eyes_at_the_span_asked(roll):
    face = _face(roll=roll)
    transform = window_transform(face)
    points = to_window(face, transform)
    centre = points[48:60].mean(axis=0)
    assert centre == pytest.approx([(MOUTH.size - 1) / 2] * 2, abs=1e-6)
    eyes = points[36:42].mean(axis=0), points[42:48].mean(axis=0)
    assert eyes[1][1] - eyes[0][1] == pytest.approx(0.0, abs=1e-6)  # the eye line is level in the window
    assert float(inter_ocular_distance(points)) == pytest.approx(window_eye_distance(MOUTH), rel=1e-6)
    assert (points[48:68] > 0).all() and (points[48:68] < MOUTH.size - 1).all()  # the whole mouth is inside


def test_missing_landmarks_give_no_window():
    face = _face()
    face[3] = np.nan
    assert window_transform(face) is None
    with pytest.raises(ValueError):
        window_transform(face[:60])


def test_lip_masks_cover_the_lips_and_an_open_mouth_only_when_it_opens():
    open_points = to_window(_face(0.3), window_transform(_face(0.3)))
    outer, inside = lip_masks(open_points, MOUTH.size)
    centre = np.round(open_points[60:68].mean(axis=0)).astype(int)
    assert inside[centre[1], centre[0]] == pytest.approx(1.0) and outer[centre[1], centre[0]] == pytest.approx(1.0)
    assert outer[2, 2] == 0 and inside[2, 2] == 0
    assert inside.sum() < outer.sum()
    closed = to_window(_face(0.0), window_transform(_face(0.0)))
    assert lip_masks(closed, MOUTH.size)[1].sum() < 0.2 * inside.sum()  # a line: the lips meet


def test_paste_weight_takes_the_lips_and_fades_before_the_window_edge():
    points = to_window(_face(0.3), window_transform(_face(0.3)))
    weight = paste_weight(points, MOUTH.size, window_eye_distance(MOUTH))
    for x, y in np.round(points[48:60]).astype(int):
        assert weight[y, x] > 0.95
    assert np.abs(weight[[0, -1]]).max() == 0 and np.abs(weight[:, [0, -1]]).max() == 0
    nose = np.round(points[30]).astype(int)
    assert weight[nose[1], nose[0]] < 1e-3


def test_extract_then_paste_puts_the_drawn_window_under_its_weight_and_leaves_the_rest(rng):
    face = _face(0.3, roll=10.0)
    image = rng.integers(0, 256, (SIDE, SIDE, 3), dtype=np.uint8)
    image = cv2.GaussianBlur(image, (0, 0), 3)  # smooth, so bilinear resampling is nearly exact
    transform = window_transform(face)
    window = extract(image, transform, MOUTH.size)
    points = to_window(face, transform)
    weight = paste_weight(points, MOUTH.size, window_eye_distance(MOUTH))
    same = paste(image, window, weight, transform)  # pasting the window itself changes (almost) nothing
    assert np.abs(same.astype(int) - image.astype(int)).max() <= 3
    drawn = np.full_like(window, 255)
    pasted = paste(image, drawn, weight, transform)
    lip = np.round(face[51]).astype(int)  # an outer-lip point: wholly the drawn window
    assert (pasted[lip[1], lip[0]] >= 250).all()
    far = np.round(face[36]).astype(int)  # an eye: untouched
    assert (pasted[far[1], far[0]] == image[far[1], far[0]]).all()
    changed = np.abs(pasted.astype(int) - image.astype(int)).max(axis=-1) > 0
    ys, xs = np.nonzero(changed)
    eyes = float(inter_ocular_distance(face))
    assert np.hypot(xs - face[48:60, 0].mean(), ys - face[48:60, 1].mean()).max() < MOUTH.span / 2 * np.sqrt(2) * eyes
