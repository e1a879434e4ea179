"""The driver's mouth interior inside the target's inner lips (landmarks.parts.mouth.interior): where it goes, its colour,
and that nothing else moves."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from landmarks.shape.expression import set_mouth_opening
from landmarks.parts.mouth.interior import DriverMouth, cut_driver_mouth, interior_strength, lip_affine, paste_interior
from landmarks.parts.lay_in import CAST, GAIN
from landmarks.motion.head_pose import project_canonical

SIDE = 256
SKIN, LIPS = (200, 150, 130), (170, 60, 70)


def _points(opening: float, scale: float = 0.5, shift=(0.0, 0.0)) -> np.ndarray:
    face = project_canonical(0, 0, 0, (SIDE, SIDE), scale=scale).astype(np.float64)
    return set_mouth_opening(face, opening) + shift


def _face(points: np.ndarray, inside, skin=SKIN, lips=LIPS, teeth: bool = False,
          base: np.ndarray | None = None) -> np.ndarray:
    """A flat face: skin (or ``base``, a copy), the outer-lip polygon in lip colour, the inner-lip polygon filled
    with ``inside`` (and a white band along its top edge: teeth)."""
    image = np.zeros((SIDE, SIDE, 3), np.uint8) if base is None else base.copy()
    if base is None:
        image[:] = skin
    cv2.fillPoly(image, [np.round(points[48:60]).astype(np.int32)], lips)
    cv2.fillPoly(image, [np.round(points[60:68]).astype(np.int32)], inside)
    if teeth:
        top = np.round(points[61:64].mean(axis=0)).astype(int)
        cv2.rectangle(image, (top[0] - 6, top[1]), (top[0] + 6, top[1] + 3), (250, 250, 250), -1)
    return image


def _centre(points: np.ndarray) -> tuple[int, int]:
    x, y = np.round(points[[62, 66]].mean(axis=0)).astype(int)
    return y, x


def test_the_driver_interior_fills_the_target_inner_lips_and_nothing_else_moves():
    driver_points = _points(0.35, scale=0.4, shift=(-20, 10))
    driver = _face(driver_points, (20, 10, 10), teeth=True)  # a dark cavity with teeth
    target_points = _points(0.35, scale=0.55)
    target = _face(target_points, (190, 90, 100))  # stretched lips where no shot opens the mouth
    mouth = cut_driver_mouth(driver, driver_points)
    assert mouth is not None and mouth.patch.shape[0] < SIDE / 2
    result = paste_interior(target, target_points, mouth)
    y, x = _centre(target_points)
    assert result[y, x].max() < 40  # the cavity, dark as the driver's
    band = np.round(target_points[61:64].mean(axis=0)).astype(int)
    assert result[band[1] + 2, band[0]].min() > 200  # the teeth under the upper lip, where the driver shows them
    changed = np.abs(result.astype(int) - target.astype(int)).max(axis=-1) > 0
    outer = np.zeros((SIDE, SIDE), np.uint8)
    cv2.fillPoly(outer, [np.round(target_points[48:60]).astype(np.int32)], 1)
    assert not (changed & (outer == 0)).any()  # the skin is the synthesis', bit for bit
    lip_line = np.round((target_points[50] + target_points[61]) / 2).astype(int)  # on the upper lip
    assert np.array_equal(result[lip_line[1], lip_line[0]], target[lip_line[1], lip_line[0]])


def test_the_interior_takes_the_target_light_from_the_skin():
    driver_points = target_points = _points(0.35)
    driver = _face(driver_points, (100, 100, 100), skin=tuple(int(0.7 * c) for c in SKIN))  # a darker room
    target = _face(target_points, (190, 90, 100))
    result = paste_interior(target, target_points, cut_driver_mouth(driver, driver_points))
    y, x = _centre(target_points)
    expected = 100 * (np.mean(SKIN) + 1) / (np.mean([int(0.7 * c) for c in SKIN]) + 1)  # one gain, brightness
    assert np.abs(result[y, x] - expected).max() <= 2
    ruddy = (235, 175, 120)  # a ruddier face: white teeth stay about white (the whole cast turned them orange) ...
    warm = _face(target_points, (190, 90, 100), skin=ruddy)
    teeth = _face(driver_points, (220, 220, 220), skin=(180, 180, 180))
    laid = paste_interior(warm, target_points, cut_driver_mouth(teeth, driver_points))[y, x].astype(int)
    assert np.ptp(laid) <= 0.1 * np.ptp(ruddy) and laid.min() > 200
    grey = _face(driver_points, (60, 60, 60), skin=(180, 180, 180))  # ... while a dark inside takes CAST of it
    dark = paste_interior(warm, target_points, cut_driver_mouth(grey, driver_points))[y, x].astype(float)
    cast = np.subtract(ruddy, np.mean(ruddy))
    np.testing.assert_allclose(dark - dark.mean(), CAST * cast, atol=1.5)
    bright = _face(driver_points, (100, 100, 100), skin=(255, 255, 255))  # a gain below GAIN[0] is clipped
    clipped = paste_interior(target, target_points, cut_driver_mouth(bright, driver_points))
    assert clipped[y, x].mean() >= 100 * GAIN[0] - 1  # in grey: the cast adds nothing to it


def test_a_bearded_driver_lends_its_interior_lit_by_its_nose_not_its_beard():
    points = _points(0.35)
    y, x = _centre(points)
    beard = cv2.dilate(cv2.fillPoly(np.zeros((SIDE, SIDE), np.uint8), [np.round(points[48:60]).astype(np.int32)], 1),
                       cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (11, 11))) > 0
    driver = _face(points, (100, 100, 100))
    driver[beard] = (60, 45, 40)  # a dark beard all around the mouth, in the same light as the target
    driver = _face(points, (100, 100, 100), skin=None, base=driver)
    target = _face(points, (190, 90, 100))
    mouth = cut_driver_mouth(driver, points)
    assert mouth.light is not None and np.abs(mouth.light - SKIN).max() < 1  # the nose: skin, not beard
    laid = paste_interior(target, points, mouth)[y, x].astype(float)
    assert np.abs(laid.mean() - 100) <= 3  # as bright as the driver shows it (the beard ring: x1.6, clipped)
    ringed = paste_interior(target, points, DriverMouth(mouth.patch, mouth.lips, mouth.opening, mouth.yaw))[y, x]
    assert ringed.mean() > 150  # what the ring around the lips gave


def test_a_closed_mouth_is_left_as_it_is():
    driver_points = _points(0.35)
    driver = _face(driver_points, (20, 10, 10))
    target_points = _points(0.0)
    target = _face(target_points, (190, 90, 100))
    mouth = cut_driver_mouth(driver, driver_points)
    assert paste_interior(target, target_points, mouth) is target  # the target's mouth is shut
    assert cut_driver_mouth(driver, _points(0.0)) is None  # a shut driver gives nothing to take
    assert paste_interior(target, _points(0.35), None) is target
    half = DriverMouth(mouth.patch, mouth.lips, 0.03)  # the lesser opening decides: half way
    assert interior_strength(_points(0.35), half) == pytest.approx(0.5)
    assert abs(mouth.yaw) < 5  # a frontal driver
    for yaw, strength in ((-42.5, 0.5), (60.0, 0.0), (float("nan"), 0.0)):  # a mouth seen from the side: none
        assert interior_strength(_points(0.35), DriverMouth(mouth.patch, mouth.lips, 0.35, yaw)) == \
            pytest.approx(strength)


def test_points_that_are_not_finite_or_not_68_are_handled():
    driver_points = _points(0.35)
    driver = _face(driver_points, (20, 10, 10))
    broken = driver_points.copy()
    broken[62] = np.nan
    assert cut_driver_mouth(driver, broken) is None
    target = _face(driver_points, (190, 90, 100))
    assert paste_interior(target, broken, cut_driver_mouth(driver, driver_points)) is target
    with pytest.raises(ValueError, match="68"):
        cut_driver_mouth(driver, driver_points[:60])
    with pytest.raises(ValueError, match="uint8"):
        paste_interior(target.astype(np.float32), driver_points, None)


def test_lip_affine_recovers_an_affine_map():
    rng = np.random.default_rng(0)
    source = rng.uniform(0, 100, (20, 2))
    matrix = np.array([[1.2, 0.1, 5.0], [-0.2, 0.9, -3.0]])
    target = source @ matrix[:, :2].T + matrix[:, 2]
    np.testing.assert_allclose(lip_affine(source, target), matrix, atol=1e-9)

