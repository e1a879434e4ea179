"""The mouth from the nearest warped shot (landmarks.parts.mouth.nearest_mouth): where it goes, and that nothing else moves."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.shape.expression import set_mouth_opening
from landmarks.parts.mouth.nearest_mouth import MOUTH_MARGIN, keep_nearest_mouth, mouth_weight
from landmarks.motion.head_pose import project_canonical
from landmarks.shape.measures import inter_ocular_distance

SIDE = 256


def _face(opening: float = 0.3) -> np.ndarray:
    return set_mouth_opening(project_canonical(0, 0, 0, (SIDE, SIDE), scale=0.5).astype(np.float64), opening)


def _full(weight_box: tuple[np.ndarray, tuple[int, int, int, int]]) -> np.ndarray:
    weight, (x0, y0, x1, y1) = weight_box
    full = np.zeros((SIDE, SIDE), np.float32)
    full[y0:y1, x0:x1] = weight
    return full


def test_mouth_weight_covers_the_lips_and_their_margin_and_nothing_far_away():
    face = _face()
    full = _full(mouth_weight(face, (SIDE, SIDE)))
    eyes = float(inter_ocular_distance(face))
    lips = face[48:60]
    centre = np.round(lips.mean(axis=0)).astype(int)
    assert full[centre[1], centre[0]] == pytest.approx(1.0, abs=1e-3)  # inside the open mouth
    for x, y in np.round(lips).astype(int):  # every outer-lip point, and the skin just beyond it, fully taken
        assert full[y, x] > 0.99
    below = np.round(face[57] + [0, 0.6 * MOUTH_MARGIN * eyes]).astype(int)
    assert full[below[1], below[0]] > 0.5
    for far in (face[8], face[30], face[36], face[45], face[0], face[16]):  # chin, nose tip, eyes, jaw ends
        x, y = np.round(far).astype(int)
        assert full[y, x] < 1e-3
    assert 0.0 <= full.min() and full.max() <= 1.0


def test_keep_nearest_mouth_takes_the_mouth_from_the_nearest_shot_only_where_its_warp_is_valid():
    face = _face()
    image = np.full((SIDE, SIDE, 3), 40, np.uint8)
    nearest = np.full((SIDE, SIDE, 3), 50, np.uint8)  # alike around the mouth (``mismatch`` 10) ...
    weight = _full(mouth_weight(face, (SIDE, SIDE)))
    nearest[weight > 0.6] = 200  # ... whatever it shows inside
    valid = np.ones((SIDE, SIDE), np.float32)
    out = keep_nearest_mouth(image, nearest, valid, face)
    centre = np.round(face[48:60].mean(axis=0)).astype(int)
    assert (out[centre[1], centre[0]] == 200).all()
    untouched = weight == 0
    assert (out[untouched] == 40).all() and untouched.mean() > 0.8  # the rest of the face is the network's
    between = (weight > 0.2) & (weight < 0.5)  # a feathered edge, no hard seam
    assert between.any() and ((out[between] > 40) & (out[between] < 50)).all()
    # where the nearest warp sampled outside its shot, the network's pixels stay
    valid[:, : centre[0]] = 0.0
    half = keep_nearest_mouth(image, nearest, valid, face)
    assert (half[:, : centre[0]] == 40).all() and (half[centre[1], centre[0] + 2] == 200).all()
    assert (image == 40).all()  # the input is not written


def test_a_nearest_shot_unlike_the_synthesis_around_the_mouth_is_taken_less_then_not_at_all():
    """Another lighting (the FSTH sample's shots come from several videos): its mouth would be a patch."""
    from landmarks.parts.mouth.nearest_mouth import MISMATCH, mismatch

    face = _face()
    rng = np.random.default_rng(0)
    image = rng.integers(60, 140, (SIDE, SIDE, 3)).astype(np.uint8)
    valid = np.ones((SIDE, SIDE), np.float32)
    region = mouth_weight(face, (SIDE, SIDE))
    weight = _full(region)
    centre = np.round(face[48:60].mean(axis=0)).astype(int)
    low, high = MISMATCH
    for offset, taken in ((0.0, 1.0), (low - 2, 1.0), ((low + high) / 2, 0.5), (high + 2, 0.0)):
        nearest = np.clip(image.astype(np.float32) + offset, 0, 255).astype(np.uint8)
        nearest[weight > 0.999] = 250  # the mouth itself may differ as much as it likes
        assert mismatch(image, nearest, valid, region) == pytest.approx(offset, abs=0.01)
        out = keep_nearest_mouth(image, nearest, valid, face)
        expected = taken * 250 + (1 - taken) * image[centre[1], centre[0]].astype(float)
        np.testing.assert_allclose(out[centre[1], centre[0]], expected, atol=1.0)
    assert mismatch(image, np.full_like(image, 255), np.zeros_like(valid), region) == 0.0  # no valid edge


def test_keep_nearest_mouth_leaves_images_without_a_usable_mouth_alone():
    image = np.full((SIDE, SIDE, 3), 40, np.uint8)
    nearest = np.full((SIDE, SIDE, 3), 200, np.uint8)
    valid = np.ones((SIDE, SIDE), np.float32)
    missing = np.full((68, 2), np.nan)
    assert keep_nearest_mouth(image, nearest, valid, missing) is image
    outside = _face() + 3 * SIDE  # a face entirely beyond the crop
    assert mouth_weight(outside, (SIDE, SIDE)) is None
    assert keep_nearest_mouth(image, nearest, valid, outside) is image
    with pytest.raises(ValueError, match="uint8"):
        keep_nearest_mouth(image.astype(np.float32), nearest, valid, _face())


def test_mouth_strength_is_how_far_the_target_opens_beyond_the_references():
    """0 where most of the nearest shots open as wide as the target (their blend is right), 1 from CLOSED_MOUTH
    beyond their median; a strength of 0 leaves the image as it is."""
    from landmarks.shape.expression import CLOSED_MOUTH
    from landmarks.parts.mouth.nearest_mouth import mouth_strength

    shots = np.stack([_face(o) for o in (0.02, 0.03, 0.04, 0.3, 0.35)])  # mostly closed, two open
    assert mouth_strength(_face(0.04), shots, 5) == pytest.approx(0.0, abs=0.05)  # the median shot
    assert mouth_strength(_face(0.04 + CLOSED_MOUTH / 2), shots, 5) == pytest.approx(0.5, abs=0.1)
    assert mouth_strength(_face(0.3), shots, 5) == 1.0
    open_shots = np.stack([_face(o) for o in (0.28, 0.3, 0.32, 0.31, 0.29)])
    assert mouth_strength(_face(0.3), open_shots, 5) == pytest.approx(0.0, abs=0.05)  # the shots show this mouth
    assert mouth_strength(_face(0.3), shots[:1], 5) == 1.0  # K < count: the one shot repeated
    image = np.full((SIDE, SIDE, 3), 40, np.uint8)
    assert keep_nearest_mouth(image, image + 10, np.ones((SIDE, SIDE), np.float32), _face(), 0.0) is image
    half = keep_nearest_mouth(image, image + 10, np.ones((SIDE, SIDE), np.float32), _face(), 0.5)
    centre = np.round(_face()[48:60].mean(axis=0)).astype(int)
    assert half[centre[1], centre[0], 0] == 45
