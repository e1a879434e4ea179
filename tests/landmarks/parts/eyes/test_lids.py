"""landmarks.parts.eyes.lids: a closing target's upper lids lowered so that a warp shows its aperture, not its gap."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.parts.eyes import lids as eyelids
from landmarks.warp import piecewise_affine as mesh_warp
from landmarks.shape.mesh68 import mesh_to_68
from landmarks.motion.mesh_rotation import canonical

SIZE = 128
UPPER = [vertex for _, _, upper, _ in eyelids.MESH_LIDS.eyes for vertex in upper]


def _mesh(scale: float = 0.6, centre: tuple[float, float] = (64.0, 60.0), roll: float = 0.0) -> np.ndarray:
    """(468, 3) float64: the canonical mesh rolled by ``roll`` degrees in the image plane, in a SIZE^2 frame."""
    vertices = canonical()[0] - canonical()[0].mean(0)
    angle = np.radians(roll)
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    return vertices @ rotation.T * scale + np.array([*centre, 0.0])


def _blink(mesh: np.ndarray, fraction: float, eyes: tuple[int, ...] = (0, 1)) -> np.ndarray:
    """``mesh`` with each upper lid moved ``fraction`` of the way to its lower lid, across the eye's corner line."""
    moved = mesh.copy()
    for eye in eyes:
        outer, inner, upper, lower = eyelids.MESH_LIDS.eyes[eye]
        upper, lower = list(upper), list(lower)
        along = (mesh[inner, :2] - mesh[outer, :2]) / np.linalg.norm(mesh[inner, :2] - mesh[outer, :2])
        across = np.array([-along[1], along[0]])
        order = np.argsort(mesh[lower, :2] @ along)
        lower_at = np.interp(mesh[upper, :2] @ along, (mesh[lower, :2] @ along)[order],
                             (mesh[lower, :2] @ across)[order])
        moved[upper, :2] += fraction * (lower_at - mesh[upper, :2] @ across)[:, None] * across
    return moved


def test_lid_gaps_measure_the_open_eyes_whatever_the_head_placement():
    gaps = eyelids.lid_gaps(_mesh())
    assert gaps.shape == (2,) and 0.08 < gaps.min() and gaps.max() < 0.2  # an open eye, in eye distances
    np.testing.assert_allclose(eyelids.lid_gaps(_mesh(scale=0.9, centre=(50.0, 70.0), roll=25.0)), gaps, rtol=1e-9)
    np.testing.assert_allclose(eyelids.lid_gaps(_blink(_mesh(), 0.25)), 0.75 * gaps, rtol=1e-9)
    assert np.isnan(eyelids.lid_gaps(np.full((468, 3), np.nan))).all()


class TestCloseLids:
    def test_a_target_as_open_as_the_shots_or_wider_is_left(self):
        shot = eyelids.lid_gaps(_mesh())
        for target in (_mesh(), _blink(_mesh(), -0.3)):
            np.testing.assert_array_equal(eyelids.close_lids(target, shot), target)
        blink = _blink(_mesh(), 0.5)
        np.testing.assert_array_equal(eyelids.close_lids(blink, shot, closed=0.0), blink)  # 0: as measured
        np.testing.assert_array_equal(eyelids.close_lids(blink, np.full(2, 0.05), closed=0.07), blink)  # shut shots
        np.testing.assert_array_equal(eyelids.close_lids(blink, np.full(2, np.nan)), blink)

    @pytest.mark.parametrize("fraction", [0.2, 0.4])
    def test_the_aperture_not_the_gap_is_scaled(self, fraction):
        """The lowered gap is (G_t - c) G_s / (G_s - c): the shot's aperture G_s - c, scaled by the warp's G' / G_s,
        becomes the target's, G_t - c."""
        shot, target = _mesh(), _blink(_mesh(), fraction)
        shot_gaps, target_gaps = eyelids.lid_gaps(shot), eyelids.lid_gaps(target)
        closed = 0.8 * eyelids.CLOSED_SHARE * float(shot_gaps.min())  # below CLOSED_SHARE of either eye: the fold
        lowered = eyelids.close_lids(target, shot_gaps, closed=closed)
        expected = (target_gaps - closed) * shot_gaps / (shot_gaps - closed)
        np.testing.assert_allclose(eyelids.lid_gaps(lowered), expected, rtol=1e-6)
        assert (expected < target_gaps).all()
        moved = np.abs(lowered - target).max(axis=1) > 0
        assert set(np.flatnonzero(moved)) <= set(UPPER)  # only the upper lids, and only in the image plane
        np.testing.assert_array_equal(lowered[:, 2], target[:, 2])

    def test_a_target_closed_to_the_fold_shuts_the_eye_on_a_turned_head(self):
        shot, target = _mesh(roll=30.0), _mesh(roll=-10.0)
        closed = float(eyelids.lid_gaps(shot).min()) * 0.8 * eyelids.CLOSED_SHARE  # below CLOSED_SHARE: the fold
        for eye, gap in enumerate(eyelids.lid_gaps(target)):  # each eye down to a gap of ``closed``
            target = _blink(target, 1 - closed / gap, eyes=(eye,))
        np.testing.assert_allclose(eyelids.lid_gaps(target), closed, rtol=1e-6)
        np.testing.assert_allclose(eyelids.lid_gaps(eyelids.close_lids(target, eyelids.lid_gaps(shot), closed)), 0.0,
                                   atol=1e-9)


def test_narrow_eyes_close_at_a_share_of_their_gap():
    """closed_gaps: LID_CLOSED, or CLOSED_SHARE of a narrow eye's open gap; so a narrow-eyed shot's lids are not
    slammed shut by a target a little more closed than it (with the fold at 0.07 a gap of 0.075 onto a shot's
    0.08 would warp to 0.04)."""
    np.testing.assert_allclose(eyelids.closed_gaps([0.15, 0.08]), [eyelids.LID_CLOSED, eyelids.CLOSED_SHARE * 0.08])
    shot, target = (eyelids.set_lid_gaps(_mesh(), np.full(2, gap)) for gap in (0.08, 0.075))
    shut = eyelids.CLOSED_SHARE * 0.08
    np.testing.assert_allclose(eyelids.lid_gaps(eyelids.close_lids(target, eyelids.lid_gaps(shot))),
                               (0.075 - shut) * 0.08 / (0.08 - shut), rtol=1e-6)


def test_references_close_the_eyes_further_only_where_the_target_closes_them(rng):
    """warp_references_mesh: lowering the lids changes the warped shot around the eyes only, and only when the
    target's eyes are more closed than the shot's."""
    image = rng.integers(0, 256, (SIZE // 4, SIZE // 4, 3), dtype=np.uint8).repeat(4, 0).repeat(4, 1)
    shots, meshes = image[None], _mesh()[None]
    landmarks = mesh_to_68(meshes).astype(np.float64)

    def warped(target: np.ndarray, closed: float) -> np.ndarray:
        images, _, _ = mesh_warp.warp_references_mesh(shots, meshes, landmarks, target, mesh_to_68(target), 1,
                                                      lid_closed=closed)
        return images[0].astype(np.int16)

    blink = _blink(_mesh(), 0.4)
    difference = np.abs(warped(blink, 0.07) - warped(blink, 0.0)).max(axis=-1)
    eyes = mesh_to_68(blink)[36:48]
    eye_box = np.zeros((SIZE, SIZE), bool)
    x0, y0 = np.floor(eyes.min(0) - 8).astype(int)
    x1, y1 = np.ceil(eyes.max(0) + 8).astype(int)
    eye_box[y0:y1, x0:x1] = True
    assert difference[eye_box].max() > 50  # the lid's texture came further down
    assert difference[~eye_box].max() <= 2  # sub-pixel resampling where the warp's grid is feathered
    np.testing.assert_array_equal(warped(_mesh(), 0.07), warped(_mesh(), 0.0))


def test_set_lid_gaps_moves_the_upper_lids_only():
    mesh = _mesh(roll=15.0)
    goal = eyelids.lid_gaps(mesh) * np.array([0.5, 1.2])
    moved = eyelids.set_lid_gaps(mesh, goal)
    np.testing.assert_allclose(eyelids.lid_gaps(moved), goal, rtol=1e-9)
    assert set(np.flatnonzero(np.abs(moved - mesh).max(axis=1) > 0)) <= set(UPPER)
    np.testing.assert_array_equal(eyelids.set_lid_gaps(mesh, [np.nan, -1.0]), mesh)  # no goal: the eyes stay


class TestLidsAsDriver:
    # the fold, below CLOSED_SHARE of every eye here (the narrowest: the source blinked 0.3 of the way)
    CLOSED = 0.8 * eyelids.CLOSED_SHARE * 0.7 * float(eyelids.lid_gaps(_mesh()).min())

    def _drive(self, driver_fraction: float, source_fraction: float = 0.0):
        """A driver whose reference has open eyes blinks ``driver_fraction`` of the way; the source's retargeted
        mesh (here: the source itself, shifted) gets its lids from it."""
        reference = _mesh(scale=0.5)
        driver = _blink(reference, driver_fraction)[None]
        source = _blink(_mesh(scale=0.7, roll=10.0), source_fraction)
        retargeted = source[None] + np.array([3.0, -2.0, 0.0])
        lidded = eyelids.lids_as_driver(retargeted, driver, eyelids.lid_gaps(reference), source,
                                        closed=self.CLOSED)
        return lidded, driver, reference, source

    def test_the_reference_frame_gives_the_source_its_own_eyes(self):
        lidded, _, _, source = self._drive(0.0, source_fraction=-0.4)  # a wide-eyed source
        np.testing.assert_allclose(eyelids.lid_gaps(lidded[0]), eyelids.lid_gaps(source), rtol=1e-9)

    @pytest.mark.parametrize("source_fraction", [-0.4, 0.3])
    def test_the_aperture_follows_the_driver_in_proportion(self, source_fraction):
        lidded, driver, reference, source = self._drive(0.5, source_fraction)
        closed = self.CLOSED
        share = (eyelids.lid_gaps(driver[0]) - closed) / (eyelids.lid_gaps(reference) - closed)
        expected = closed + (eyelids.lid_gaps(source) - closed) * eyelids.lid_share(share)
        np.testing.assert_allclose(eyelids.lid_gaps(lidded[0]), expected, rtol=1e-9)

    def test_a_driver_blink_shuts_any_source_and_a_wide_eye_is_capped(self):
        driver_closed = 1 - self.CLOSED / eyelids.lid_gaps(_mesh(scale=0.5))  # the driver's lids down to the fold
        for source_fraction in (-0.4, 0.3):
            lidded, *_ = self._drive(float(driver_closed.mean()), source_fraction)
            np.testing.assert_allclose(eyelids.lid_gaps(lidded[0]), self.CLOSED, rtol=0.02)
        lidded, _, _, source = self._drive(-2.0)  # a driver opening its eyes three times as wide
        expected = self.CLOSED + (eyelids.lid_gaps(source) - self.CLOSED) * eyelids.MAX_APERTURE
        np.testing.assert_allclose(eyelids.lid_gaps(lidded[0]), expected, rtol=1e-9)

    def test_missing_meshes_pass_through(self):
        lidded, driver, reference, source = self._drive(0.5)
        frames = np.stack([lidded[0], np.full((468, 3), np.nan)])
        out = eyelids.lids_as_driver(frames, np.concatenate([driver, driver]), eyelids.lid_gaps(reference), source)
        assert np.isnan(out[1]).all()
        nowhere = np.full(2, np.nan)  # no reference lids
        np.testing.assert_array_equal(eyelids.lids_as_driver(frames, np.concatenate([driver, driver]), nowhere,
                                                             source), frames)


def test_a_driver_whose_first_face_blinks_does_not_widen_every_later_eye():
    """LidReference: the driver's reference lids are the median of its faces so far and of those seen ahead, so a
    blink in the first face (which relative motion is measured from) counts for one frame of many: the source keeps
    its own eyes at the driver's open ones and shuts them at the driver's blinks. A fixed blinking reference widened
    them to the cap."""
    reference = _mesh(scale=0.5)
    closed = TestLidsAsDriver.CLOSED
    shut = 1 - closed / eyelids.lid_gaps(reference)  # the lids down to the fold
    fractions = [0.8, 0.0, 0.0, float(shut.mean()), 0.0, 0.0, 0.0]  # blinks at the first face and the fourth
    driver = np.stack([_blink(reference, fraction) for fraction in fractions])
    source = _mesh(scale=0.7, roll=10.0)
    open_gaps = eyelids.lid_gaps(reference)[None]
    ahead = eyelids.running_reference_gaps(driver)  # a file: its first LOOK_AHEAD faces seen before driving
    np.testing.assert_allclose(ahead, open_gaps.repeat(len(driver), 0), rtol=1e-9)
    lidded = eyelids.lids_as_driver(driver, driver, ahead, source, closed=closed)  # (retargeted: here the driver)
    gaps = np.array([eyelids.lid_gaps(face) for face in lidded])
    np.testing.assert_allclose(gaps[[1, 2, 4, 5, 6]], eyelids.lid_gaps(source)[None].repeat(5, 0), rtol=1e-9)
    assert (gaps[0] < 0.5 * eyelids.lid_gaps(source)).all()
    np.testing.assert_allclose(gaps[3], closed, rtol=0.02)
    fixed = eyelids.lids_as_driver(driver, driver, eyelids.lid_gaps(driver[0]), source, closed=closed)
    widest = closed + (eyelids.lid_gaps(source) - closed) * eyelids.MAX_APERTURE
    np.testing.assert_allclose(eyelids.lid_gaps(fixed[2]), widest, rtol=1e-9)
    # a camera sees nothing ahead: the first face is all it has, then the median catches up
    running = eyelids.running_reference_gaps(driver, look_ahead=0)
    np.testing.assert_allclose(running[0], eyelids.lid_gaps(driver[0]))
    np.testing.assert_allclose(running[[2, 4, 5, 6]], open_gaps.repeat(4, 0), rtol=1e-9)
    # a stream keeps the last REST_FRAMES faces, skips faces it could not read, counts the faces seen ahead
    # once, and starts anew on reset
    stream = eyelids.LidReference(frames=2)
    assert np.isnan(stream(np.full((468, 3), np.nan))).all()
    for face in driver[:3]:
        latest = stream(face)
    np.testing.assert_allclose(latest, open_gaps[0])
    stream.reset()
    stream.look_ahead([driver[3], None])
    np.testing.assert_allclose(stream(driver[3]), eyelids.lid_gaps(driver[3]))  # not counted twice
    np.testing.assert_allclose(stream(driver[4]), eyelids.lid_gaps(driver[3]))  # the None seen ahead
    np.testing.assert_allclose(stream(driver[5]), (eyelids.lid_gaps(driver[3]) + open_gaps[0]) / 2)


def test_small_lid_motions_move_further_and_blinks_stay_blinks():
    """lid_share: a small change of the driver's aperture moves the source's about SMALL_LID_GAIN times as far, a
    blink still shuts the eye, a large change is the driver's own, the map keeps the order of the driver's shares
    and its pull on the driver's reference is bounded (0.3 of the aperture at the defaults)."""
    gain, span = eyelids.SMALL_LID_GAIN, eyelids.SMALL_LID_SPAN
    for change in (-0.01, 0.01):
        assert eyelids.lid_share(1 + change) - 1 == pytest.approx(gain * change, rel=0.01)
    assert eyelids.lid_share(1.0) == 1.0 and eyelids.lid_share(0.0) == 0.0
    assert eyelids.lid_share(1 - 2.5 * span) == pytest.approx(1 - 2.5 * span, abs=0.005)  # a large closing: the driver's
    assert eyelids.lid_share(5.0) == eyelids.MAX_APERTURE
    shares = np.linspace(0.0, 2.0, 2001)
    mapped = eyelids.lid_share(shares)
    assert (np.diff(mapped) >= 0).all() and np.diff(mapped).max() > 0
    bound = (gain - 1) * span / np.sqrt(2) * np.exp(-0.5)
    assert np.abs(mapped - np.clip(shares, 0, eyelids.MAX_APERTURE)).max() <= bound + 1e-9
    np.testing.assert_allclose(eyelids.lid_share(shares, gain=1.0), np.clip(shares, 0, eyelids.MAX_APERTURE), atol=1e-12)


def test_the_68_points_have_lids_too():
    """lid_gaps, set_lid_gaps and lids_as_driver take 68 points as they take meshes (the same geometry: the gap
    across the corner line over the corners' eye distance)."""
    points = mesh_to_68(_mesh()[:, :2]).astype(np.float64)
    gaps = eyelids.lid_gaps(points)
    assert gaps.shape == (2,) and 0.05 < gaps.min() and gaps.max() < 0.25
    moved = eyelids.set_lid_gaps(points, 0.5 * gaps)
    np.testing.assert_allclose(eyelids.lid_gaps(moved), 0.5 * gaps, rtol=1e-9)
    assert set(np.flatnonzero(np.abs(moved - points).max(axis=1) > 0)) == {37, 38, 43, 44}
    reference, source = points, eyelids.set_lid_gaps(points * 1.3, 1.4 * gaps)
    shut = eyelids.set_lid_gaps(reference, eyelids.closed_gaps(eyelids.lid_gaps(reference)))[None]
    lidded = eyelids.lids_as_driver(source[None], shut, eyelids.lid_gaps(reference), source)[0]
    np.testing.assert_allclose(eyelids.lid_gaps(lidded), eyelids.closed_gaps(eyelids.lid_gaps(source)), rtol=1e-9)
    with pytest.raises(ValueError, match="468"):
        eyelids.lid_gaps(points[:60])


def test_retarget_driving_shuts_the_sources_eyes_at_the_drivers_blink():
    """The 68-point retargeting (no meshes: the hog and dlib detectors' path) closes the eyes in proportion too."""
    from landmarks.motion.retarget_points import retarget_driving

    reference = mesh_to_68(_mesh()[:, :2]).astype(np.float64)
    source = eyelids.set_lid_gaps(mesh_to_68(_mesh(scale=0.8, roll=10.0)[:, :2]).astype(np.float64),
                                  1.5 * eyelids.lid_gaps(reference))  # a wide-eyed source
    driver_shut, source_shut = (eyelids.closed_gaps(eyelids.lid_gaps(face)) for face in (reference, source))
    half = driver_shut + 0.5 * (eyelids.lid_gaps(reference) - driver_shut)
    driver = np.stack([reference, eyelids.set_lid_gaps(reference, half), eyelids.set_lid_gaps(reference, driver_shut)])
    moved = retarget_driving(driver, reference, source)
    source_aperture = eyelids.lid_gaps(source) - source_shut
    for frame, share in zip(moved, (1.0, 0.5, 0.0)):
        np.testing.assert_allclose(eyelids.lid_gaps(frame), source_shut + eyelids.lid_share(share) * source_aperture,
                                   rtol=1e-6)


def test_a_collapsed_eye_is_left_as_it_is():
    """A turned head's far eye can collapse to a point: its gap is NaN, nothing moves, and no warning is raised."""
    import warnings

    mesh = _mesh()
    outer, inner, upper, lower = eyelids.MESH_LIDS.eyes[1]
    mesh[[outer, inner, *upper, *lower]] = mesh[outer]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gaps = eyelids.lid_gaps(mesh)
        assert np.isnan(gaps[1]) and gaps[0] > 0
        np.testing.assert_array_equal(eyelids.set_lid_gaps(mesh, [0.05, 0.05])[list(upper)], mesh[list(upper)])
        np.testing.assert_array_equal(eyelids.close_lids(mesh, [0.2, 0.2])[list(upper)], mesh[list(upper)])
        lidded = eyelids.lids_as_driver(mesh[None], _blink(_mesh(), 0.5)[None], eyelids.lid_gaps(_mesh()), mesh)
        assert np.isfinite(lidded).all()
