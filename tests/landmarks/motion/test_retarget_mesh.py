"""Cross-identity driving of face meshes (landmarks.motion.retarget_mesh): the 2D retargeting of the 68 points on every
vertex, and the 3D one that turns the source's own head."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.motion import retarget_mesh as mesh_retarget
from landmarks.warp import piecewise_affine as mesh_warp
from landmarks.shape.mesh68 import mesh_to_68


def _face(scale: float = 26.0, centre: tuple[float, float] = (48.0, 44.0)) -> np.ndarray:
    """(468, 2) float64: the canonical mesh placed in a frame."""
    return mesh_warp.frontal_canonical() * scale + np.asarray(centre)


class TestRetargetMesh:
    def _driver(self, rng: np.random.Generator, opening: float = 0.0, jitter: float = 0.3) -> np.ndarray:
        """(4, 468, 2): a reference frame, then turned, zoomed and jittered frames with the mouth opened by ``opening``
        (the 68 points' jaw drop of ``set_mouth_opening``, spread onto the vertices)."""
        from landmarks.shape.expression import mouth_opening, set_mouth_opening

        reference = _face(20.0, (50.0, 40.0))
        points = mesh_to_68(reference).astype(np.float64)
        opened = reference + mesh_retarget.spreading_weights() @ (
            set_mouth_opening(points, mouth_opening(points) + opening) - points)
        frames = [reference]
        for turn in (0.05, -0.08, 0.1):
            rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
            frames.append((opened - 45.0) @ rotation.T * (1 + turn) + 45.0 + rng.normal(0, jitter, reference.shape))
        return np.stack(frames)

    def test_matches_the_68_point_retargeting(self, rng):
        from landmarks.shape.expression import mouth_opening
        from landmarks.motion.retarget_points import retarget_driving

        driver = self._driver(rng, opening=0.15)
        source = _face(30.0, (40.0, 50.0))
        moved = mesh_retarget.retarget_mesh(driver, driver[0], source)
        assert moved.shape == (4, 468, 2)
        np.testing.assert_allclose(moved[0], source, atol=0.05 * 30.0 * 0.1)  # the reference frame maps onto the source
        points = [mesh_to_68(mesh).astype(np.float64) for mesh in (driver, driver[0], source)]
        expected = retarget_driving(*points)  # what the 68 points of the same frames are driven with
        error = np.linalg.norm(mesh_to_68(moved) - expected, axis=-1)
        assert error.max() < 0.03 * 30.0  # within 3 % of the inter-ocular distance
        np.testing.assert_allclose(mouth_opening(mesh_to_68(moved).astype(np.float64)),
                                   mouth_opening(points[0]), atol=0.01)  # as open as the driver's, not relative

    def test_opening_the_mouth_does_not_fold_the_mesh(self, rng):
        triangles = mesh_warp.triangulation()
        source = _face(30.0, (40.0, 50.0))
        for opening in (0.0, 0.2):
            moved = mesh_retarget.retarget_mesh(self._driver(rng, opening, jitter=0.0), _face(20.0, (50.0, 40.0)), source)
            # the lower lip's vertices went down with it: (almost) nothing folds
            assert np.all(np.sum(mesh_warp.signed_areas(moved, triangles) < 0, axis=1) <= 0.01 * len(triangles))

    def test_missing_frames_stay_missing_and_bad_inputs_raise(self, rng):
        driver = self._driver(rng)
        driver[2] = np.nan
        moved = mesh_retarget.retarget_mesh(driver, driver[0], _face())
        assert np.isnan(moved[2]).all() and np.isfinite(moved[[0, 1, 3]]).all()
        with pytest.raises(ValueError):
            mesh_retarget.retarget_mesh(driver, np.full((468, 2), np.nan), _face())
        with pytest.raises(ValueError):
            mesh_retarget.retarget_mesh(driver[:, :68], driver[0], _face())


def _rotation(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """(3, 3) rotation by degrees about y (yaw), x (pitch), z (roll)."""
    y, p, r = np.radians([yaw, pitch, roll])
    about_y = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    about_x = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    about_z = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    return about_z @ about_x @ about_y


def _head(scale: float, centre: tuple[float, float], rotation: np.ndarray | None = None,
          shape: np.ndarray | None = None) -> np.ndarray:
    """(468, 3): the canonical head (or ``shape``, in its units) turned, scaled and placed in frame pixels."""
    from landmarks.motion.mesh_rotation import canonical

    vertices = canonical()[0] if shape is None else shape
    rotation = np.eye(3) if rotation is None else rotation
    return vertices @ rotation.T * scale + np.array([*centre, 0.0])


class TestRetargetMesh3d:
    def _other_shape(self, rng: np.random.Generator) -> np.ndarray:
        """Another person: the canonical head widened and with a longer face, plus per-vertex noise."""
        from landmarks.motion.mesh_rotation import canonical

        vertices = canonical()[0]
        return vertices * np.array([1.12, 0.93, 1.0]) + rng.normal(0, 0.004, vertices.shape) * np.ptp(vertices[:, 0])

    def test_the_reference_frame_gives_the_source(self, rng):
        source = _head(120.0, (250.0, 260.0), _rotation(8.0, -4.0, 3.0), self._other_shape(rng))
        reference = _head(90.0, (200.0, 220.0), _rotation(-5.0, 2.0, -2.0))
        moved = mesh_retarget.retarget_mesh_3d(reference[None], reference, source)
        assert moved.shape == (1, 468, 3)
        scale = np.ptp(source[:, 0])
        from landmarks.shape.expression import mouth_opening

        if abs(mouth_opening(mesh_to_68(source).astype(float)) - mouth_opening(mesh_to_68(reference).astype(float))) < 1e-3:
            np.testing.assert_allclose(moved[0], source, atol=1e-6 * scale)
        # away from the mouth (which takes the driver's opening) the source is kept
        np.testing.assert_allclose(moved[0][:, :2][_far_from_mouth()], source[:, :2][_far_from_mouth()], atol=0.02 * scale)

    def test_a_head_turn_turns_the_sources_own_face(self, rng):
        shape = self._other_shape(rng)
        source = _head(120.0, (250.0, 260.0), _rotation(5.0), shape)
        reference = _head(90.0, (200.0, 220.0))
        turns = ((25.0, 0.0, 0.0), (-30.0, 10.0, 0.0), (10.0, -5.0, 12.0))
        driver = np.stack([_head(90.0, (200.0, 220.0), _rotation(*turn)) for turn in turns])
        moved = mesh_retarget.retarget_mesh_3d(driver, reference, source)
        keep = _far_from_mouth()
        for frame, turn in zip(moved, turns):
            # the source's own head turned by the driver's rotation about its centre (and nothing else)
            expected = _head(120.0, (250.0, 260.0), _rotation(*turn) @ _rotation(5.0), shape)
            np.testing.assert_allclose(frame[keep], expected[keep], atol=0.01 * np.ptp(source[:, 0]))

    def test_the_2d_retargeting_carries_the_drivers_shape_into_a_turn(self, rng):
        """Why 3D: the 2D similarity cannot express yaw, so the driver's turned face shape is added as a delta."""
        shape = self._other_shape(rng)
        source = _head(120.0, (250.0, 260.0), None, shape)
        reference = _head(90.0, (200.0, 220.0))
        driver = _head(90.0, (200.0, 220.0), _rotation(30.0))[None]
        expected = _head(120.0, (250.0, 260.0), _rotation(30.0), shape)
        error_3d = np.linalg.norm(mesh_retarget.retarget_mesh_3d(driver, reference, source)[0, :, :2] - expected[:, :2], axis=1)
        error_2d = np.linalg.norm(mesh_retarget.retarget_mesh(driver, reference, source)[0] - expected[:, :2], axis=1)
        keep = _far_from_mouth()
        assert np.median(error_3d[keep]) < 0.3 * np.median(error_2d[keep])

    def test_the_mouth_opens_as_the_drivers_and_missing_frames_stay_missing(self, rng):
        from landmarks.shape.expression import mouth_opening

        source = _head(120.0, (250.0, 260.0), None, self._other_shape(rng))
        reference = _head(90.0, (200.0, 220.0))
        points = mesh_to_68(reference[:, :2]).astype(np.float64)
        from landmarks.shape.expression import set_mouth_opening

        opened = reference.copy()
        opened[:, :2] += mesh_retarget.spreading_weights() @ (set_mouth_opening(points, 0.3) - points)
        driver = np.stack([opened, np.full((468, 3), np.nan)])
        moved = mesh_retarget.retarget_mesh_3d(driver, reference, source)
        assert np.isnan(moved[1]).all() and np.isfinite(moved[0]).all()
        assert abs(mouth_opening(mesh_to_68(moved[0, :, :2]).astype(np.float64)) - 0.3) < 0.02

    def test_bad_inputs_raise(self):
        head = _head(90.0, (200.0, 220.0))
        with pytest.raises(ValueError):
            mesh_retarget.retarget_mesh_3d(head[None, :, :2], head, head)  # no depth
        with pytest.raises(ValueError):
            mesh_retarget.retarget_mesh_3d(head[None], np.full((468, 3), np.nan), head)
        with pytest.raises(ValueError):
            mesh_retarget.retarget_mesh_3d(head[None], head[:68], head)


def _far_from_mouth() -> np.ndarray:
    """(468,) bool: vertices whose spreading weights take nothing from the mouth and jaw (68 points 3-13, 48-67)."""
    weights = mesh_retarget.spreading_weights()
    return weights[:, list(range(3, 14)) + list(range(48, 68))].sum(1) == 0


@pytest.mark.parametrize("mode", ["2d", "3d"])
def test_retarget_face_shuts_the_sources_eyes_at_the_drivers_blink(mode):
    """A driver's blink (lids down to the fold) shuts the source's eyes, whatever their size, in the mesh and in the
    68 points; the reference frame leaves the source's own eyes."""
    from landmarks.parts.eyes import lids as eyelids

    reference = _head(90.0, (200.0, 220.0))
    blink = eyelids.set_lid_gaps(reference, eyelids.closed_gaps(eyelids.lid_gaps(reference)))  # lids down to the fold
    source = eyelids.set_lid_gaps(_head(120.0, (250.0, 260.0)), eyelids.lid_gaps(reference) * 1.4)  # wide eyes
    driver = np.stack([reference, blink])
    landmarks = mesh_to_68(driver[..., :2]).astype(np.float64)
    source_points = mesh_to_68(source[:, :2]).astype(np.float64)
    targets, meshes = mesh_retarget.retarget_face(landmarks, landmarks[0], source_points, driver, reference, source,
                                                  mode=mode)
    np.testing.assert_allclose(eyelids.lid_gaps(meshes[0]), eyelids.lid_gaps(source), rtol=1e-6)
    np.testing.assert_allclose(eyelids.lid_gaps(meshes[1]), eyelids.closed_gaps(eyelids.lid_gaps(source)), rtol=1e-6)
    shut = eyelids.closed_gaps(eyelids.lid_gaps(source_points))  # the 68 points' lids, measured on them
    open_gap = eyelids.lid_gaps(source_points) - shut
    assert np.abs(eyelids.lid_gaps(targets[0]) - eyelids.lid_gaps(source_points)).max() < 0.05 * open_gap.min()
    assert (eyelids.lid_gaps(targets[1]) - shut < 0.25 * open_gap).all()


@pytest.mark.parametrize("mode", ["2d", "3d"])
def test_a_stream_is_driven_as_the_whole_driver_at_once(mode):
    """What ``lsr reenact`` does frame by frame (``DriverReference``: the first face, the lids' reference from the
    faces seen ahead and so far) is what ``lsr eval`` does to the whole driver at once (``running_reference_gaps``),
    so the evaluation measures the re-enactment users get; a driver whose first face blinks included."""
    from landmarks.parts.eyes import lids as eyelids

    reference = _head(90.0, (200.0, 220.0))
    closed = eyelids.closed_gaps(eyelids.lid_gaps(reference))
    driver = np.stack([eyelids.set_lid_gaps(_head(90.0 + step, (200.0 + 2 * step, 220.0)), gaps)
                       for step, gaps in enumerate([closed, *[eyelids.lid_gaps(reference)] * 3, 0.5 * closed])])
    landmarks = mesh_to_68(driver[..., :2]).astype(np.float64)
    source = _head(120.0, (250.0, 260.0))
    source_points = mesh_to_68(source[:, :2]).astype(np.float64)
    batch = mesh_retarget.retarget_face(landmarks, landmarks[0], source_points, driver, driver[0], source, mode,
                                        eyelids.running_reference_gaps(landmarks),
                                        eyelids.running_reference_gaps(driver))
    stream = mesh_retarget.DriverReference()
    stream.look_ahead(list(landmarks), list(driver))
    for index, (points, mesh) in enumerate(zip(landmarks, driver)):
        gaps, mesh_gaps = stream.lids(points, mesh)
        stream.start(points, mesh)
        one = mesh_retarget.retarget_face(points[None], stream.landmarks, source_points, mesh[None], stream.mesh,
                                          source, mode, gaps, mesh_gaps)
        np.testing.assert_allclose(one[0][0], batch[0][index], atol=1e-9)
        np.testing.assert_allclose(one[1][0], batch[1][index], atol=1e-9)
    # the driver's open eyes (frames 1-3) give the source its own, though the first face blinked
    for index in (1, 2, 3):
        np.testing.assert_allclose(eyelids.lid_gaps(batch[1][index]), eyelids.lid_gaps(source), rtol=1e-6)
