"""landmarks.scene.compositing (composite a face into a scene, the head following rigidly) and landmarks.shape.expression."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.align import crop_transform, warp_to_crop
from landmarks.shape.expression import eye_opening, mouth_opening, pick_anchor
from landmarks.motion.head_pose import project_canonical
from landmarks.scene.compositing import composite_face, face_side, head_region

SIZE = (240, 320)  # (H, W): a scene wider than tall, face off-centre


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A textured (H, W, 3) scene and a frontal face's (68, 2) landmarks in it."""
    import cv2

    noise = cv2.GaussianBlur(rng.random((*SIZE, 3)).astype(np.float32), (0, 0), 3)  # texture a warp can follow
    scene = np.clip((noise - noise.mean()) / noise.std() * 50 + 128, 0, 255).astype(np.uint8)
    points = project_canonical(0, 0, 0, SIZE, scale=0.55, translation=(30, -5)).astype(np.float64)
    return scene, points


def _psnr(first: np.ndarray, second: np.ndarray) -> float:
    error = np.mean((first.astype(np.float64) - second.astype(np.float64)) ** 2)
    return float("inf") if error == 0 else 10 * np.log10(255**2 / error)


def test_the_scene_itself_as_face_gives_the_scene_back(rng):
    scene, points = _scene(rng)
    matrix = crop_transform(points, 128)
    result = composite_face(scene, points, points, warp_to_crop(scene, matrix, 128), matrix)
    assert result.frame.shape == scene.shape and result.frame.dtype == np.uint8
    x0, y0, x1, y1 = result.box
    outside = np.ones(SIZE, bool)
    outside[y0:y1, x0:x1] = False
    np.testing.assert_array_equal(result.frame[outside], scene[outside])  # bit for bit outside the head box
    np.testing.assert_allclose(result.head_motion, np.eye(2, 3), atol=1e-6)  # no head motion: no head layer warp
    # inside, the face went through a crop and back (resampling noise only) and the colour match adds nothing
    assert _psnr(result.frame[y0:y1, x0:x1], scene[y0:y1, x0:x1]) > 20


def test_outside_the_head_region_nothing_changes_and_the_head_follows_a_translation(rng):
    scene, points = _scene(rng)
    target = points + [12.0, 0.0]  # the head moves 12 px to the right
    matrix = crop_transform(target, 128)
    face = np.full((128, 128, 3), 90, np.uint8)  # a flat synthesised face
    result = composite_face(scene, points, target, face, matrix)
    region = head_region([points, target], SIZE)
    np.testing.assert_array_equal(result.frame[~region], scene[~region])
    # hair above the forehead (inside the head, outside the face) is the scene's, moved by 12 px
    side = face_side(points)
    top = int(points[19, 1] - 0.2 * side)
    left = int(points[27, 0]) - 8
    moved = result.frame[top - 3 : top + 3, left + 12 : left + 20].astype(int)
    original = scene[top - 3 : top + 3, left : left + 8].astype(int)
    unmoved = result.frame[top - 3 : top + 3, left : left + 8].astype(int)
    assert np.abs(moved - original).mean() < 0.3 * np.abs(unmoved - original).mean()
    assert np.abs(result.frame[int(points[33, 1]), int(target[33, 0])].astype(int) - 90).max() < 45  # the face is there


def test_bad_landmarks_raise():
    scene = np.zeros((*SIZE, 3), np.uint8)
    points = project_canonical(0, 0, 0, SIZE).astype(np.float64)
    with pytest.raises(ValueError, match="target_landmarks"):
        composite_face(scene, points, np.full((68, 2), np.nan), np.zeros((64, 64, 3), np.uint8), np.eye(2, 3))


def _open_mouth(points: np.ndarray, amount: float) -> np.ndarray:
    opened = points.copy()
    opened[[65, 66, 67, 55, 56, 57, 58, 59, 8, 7, 9]] += [0.0, amount]
    return opened


def test_openings_grow_with_the_mouth_and_ignore_face_size():
    points = project_canonical(0, 0, 0, (256, 256)).astype(np.float64)
    closed, opened = mouth_opening(points), mouth_opening(_open_mouth(points, 10))
    assert closed < 0.1 < opened
    np.testing.assert_allclose(mouth_opening(points * 2), closed)  # normalised by the eye distance
    np.testing.assert_allclose(eye_opening(np.stack([points, points * 3])), eye_opening(points)[None].repeat(2))
    assert np.isnan(mouth_opening(np.full((68, 2), np.nan)))


def test_anchor_is_the_frontal_closed_mouth_shot():
    image = (256, 256)
    frontal = project_canonical(0, 0, 0, image).astype(np.float64)
    shots = np.stack([project_canonical(25, 0, 0, image), _open_mouth(frontal, 12), frontal,
                      project_canonical(0, 15, 0, image)]).astype(np.float64)
    assert pick_anchor(shots, image) == 2
    shots[2] = np.nan
    assert pick_anchor(shots, image) in (1, 3)  # never a shot without landmarks


@pytest.mark.parametrize("scale", [0.3, 1.4])
def test_small_and_close_up_faces_change_nothing_outside_their_head_region(rng, scale):
    """The head layer's field is made on a grid (a step of the face side / HEAD_GRID_CELLS) and interpolated; a small
    face (the smallest step) and a close-up whose head leaves the frame still leave every pixel outside
    ``head_region`` bit for bit, and move the face."""
    import cv2

    noise = cv2.GaussianBlur(rng.random((*SIZE, 3)).astype(np.float32), (0, 0), 3)
    scene = np.clip((noise - noise.mean()) / noise.std() * 50 + 128, 0, 255).astype(np.uint8)
    points = project_canonical(0, 0, 0, SIZE, scale=scale, translation=(10, 20)).astype(np.float64)
    target = points * 1.03 + [5.0, -3.0]  # the head moves and grows a little
    matrix = crop_transform(target, 128)
    result = composite_face(scene, points, target, np.full((128, 128, 3), 90, np.uint8), matrix)
    region = head_region([points, target], SIZE)
    assert 0 < region.mean() < 1
    np.testing.assert_array_equal(result.frame[~region], scene[~region])
    nose = np.round(target[30]).astype(int)
    assert np.abs(result.frame[nose[1], nose[0]].astype(int) - 90).max() < 45  # the face is there


def _person_scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A scene whose person (a red head disc and hair, matte 1) stands against a blue textured wall (matte 0):
    (H, W, 3) uint8, (68, 2) face landmarks, (H, W) float32 matte."""
    import cv2

    scene, points = _scene(rng)
    wall = scene.astype(np.float32) * [0.2, 0.4, 1.0]  # blue, textured
    person = np.zeros(SIZE, np.uint8)
    centre = points.mean(0) - [0.0, 0.15 * face_side(points)]
    axes = (int(0.22 * face_side(points)), int(0.32 * face_side(points)))  # inside the head region, with wall around
    cv2.ellipse(person, tuple(int(v) for v in centre), axes, 0, 0, 360, 1, -1)
    skin = scene.astype(np.float32) * [1.0, 0.4, 0.2]  # red, textured (the hair a warp can be followed on)
    image = np.where(person[..., None] > 0, skin, wall)
    return np.clip(image, 0, 255).astype(np.uint8), points, person.astype(np.float32)


def test_with_a_matte_the_wall_stays_the_person_moves_and_what_they_uncover_is_wall(rng):
    from landmarks.scene.compositing import background_plate

    scene, points, matte = _person_scene(rng)
    layers = background_plate(scene, points, matte)
    away = cv2_dilated(matte, 25) == 0  # the wall away from the person's edge (and the plate's margin)
    np.testing.assert_array_equal(layers.plate[away], scene[away])
    assert layers.plate[matte > 0][:, 2].mean() > 2 * layers.plate[matte > 0][:, 0].mean()  # the person: filled with wall
    shift = 14.0
    target = points + [shift, 0.0]
    matrix = crop_transform(target, 128)
    face = np.full((128, 128, 3), 90, np.uint8)
    plain = composite_face(scene, points, target, face, matrix).frame
    result = composite_face(scene, points, target, face, matrix, layers)
    matted = result.frame
    region = head_region([points, target], SIZE, person=True)  # with the matte the head layer reaches further
    x0, y0, x1, y1 = result.box
    face_layer = np.zeros(SIZE, bool)
    face_layer[y0:y1, x0:x1] = result.face_alpha > 0
    np.testing.assert_array_equal(matted[~region], scene[~region])
    # the wall inside the head region, away from the person where it was and where it is: the scene's, unmoved
    moved_matte = np.roll(matte, int(shift), axis=1)
    still_wall = region & away & (cv2_dilated(moved_matte, 25) == 0) & ~face_layer
    assert still_wall.sum() > 500
    matted_error = np.abs(matted[still_wall].astype(int) - scene[still_wall]).max(1)
    plain_error = np.abs(plain[still_wall].astype(int) - scene[still_wall]).max(1)
    # (bit for bit where the head layer moves a pixel or more; where it moves less, the scene as before)
    assert (matted_error == 0).mean() > 0.8 and matted_error.mean() < 0.2 * plain_error.mean()  # without: it waves
    # what the head uncovers (person before, wall after, on its trailing side) is wall: blue, not red
    uncovered = region & (matte > 0) & (cv2_dilated(moved_matte, 5) == 0) & ~face_layer
    assert uncovered.sum() > 50
    red, blue = matted[uncovered][:, 0].astype(float).mean(), matted[uncovered][:, 2].astype(float).mean()
    assert blue > 2 * red
    # the hair above the forehead moved with the head, rigidly (without the matte, the head layer's fading field
    # bends it there)
    top = int(points[19, 1] - 0.2 * face_side(points))
    source = slice(int(points[27, 0]) - 8, int(points[27, 0]))
    columns = slice(source.start + int(shift), source.stop + int(shift))
    np.testing.assert_array_equal(matted[top - 3 : top + 3, columns], scene[top - 3 : top + 3, source])
    assert not np.array_equal(plain[top - 3 : top + 3, columns], scene[top - 3 : top + 3, source])


def test_with_a_matte_hair_beyond_the_head_ellipse_moves_and_the_body_below_the_neck_stays(rng):
    from landmarks.scene.compositing import NECK_FADE, background_plate

    scene, points = _scene(rng)
    side = face_side(points)
    matte = np.zeros(SIZE, np.float32)
    top = int(points[19, 1] - 0.75 * side)  # a tall hairdo, beyond the head ellipse's top (0.54 side above the eyes)
    columns = slice(int(points[27, 0]) - 6, int(points[27, 0]) + 6)
    matte[max(top, 0):, columns] = 1.0  # hair from the top down and the body below: one person
    layers = background_plate(scene, points, matte)
    target = points + [0.0, -10.0]  # the head rises
    result = composite_face(scene, points, target, np.full((128, 128, 3), 90, np.uint8), crop_transform(target, 128),
                            layers).frame
    plain_region, region = head_region([points, target], SIZE), head_region([points, target], SIZE, person=True)
    assert (region >= plain_region).all() and region.sum() > plain_region.sum()
    assert not region[int(max(points[8, 1], target[8, 1]) + NECK_FADE * side) + 1:].any()  # the body: never moved
    hair = max(top, 0) + 12
    assert not plain_region[hair, columns].any() and region[hair, columns].all()
    np.testing.assert_array_equal(result[hair - 10, columns], scene[hair, columns])  # moved up with the head
    np.testing.assert_array_equal(result[~region], scene[~region])


def cv2_dilated(mask: np.ndarray, size: int) -> np.ndarray:
    import cv2

    return cv2.dilate((mask > 0).astype(np.uint8), np.ones((size, size), np.uint8))


def test_fill_in_keeps_what_is_known_and_fills_holes_smoothly_from_around(rng):
    from landmarks.scene.compositing import fill_in

    ramp = np.tile(np.linspace(0, 200, 64, dtype=np.float32), (48, 1))[..., None].repeat(3, 2)
    known = np.ones((48, 64), np.float32)
    known[10:30, 20:44] = 0
    filled = fill_in(ramp, known)
    np.testing.assert_allclose(filled[known == 1], ramp[known == 1], atol=1e-3)
    hole = filled[10:30, 20:44, 0]
    assert ramp[..., 0][known == 1].min() <= hole.min() and hole.max() <= ramp[..., 0][known == 1].max()
    assert hole[:, -1].mean() > hole[:, 0].mean() + 20  # the ramp carries on across the hole
    assert np.isfinite(fill_in(ramp, np.zeros_like(known))).all()  # nothing known: no NaN


def test_the_plate_fills_the_person_with_the_wall_beside_them_not_a_ghost_of_the_far_background(rng):
    """A white wall beside the person and a dark doorway across the frame: what a moved head uncovers is the white
    wall, not the grey the plain push-pull left (the doorway's share of the mean: a shadow of the person)."""
    from landmarks.scene.compositing import PLATE_TRUST, background_plate, fill_in, plate_hole

    _, points = _scene(rng)
    height, width = SIZE
    scene = np.full((height, width, 3), 230, np.uint8)
    scene[:, : width // 5] = 40  # the doorway, far from the person
    matte = np.zeros(SIZE, np.float32)
    centre, side = points.mean(0), face_side(points)
    rows, cols = np.mgrid[0:height, 0:width]
    matte[np.hypot((cols - centre[0]) / (0.3 * side), (rows - centre[1]) / (0.45 * side)) <= 1] = 1.0
    scene[matte > 0] = (200, 80, 60)  # the person
    plate = background_plate(scene, points, matte).plate
    beside = (matte > 0) & (cv2_dilated(1 - matte, 9) > 0)  # the person's rim: what a small head motion uncovers
    assert beside.sum() > 100
    assert plate[beside].min() >= 215  # the white wall carried in
    # the plain push-pull (trust 1) on the same pixels: the doorway's grey shows through at the rim
    known = (1 - plate_hole(matte, points)).astype(np.float32)
    plain = fill_in(scene.astype(np.float32), known)
    assert plain[beside].mean() < plate[beside].astype(float).mean() - 5 and PLATE_TRUST > 1


def test_a_plate_needs_a_matte_of_the_scene_size(rng):
    from landmarks.scene.compositing import background_plate

    scene, points, matte = _person_scene(rng)
    with pytest.raises(ValueError, match="matte"):
        background_plate(scene, points, matte[:-1])


def test_a_close_up_moving_down_keeps_its_hair_at_the_frame_top_instead_of_mirroring_what_lies_above(rng):
    """The head layer of a head that leaves the frame's top and moves down would show rows from above the frame,
    which it does not have (a mirrored band of hair, before): the motion fades to none at that edge, so the top
    row stays the scene's and the head a little below it still moves down."""
    import cv2

    noise = cv2.GaussianBlur(rng.random((*SIZE, 3)).astype(np.float32), (0, 0), 3)
    scene = np.clip((noise - noise.mean()) / noise.std() * 50 + 128, 0, 255).astype(np.uint8)
    points = project_canonical(0, 0, 0, SIZE, scale=0.8, translation=(0, -10)).astype(np.float64)
    target = points + [0.0, 12.0]
    result = composite_face(scene, points, target, np.full((128, 128, 3), 90, np.uint8), crop_transform(target, 128))
    x0, y0, x1, y1 = result.box
    assert y0 == 0  # the head region is cut by the frame's top
    region = head_region([points, target], SIZE)
    face_layer = np.zeros(SIZE, bool)
    face_layer[y0:y1, x0:x1] = result.face_alpha > 0
    top = region[0] & ~face_layer[0]
    assert top.sum() > 50
    np.testing.assert_array_equal(result.frame[0, top], scene[0, top])  # the edge itself: the scene's, unmirrored
    # further down the hair moves with the head: row 40 shows rows above it
    column = int(points[27, 0])
    row = 40
    errors = [np.abs(result.frame[row, column - 20 : column + 20].astype(int) - scene[row - d, column - 20 : column + 20]).mean()
              for d in range(0, 13)]
    assert int(np.argmin(errors)) >= 3


def test_a_head_moving_further_than_its_ramp_is_wide_does_not_fold_the_layer(rng):
    """A motion larger than the ramp the head layer fades over folds it (the hair and collar drawn as loops at a
    large turn of a close-up): the ramp then starts further in until the layer does not fold."""
    from landmarks.scene.compositing import _fold_free_weight, _folds, _person_ellipse, _person_weight

    points = project_canonical(0, 0, 0, (480, 640), scale=0.5, translation=(0, 0)).astype(np.float64)
    side = face_side(points)
    shift = 0.12 * side  # 17 pixels: the grown ellipse's ramp is 16 wide
    target = points + [shift, 0.0]
    ellipses = [_person_ellipse(points), _person_ellipse(target)]
    grid_x, grid_y = np.arange(0, 640, 4, dtype=np.float64), np.arange(0, 480, 4, dtype=np.float64)
    shift_x, shift_y = np.full((len(grid_y), len(grid_x)), -shift), np.zeros((len(grid_y), len(grid_x)))
    chin = float(max(points[8, 1], target[8, 1]))
    plain = _person_weight(ellipses, grid_x, grid_y, chin, side)
    assert _folds(grid_x, grid_y, shift_x * plain, shift_y * plain)  # the shipped ramp alone folds here
    weight = _fold_free_weight(ellipses, grid_x, grid_y, shift_x, shift_y, chin, side, True, (1, 1, 639, 479),
                               (480, 640))
    assert not _folds(grid_x, grid_y, shift_x * weight, shift_y * weight)
    assert weight.max() == 1.0 and ((weight > 0) == (plain > 0)).all()  # the head still moves; the region is the same
    # a small motion keeps the shipped ramp, exactly
    small = _fold_free_weight(ellipses, grid_x, grid_y, shift_x / 10, shift_y, chin, side, True, (1, 1, 639, 479),
                              (480, 640))
    np.testing.assert_array_equal(small, plain)
