"""Retargeting: Procrustes, relative motion transfer keeps the source's shape, absolute re-placing."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.motion.head_pose import project_canonical
from landmarks.motion.retarget_points import (
    RIGID_INDEX,
    apply_similarity,
    retarget_absolute,
    retarget_relative,
    similarity_procrustes,
)

RIGID = list(RIGID_INDEX)


def rotation(degrees: float) -> np.ndarray:
    angle = np.radians(degrees)
    return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])


def source_face() -> np.ndarray:
    return project_canonical(0.0, 0.0, 2.0, (256, 256)).astype(np.float64)


def driver_face() -> np.ndarray:
    """A different identity: wider jaw, longer nose, bigger, placed elsewhere, slight roll."""
    face = project_canonical(0.0, 0.0, -4.0, (400, 400), scale=1.3, translation=(30.0, -10.0)).astype(np.float64)
    centre = face.mean(0)
    face[0:17, 0] = centre[0] + (face[0:17, 0] - centre[0]) * 1.25  # wide jaw
    face[31:36, 1] += 8.0  # nose base lower
    return face


def inter_ocular(face: np.ndarray) -> float:
    return float(np.linalg.norm(face[42:48].mean(0) - face[36:42].mean(0)))


def inner_lip_gap(face: np.ndarray) -> float:
    return float(np.linalg.norm(face[66] - face[62]))


def normalised_jaw(face: np.ndarray, onto: np.ndarray) -> np.ndarray:
    """Jaw points after similarity-aligning the face's rigid points onto ``onto``'s."""
    return apply_similarity(face, *similarity_procrustes(face[RIGID], onto[RIGID]))[0:17]


class TestProcrustes:
    def test_recovers_known_similarity(self, rng):
        points = rng.normal(size=(30, 2))
        target = apply_similarity(points, 2.5, rotation(33.0), np.array([4.0, -7.0]))
        scale, rot, shift = similarity_procrustes(points, target)
        assert scale == pytest.approx(2.5)
        np.testing.assert_allclose(rot, rotation(33.0), atol=1e-12)
        np.testing.assert_allclose(shift, [4.0, -7.0], atol=1e-12)

    def test_never_reflects(self, rng):
        points = rng.normal(size=(20, 2))
        _, rot, _ = similarity_procrustes(points, points * [-1, 1])
        assert np.linalg.det(rot) == pytest.approx(1.0)

    @pytest.mark.parametrize(
        "first, second, message",
        [(np.zeros((5, 2)), np.zeros((6, 2)), "same N"), (np.ones((5, 2)), np.ones((5, 2)), "coincide"),
         (np.full((5, 2), np.nan), np.ones((5, 2)), "NaN")],
    )
    def test_bad_inputs(self, first, second, message):
        with pytest.raises(ValueError, match=message):
            similarity_procrustes(first, second)


class TestRetargetRelative:
    def test_identity_returns_source(self):
        source, driver = source_face(), driver_face()
        out = retarget_relative(np.stack([driver, driver]), driver, source)
        assert out.shape == (2, 68, 2)
        np.testing.assert_allclose(out, np.stack([source, source]), atol=1e-9)
        np.testing.assert_allclose(retarget_relative(driver, driver, source), source, atol=1e-9)

    def test_keeps_source_shape(self):
        source, reference = source_face(), driver_face()
        frame = reference.copy()
        frame[[37, 38, 43, 44]] += [0.0, 4.0]  # half blink
        frame[17:27, 1] -= 5.0  # brows up
        out = retarget_relative(frame[None], reference, source)[0]
        assert inter_ocular(out) == pytest.approx(inter_ocular(source), rel=0.01)
        jaw_error = np.abs(normalised_jaw(out, source) - source[0:17]).max()
        driver_jaw_error = np.abs(normalised_jaw(frame, source) - source[0:17]).max()
        assert jaw_error < 0.05 * inter_ocular(source)  # the source's jaw, not the driver's
        assert driver_jaw_error > 5 * jaw_error

    def test_transfers_mouth_opening_scaled(self):
        source, reference = source_face(), driver_face()
        opening = 12.0
        frame = reference.copy()
        frame[[65, 66, 67]] += [0.0, opening]  # lower inner lip drops
        frame[55:60] += [0.0, opening]  # lower outer lip
        out = retarget_relative(frame, reference, source)
        size_ratio = similarity_procrustes(reference[RIGID], source[RIGID])[0]
        assert 0.3 < size_ratio < 0.8  # the driver really is bigger
        growth = inner_lip_gap(out) - inner_lip_gap(source)
        assert growth == pytest.approx(opening * size_ratio, rel=0.03)

    def test_transfers_rigid_motion(self):
        source, reference = source_face(), driver_face()
        centre = reference[RIGID].mean(0)
        moved = apply_similarity(reference - centre, 1.1, rotation(10.0), centre + [25.0, -15.0])
        out = retarget_relative(moved, reference, source)
        scale, rot, shift = similarity_procrustes(source, out)
        size_ratio = similarity_procrustes(reference[RIGID], source[RIGID])[0]
        assert scale == pytest.approx(1.1, rel=1e-6)
        assert np.degrees(np.arctan2(rot[1, 0], rot[0, 0])) == pytest.approx(10.0, abs=1e-6)
        # Pure rigid driver motion: the output is the source moved rigidly (no shape change).
        np.testing.assert_allclose(apply_similarity(source, scale, rot, shift), out, atol=1e-6)
        # Translation scaled into the source's size: centre shift = ratio * driver shift (small roll aside).
        shift_out = out[RIGID].mean(0) - source[RIGID].mean(0)
        assert np.linalg.norm(shift_out) == pytest.approx(np.linalg.norm([25.0, -15.0]) * size_ratio, rel=0.15)

    def test_nan_frames_stay_nan(self):
        source, reference = source_face(), driver_face()
        frames = np.stack([reference, np.full((68, 2), np.nan), reference])
        out = retarget_relative(frames, reference, source)
        assert np.isnan(out[1]).all() and np.isfinite(out[[0, 2]]).all()

    def test_bad_inputs(self):
        source, reference = source_face(), driver_face()
        with pytest.raises(ValueError, match="driver"):
            retarget_relative(np.zeros((3, 67, 2)), reference, source)
        with pytest.raises(ValueError, match="source"):
            retarget_relative(reference, reference, np.full((68, 2), np.nan))


class TestRetargetAbsolute:
    def test_aligns_driver_onto_source_placement(self):
        source, driver = source_face(), driver_face()
        frames = np.stack([driver, np.full((68, 2), np.nan), driver + [5.0, 0.0]])
        out = retarget_absolute(frames, source)
        assert np.isnan(out[1]).all()
        # Reference frame lands on the source's rigid points (up to the shape difference).
        residual = np.abs(out[0][RIGID] - source[RIGID]).mean()
        assert residual < 0.1 * inter_ocular(source)
        # The driver's own shape is kept: one similarity for all frames.
        scale, _, _ = similarity_procrustes(driver, out[0])
        np.testing.assert_allclose(out[2] - out[0], np.tile((out[2] - out[0])[0], (68, 1)), atol=1e-9)
        assert np.linalg.norm((out[2] - out[0])[0]) == pytest.approx(5.0 * scale)

    def test_all_nan_raises(self):
        with pytest.raises(ValueError, match="NaN"):
            retarget_absolute(np.full((2, 68, 2), np.nan), source_face())
