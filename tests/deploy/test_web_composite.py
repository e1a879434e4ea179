"""The web runtime's scene composite (deploy/web/src/composite.ts) against landmarks.scene.compositing.composite_face."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from landmarks.scene import compositing as scene_module
from landmarks.align import crop_transform, warp_to_crop


def _psnr(first: np.ndarray, second: np.ndarray) -> float:
    error = np.mean((first.astype(np.float64) - second.astype(np.float64)) ** 2)
    return float("inf") if error == 0 else float(10 * np.log10(255**2 / error))


@pytest.fixture(scope="module")
def real_frames() -> tuple[np.ndarray, np.ndarray]:
    """Two frames of the bundled real video (360 x 288) and their 68 points (the default detector)."""
    from landmarks.detect.registry import make_detector
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_SOURCE

    detector = make_detector()
    frames = [frame for index, frame in enumerate(iter_frames(REAL_SOURCE)) if index in (0, 40)]
    return np.stack(frames), np.stack([detector.detect_one(frame).landmarks.astype(np.float64) for frame in frames])


def _moved(points: np.ndarray, degrees: float, shift: tuple[float, float], scale: float = 1.0) -> np.ndarray:
    """The head moved by a similarity about its centre."""
    angle = np.deg2rad(degrees)
    rotation = scale * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    centre = points.mean(0)
    return (points - centre) @ rotation.T + centre + np.asarray(shift)


def _layers(scene: np.ndarray, points: np.ndarray) -> scene_module.SceneLayers:
    """A person matte (a soft blob over the head and shoulders) and the plate Python makes from it."""
    height, width = scene.shape[:2]
    rows, cols = np.mgrid[0:height, 0:width]
    centre, side = points.mean(0), scene_module.face_side(points)
    matte = np.clip(1.3 - np.hypot((cols - centre[0]) / (0.45 * side), (rows - centre[1] - 0.15 * side) / (0.7 * side)), 0, 1)
    matte = cv2.GaussianBlur(matte.astype(np.float32), (0, 0), 3)
    return scene_module.background_plate(scene, points, matte)


def _compare(web, cases) -> list[float]:
    """cases: (scene, scene points, target points, face crop, crop matrix, layers or None): the web composite of each
    against Python's: the same box, the frame within 40 dB PSNR, bit for bit outside the box."""
    calls = [("compositeFace", [scene, points, target, face, list(matrix.ravel())]
              + ([{"matte": layers.matte, "plate": layers.plate}] if layers is not None else []))
             for scene, points, target, face, matrix, layers in cases]
    values = []
    for (scene, points, target, face, matrix, layers), got in zip(cases, web.calls(*calls)):
        expected = scene_module.composite_face(scene, points, target, face, matrix, layers)
        assert got["frame"].shape == scene.shape and got["frame"].dtype == np.uint8
        assert (tuple(got["box"]) if got["box"] is not None else None) == expected.box
        values.append(_psnr(got["frame"], expected.frame))
        assert values[-1] >= 40, values[-1]
        outside = np.ones(scene.shape[:2], bool)
        if expected.box is not None:
            x0, y0, x1, y1 = expected.box
            outside[y0:y1, x0:x1] = False
            np.testing.assert_allclose(np.reshape(got["headMotion"], (2, 3)), expected.head_motion, atol=1e-9)
            np.testing.assert_allclose(got["faceAlpha"], expected.face_alpha, atol=1e-3)
        np.testing.assert_array_equal(got["frame"][outside], scene[outside])
    return values


def test_a_moved_head_composites_as_python(web, real_frames):
    frames, landmarks = real_frames
    scene, points = frames[0], landmarks[0]
    target = _moved(points, 4.0, (5.0, -3.0))
    matrix = crop_transform(target, 256)
    own = warp_to_crop(scene, matrix, 256)  # the scene's own face at the target's framing
    other = warp_to_crop(frames[1], crop_transform(landmarks[1], 256), 256)  # another frame's: the colours differ
    layers = _layers(scene, points)
    values = _compare(web, [(scene, points, target, own, matrix, None), (scene, points, target, own, matrix, layers),
                            (scene, points, target, other, matrix, None), (scene, points, target, other, matrix, layers)])
    print(f"moved head, PSNR against Python (dB): {np.round(values, 1).tolist()}")


def test_still_heads_cut_heads_and_small_faces_composite_as_python(web, real_frames):
    frames, landmarks = real_frames
    scene, points = frames[0], landmarks[0]
    face = warp_to_crop(frames[1], crop_transform(landmarks[1], 256), 256)
    cases = [(scene, points, points, face, crop_transform(points, 256), None)]  # no motion: the head layer stays
    # the head cut by the frame's left edge (the box and the face layer clipped)
    cut, cut_points = scene[:, 110:].copy(), points - [110.0, 0.0]
    cut_target = _moved(cut_points, -3.0, (-6.0, 2.0), 1.04)
    cases += [(cut, cut_points, cut_target, face, crop_transform(cut_target, 256), layers)
              for layers in (None, _layers(cut, cut_points))]
    # a small face (side < 50 px): the colour match blurs at full size
    small = cv2.resize(scene, (80, 64), interpolation=cv2.INTER_AREA)
    small_points = points * [80 / 360, 64 / 288]
    small_target = _moved(small_points, 5.0, (1.5, -1.0))
    assert scene_module.face_side(small_target) < 50
    cases.append((small, small_points, small_target, face, crop_transform(small_target, 256), None))
    values = _compare(web, cases)
    print(f"still / cut / small, PSNR against Python (dB): {np.round(values, 1).tolist()}")


def test_masks_and_blur_match_opencv(web, rng):
    ellipses = [60.3, 70.7, 40.2, 52.9, 10.1, 100.5, 30.0, 60.0]  # (cx, cy, a, b) twice, the second cut by the edge
    points = rng.integers(-5, 100, (27, 2))
    values = rng.random((61, 47, 3)).astype(np.float32)
    ellipse, hull, distance, small, large, single = web.calls(
        ("sceneMask", ["ellipse", 120, 110, ellipses]), ("sceneMask", ["hull", 100, 90, list(points.ravel())]),
        ("sceneMask", ["distance", 100, 90, list(points.ravel())]), ("sceneBlur", [values, 4.0]),
        ("sceneBlur", [values, 20.0]), ("sceneBlur", [values[..., 0].copy(), 15.0]))
    pairs = [(np.array(ellipses[i : i + 2]), np.array(ellipses[i + 2 : i + 4])) for i in (0, 4)]
    np.testing.assert_array_equal(ellipse, scene_module._inside_heads(pairs, (120, 110), (0, 0)))
    expected_hull = np.zeros((100, 90), np.uint8)
    cv2.fillConvexPoly(expected_hull, cv2.convexHull(points.astype(np.int32)), 1)
    np.testing.assert_array_equal(hull, expected_hull)
    np.testing.assert_allclose(distance, cv2.distanceTransform(1 - expected_hull, cv2.DIST_L2, 3), atol=1e-4)
    np.testing.assert_allclose(small, scene_module.blur(values, 4.0), atol=1e-5)
    np.testing.assert_allclose(large, scene_module.blur(values, 20.0), atol=1e-5)
    np.testing.assert_allclose(single, scene_module.blur(values[..., 0].copy(), 15.0), atol=1e-5)


def test_bad_landmarks_raise(web, real_frames):
    frames, landmarks = real_frames
    with pytest.raises(RuntimeError, match="target_landmarks"):
        web.call("compositeFace", frames[0], landmarks[0], np.full((68, 2), np.nan), np.zeros((64, 64, 3), np.uint8),
                 [1.0, 0.0, 0.0, 0.0, 1.0, 0.0])


def test_a_close_up_moving_far_composites_as_python(web, real_frames):
    """A head cut by the frame's top that moves down and aside further than its ramp is wide: the head layer fades
    to none at the edges it would reach past and starts its ramp further in where it would fold
    (landmarks.scene.compositing._fold_free_weight), in the web page as in Python."""
    frames, landmarks = real_frames
    scene, points = frames[0][90:, 40:-40].copy(), landmarks[0] - [40.0, 90.0]
    target = _moved(points, 8.0, (0.15 * scene_module.face_side(points), 14.0), 0.9)
    assert scene_module.composite_face(scene, points, target, np.zeros((256, 256, 3), np.uint8),
                                       crop_transform(target, 256)).box[1] == 0  # cut by the top
    face = warp_to_crop(frames[1], crop_transform(landmarks[1], 256), 256)
    values = _compare(web, [(scene, points, target, face, crop_transform(target, 256), layers)
                            for layers in (None, _layers(scene, points))])
    print(f"close-up moving far, PSNR against Python (dB): {np.round(values, 1).tolist()}")
