"""The shots' irises carried by their warps to where the target looks (landmarks.parts.eyes.iris_shift)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from landmarks.shape.measures import EYE_RINGS
from landmarks.parts.eyes.iris_shift import BAND, REACH, align_irises, landed

SIDE = 128
WHITE, SKIN, IRIS = 235, 150, 30
WIDTH = 30.0  # eye width: corners 30 px apart


def _eyes() -> np.ndarray:
    """68 points with two level eyes (corners 30 px apart, lids 14 px apart at y = 50), the rest far below them."""
    points = np.tile(np.array([[64.0, 110.0]]), (68, 1))
    for ring, left in zip(EYE_RINGS, (20.0, 78.0)):
        points[list(ring)] = [[left, 50], [left + 10, 43], [left + 20, 43], [left + 30, 50], [left + 20, 57],
                              [left + 10, 57]]
    return points


def _shot(points: np.ndarray, look: float) -> tuple[np.ndarray, np.ndarray]:
    """Skin, white eyes, one dark iris per eye ``look`` eye widths right of the eye's centre -> (image, irises
    (2, 2))."""
    image = np.full((SIDE, SIDE, 3), SKIN, np.uint8)
    irises = []
    for ring in EYE_RINGS:
        lids = points[list(ring)]
        cv2.fillPoly(image, [np.round(lids).astype(np.int32)], (WHITE,) * 3)
        centre = np.round((lids[0] + lids[3]) / 2 + [look * WIDTH, 0.0])
        cv2.circle(image, (int(centre[0]), int(centre[1])), 5, (IRIS,) * 3, -1)
        irises.append(centre)
    return image, np.array(irises)


def _identity() -> tuple[np.ndarray, np.ndarray]:
    ys, xs = np.mgrid[0:SIDE, 0:SIDE].astype(np.float32)
    return xs, ys


def _dark(image: np.ndarray, points: np.ndarray, eye: int) -> tuple[int, np.ndarray]:
    """(dark blobs in the eye's box, the centroid (x, y) of its dark pixels)."""
    lids = points[list(EYE_RINGS[eye])]
    x0, y0 = np.floor(lids.min(axis=0)).astype(int) - 2
    x1, y1 = np.ceil(lids.max(axis=0)).astype(int) + 2
    dark = (image[y0:y1, x0:x1].mean(axis=2) < 80).astype(np.uint8)
    count, _ = cv2.connectedComponents(dark)
    ys, xs = np.nonzero(dark)
    return count - 1, np.array([xs.mean() + x0, ys.mean() + y0]) if len(xs) else np.full(2, np.nan)


def _warp(image: np.ndarray, maps: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    return cv2.remap(image, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def test_landed_inverts_a_backward_map_to_a_fraction_of_a_pixel():
    xs, ys = _identity()
    angle = np.radians(8.0)
    map_x = (np.cos(angle) * xs - np.sin(angle) * ys + 3.3).astype(np.float32)  # p -> R p + t
    map_y = (np.sin(angle) * xs + np.cos(angle) * ys - 2.6).astype(np.float32)
    point = np.array([70.4, 51.7])
    found = landed(map_x, map_y, point)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    np.testing.assert_allclose(found, np.linalg.solve(rotation, point - [3.3, -2.6]), atol=0.05)
    assert np.isnan(landed(map_x, map_y, np.array([500.0, 500.0]))).all()  # the map never samples there


def test_shots_that_looked_apart_agree_after_the_warp_on_the_nearest_shots_iris():
    points = _eyes()
    shots = [_shot(points, look) for look in (0.0, 0.2, -0.2)]
    maps = [_identity()] * 3
    blend = np.mean([_warp(image, m) for (image, _), m in zip(shots, maps)], axis=0).astype(np.uint8)
    assert _dark(blend, points, 0)[0] == 0  # no pixel darker than two thirds white: a smudge, no iris
    aligned = align_irises(maps, np.stack([irises for _, irises in shots]), points)
    warped = [_warp(image, m) for (image, _), m in zip(shots, aligned)]
    blend = np.mean(warped, axis=0).astype(np.uint8)
    for eye in range(2):
        blobs, centroid = _dark(blend, points, eye)
        assert blobs == 1 and abs(centroid[0] - shots[0][1][eye, 0]) < 0.8
    np.testing.assert_array_equal(warped[0], shots[0][0])  # the nearest shot is where it was


@pytest.mark.parametrize("look", [-0.1, 0.0, 0.1])
def test_every_iris_lands_where_the_gaze_says_and_the_rest_of_the_face_stays(look):
    points = _eyes()
    shots = [_shot(points, start) for start in (0.0, 0.04, -0.04)]  # moved by at most 0.14 < MAX_SHIFT
    maps = [_identity()] * 3
    gaze = np.array([[look, 0.05], [look, -0.05]])  # the second coordinate (across) is not moved
    aligned = align_irises(maps, np.stack([irises for _, irises in shots]), points, gaze)
    for given in maps[0]:  # both eyes bend a copy of each map, never the maps given (here one pair, thrice)
        np.testing.assert_array_equal(given, _identity()[0] if given is maps[0][0] else _identity()[1])
    for (image, _), warp in zip(shots, aligned):
        warped = _warp(image, warp)
        for eye in range(2):
            lids = points[list(EYE_RINGS[eye])]
            blobs, centroid = _dark(warped, points, eye)
            assert blobs == 1
            np.testing.assert_allclose(centroid, (lids[0] + lids[3]) / 2 + [look * WIDTH, 0.0], atol=0.8)
        kept = np.ones((SIDE, SIDE), bool)
        for eye in range(2):
            lids = points[list(EYE_RINGS[eye])]
            centre = (lids[0] + lids[3]) / 2
            kept[int(centre[1] - BAND[1] * WIDTH) - 1:int(centre[1] + BAND[1] * WIDTH) + 2,
                 int(centre[0] - REACH * WIDTH) - 1:int(centre[0] + REACH * WIDTH) + 2] = False
        np.testing.assert_array_equal(warp[0][kept], maps[0][0][kept])
        np.testing.assert_array_equal(warp[1], maps[0][1])  # along a level eye only x moves


def test_an_iris_not_found_leaves_its_shot_and_no_gaze_no_nearest_iris_leaves_all():
    points = _eyes()
    shots = [_shot(points, look) for look in (0.0, 0.1)]
    irises = np.stack([irises for _, irises in shots])
    irises[1, 0] = np.nan  # the second shot's image-left eye is closing
    aligned = align_irises([_identity()] * 2, irises, points, np.array([[0.05, 0.0], [np.nan, np.nan]]))
    np.testing.assert_array_equal(aligned[1][0][:, :64], _identity()[0][:, :64])  # left eye untouched
    assert not np.array_equal(aligned[1][0][:, 64:], _identity()[0][:, 64:])  # right eye moved to the nearest's
    irises[0] = np.nan  # the nearest shot has no irises and no gaze is given: nothing to agree on
    aligned = align_irises([_identity()] * 2, irises, points)
    for warp in aligned:
        np.testing.assert_array_equal(warp[0], _identity()[0])
    with pytest.raises(ValueError, match="irises"):
        align_irises([_identity()] * 2, irises[:1], points)


def test_the_tps_references_carry_their_irises_to_the_gaze():
    from landmarks.warp.tps import warp_references

    points = _eyes()
    shots = [_shot(points, look) for look in (0.1, -0.1)]
    frames, irises = np.stack([image for image, _ in shots]), np.stack([irises for _, irises in shots])
    plain, plain_masks, indices = warp_references(frames, np.stack([points, points]), points, 2)
    warped, masks, same = warp_references(frames, np.stack([points, points]), points, 2, irises=irises,
                                          gaze=np.array([[0.0, 0.0], [0.0, 0.0]]))
    np.testing.assert_array_equal(same, indices)
    np.testing.assert_array_equal(masks, plain_masks)
    for reference, before in zip(warped, plain):
        for eye in range(2):
            lids = points[list(EYE_RINGS[eye])]
            blobs, centroid = _dark(reference, points, eye)
            assert blobs == 1 and abs(centroid[0] - (lids[0, 0] + lids[3, 0]) / 2) < 0.8  # at the centre: gaze 0
            assert abs(_dark(before, points, eye)[1][0] - (lids[0, 0] + lids[3, 0]) / 2) > 2.5  # 3 px aside before


def test_a_rolled_eye_keeps_its_warp_beyond_the_reach_along_its_corner_line():
    from landmarks.shape.measures import eye_axes
    from landmarks.parts.eyes.iris_shift import shift_iris

    points = _eyes()
    centre = points[36:48].mean(axis=0)
    angle = np.radians(18.0)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    rolled = (points - centre) @ rotation.T + centre
    xs, ys = _identity()
    curved = (xs + 0.002 * (ys - 50) ** 2).astype(np.float32), (ys + 0.003 * (xs - 60) ** 2).astype(np.float32)
    bent = shift_iris(*curved, rolled, 0, 0.0, 0.12)
    eye_centre, axis, width = eye_axes(rolled, 0)
    u = ((xs - eye_centre[0]) * axis[0] + (ys - eye_centre[1]) * axis[1]) / width
    beyond = np.abs(u) >= REACH
    assert not np.array_equal(bent[0], curved[0])
    np.testing.assert_array_equal(bent[0][beyond], curved[0][beyond])
    np.testing.assert_array_equal(bent[1][beyond], curved[1][beyond])
