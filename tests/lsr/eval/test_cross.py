"""Cross-identity metrics (lsr.eval.cross) on constructed faces and frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from landmarks.shape.expression import eye_opening, mouth_opening
from landmarks.motion.head_pose import project_canonical
from landmarks.scene.compositing import composite_face, head_region
from lsr.eval import cross, metrics

SIZE = 128


def _face(yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0, mouth: float = 0.0, eyes: float = 1.0,
          shift: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """A projected canonical face (68, 2) with the inner lips opened by ``mouth`` pixels and the lids scaled by ``eyes``."""
    points = project_canonical(yaw, pitch, roll, (SIZE, SIZE), translation=shift).astype(np.float64)
    points[65:68, 1] += mouth  # lower inner lip down
    for upper, lower in ((37, 41), (38, 40), (43, 47), (44, 46)):
        centre = (points[upper] + points[lower]) / 2
        points[upper] = centre + eyes * (points[upper] - centre)
        points[lower] = centre + eyes * (points[lower] - centre)
    return points


class TestExpression:
    def test_correlation_of_linear_sequences(self):
        driver = np.array([0.0, 0.1, 0.3, 0.2, 0.4])
        assert cross.opening_correlation(driver, 2 * driver + 1) == pytest.approx(1.0)
        assert cross.opening_correlation(driver, -driver) == pytest.approx(-1.0)

    def test_gain_is_the_slope_with_intercept(self):
        driver = np.array([0.0, 0.1, 0.3, 0.2, 0.4])
        assert cross.opening_gain(driver, 0.5 * driver + 0.2) == pytest.approx(0.5)
        assert cross.opening_gain(driver, driver) == pytest.approx(1.0)

    def test_frames_without_a_face_are_dropped(self):
        driver = np.array([0.0, 0.1, 0.3, 0.2, 0.4])
        output = 0.5 * driver
        output[[1, 3]] = np.nan
        assert cross.opening_correlation(driver, output) == pytest.approx(1.0)
        assert cross.opening_gain(driver, output) == pytest.approx(0.5)

    def test_too_few_frames_or_no_variance_is_nan(self):
        assert math.isnan(cross.opening_correlation(np.array([0.0, 1.0, np.nan]), np.array([0.0, 1.0, 2.0])))
        assert math.isnan(cross.opening_correlation(np.array([0.0, 1.0, 2.0]), np.full(3, 0.3)))  # frozen output
        assert math.isnan(cross.opening_gain(np.full(4, 0.1), np.arange(4.0)))
        with pytest.raises(ValueError):
            cross.opening_correlation(np.zeros(3), np.zeros(4))

    def test_openings_of_constructed_faces_follow_the_construction(self):
        faces = np.stack([_face(mouth=m) for m in (0.0, 2.0, 4.0, 6.0)])
        assert np.all(np.diff(mouth_opening(faces)) > 0)
        blink = np.stack([_face(eyes=e) for e in (1.0, 0.2)])
        assert eye_opening(blink)[1] < eye_opening(blink)[0]


class TestPose:
    def test_errors_are_absolute_and_wrapped(self):
        errors = cross.pose_errors(np.array([179.0, 10.0, -5.0]), np.array([-179.0, 4.0, 5.0]))
        assert errors == pytest.approx([2.0, 6.0, 10.0])
        assert np.isnan(cross.pose_errors(np.full(3, np.nan), np.zeros(3))).all()


class TestScene:
    def test_a_proper_composite_keeps_the_scene_and_one_into_another_background_fails(self, rng):
        scene = rng.integers(0, 256, size=(SIZE, SIZE, 3), dtype=np.uint8)
        elsewhere = rng.integers(0, 256, size=(SIZE, SIZE, 3), dtype=np.uint8)
        output = rng.integers(0, 256, size=(SIZE, SIZE, 3), dtype=np.uint8)
        anchor, target = _face(), _face(yaw=12, pitch=-5, roll=3, shift=(3, 2))
        outside = ~head_region([anchor, target], (SIZE, SIZE))
        assert 0.2 < outside.mean() < 0.95  # a real scene region, not all or nothing
        proper = composite_face(scene, anchor, target, output, np.eye(2, 3)).frame
        wrong = composite_face(elsewhere, anchor, target, output, np.eye(2, 3)).frame  # pasted into another frame
        assert metrics.psnr_from_mse(cross.scene_mse(proper, scene, outside)) >= 30.0
        assert metrics.psnr_from_mse(cross.scene_mse(wrong, scene, outside)) < 15.0
        assert math.isnan(cross.scene_mse(proper, scene, np.zeros((SIZE, SIZE), bool)))

    def test_flicker_counts_only_the_shared_outside(self, rng):
        frame = rng.integers(20, 230, size=(32, 32, 3), dtype=np.uint8)
        outside = np.ones((32, 32), bool)
        assert cross.scene_flicker(frame, frame, outside, outside) == 0.0
        assert cross.scene_flicker(frame, frame + 10, outside, outside) == pytest.approx(10.0)
        inside_changed = frame.copy()
        inside_changed[:16] = 0
        lower = np.zeros((32, 32), bool)
        lower[16:] = True
        assert cross.scene_flicker(frame, inside_changed, outside, lower) == 0.0  # the change is in a head region
        assert math.isnan(cross.scene_flicker(frame, frame, ~lower, lower))  # nothing shared

    def test_face_sharpness(self, rng):
        import cv2

        scene = rng.integers(0, 256, size=(SIZE, SIZE, 3), dtype=np.uint8)
        face = _face()
        assert cross.face_sharpness(scene, face, scene, face) == pytest.approx(1.0)
        blurred = cv2.GaussianBlur(scene, (0, 0), 2.0)
        assert cross.face_sharpness(blurred, face, scene, face) < 0.2
        flat = np.full_like(scene, 100)
        assert math.isnan(cross.face_sharpness(scene, face, flat, face))


def test_figure_frames_pick_mouth_o_blink_and_turn():
    driver = np.stack([_face(), _face(mouth=5.0), _face(eyes=0.1), _face(mouth=3.0), _face(yaw=25.0), _face(), _face()])
    driver[3, 64, 0] -= 4.0  # a narrower inner mouth: rounder than frame 1's
    driver[3, 60, 0] += 4.0
    assert cross.figure_frames(driver, (SIZE, SIZE)) == [("mouth", 1), ("O", 3), ("blink", 2), ("turn", 4)]
    shared = dict((index, label) for label, index in cross.figure_frames(driver[:3], (SIZE, SIZE)))
    assert shared[1].split("+")[:2] == ["mouth", "O"]  # one frame, both reasons
    assert len(shared) <= 3
    with pytest.raises(ValueError):
        cross.figure_frames(np.full((2, 68, 2), np.nan), (SIZE, SIZE))


def _record(identity: str, driver_mouth: float, output_mouth: float, scene_psnr: float, **extra) -> dict:
    base = {"method": "m", "k": 1, "identity": identity, "driver": "d", "no_face": False, "idsim_source": 0.9, "nmke": 0.1,
            "yaw_error": 2.0, "pitch_error": 1.0, "roll_error": 0.5, "driver_mouth": driver_mouth,
            "output_mouth": output_mouth, "driver_eye": 0.3, "output_eye": 0.3, "sharpness_face": 1.0,
            "scene_mse": 0.0 if math.isinf(scene_psnr) else 255.0**2 / 10 ** (scene_psnr / 10),
            "scene_psnr": scene_psnr, "scene_flicker": 0.0}
    return {**base, **extra}


def test_pooled_gain_weighs_each_sequence_by_its_drivers_motion():
    """A driver that barely moves gives a slope that is mostly noise; pooled, it adds little."""
    rng = np.random.default_rng(0)
    wide = np.linspace(0.0, 0.4, 20)
    quiet = 0.1 + 0.002 * rng.standard_normal(20)
    noisy = 0.1 + 0.01 * rng.standard_normal(20)  # the output's reading, unrelated to so small a motion
    slopes = [cross.opening_gain(wide, wide), cross.opening_gain(quiet, noisy)]
    pooled = cross.pooled_gain([(wide, wide), (quiet, noisy)])
    assert abs(pooled - 1.0) < 0.05 < abs(np.mean(slopes) - 1.0)
    spread = [float(np.sum((part - part.mean()) ** 2)) for part in (wide, wide[:10])]  # each driver's variance
    assert cross.pooled_gain([(wide, 0.5 * wide + 0.1), (wide[:10], wide[:10])]) == pytest.approx(
        (0.5 * spread[0] + spread[1]) / sum(spread))  # the slopes 0.5 and 1, weighed by their drivers' motion
    assert math.isnan(cross.pooled_gain([(np.full(5, 0.1), wide[:5]), (wide[:2], wide[:2])]))  # none usable
    assert cross.pooled_gain([(wide, 2 * wide), (wide[:2], wide[:2])]) == pytest.approx(2.0)  # 2 frames: left out


def test_summary_averages_per_sequence_measures():
    records = [_record("a", d, 2 * d, math.inf) for d in (0.0, 0.1, 0.2, 0.3)]
    records += [_record("b", d, 0.5 * d + 0.1, 40.0, scene_flicker=2.0) for d in (0.0, 0.2, 0.1, 0.4)]
    records[-1].update(no_face=True, output_mouth=math.nan, nmke=math.nan)
    (row,) = cross.summarise_cross(records, ["m"], [1])
    assert row["frames"] == 8 and row["sequences"] == 2 and row["no_face"] == 1
    assert row["mouth_corr"] == pytest.approx(1.0) and row["mouth_gain_per_sequence"] == pytest.approx(1.25)  # 2, 0.5
    # pooled: a's covariance 0.1 over variance 0.05, b's (its face-less frame dropped) 0.01 over 0.02
    assert row["mouth_gain"] == pytest.approx(0.11 / 0.07)
    assert math.isnan(row["eye_corr"]) and math.isnan(row["eye_gain"])  # constant eyes: no correlation or gain to speak of
    assert row["scene_psnr"] == pytest.approx(40.0) and row["scene_psnr_infinite"] == 4
    assert row["scene_flicker"] == pytest.approx(1.0) and row["nmke"] == pytest.approx(0.1)
    assert row["yaw_error"] == 2.0 and row["sharpness_face"] == 1.0
    assert cross.summarise_cross(records, ["other"], [1]) == []
