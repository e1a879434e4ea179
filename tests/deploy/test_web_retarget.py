"""The web runtime's live path between the tracker and the network (deploy/web/src/smooth.ts and retarget.ts)
against lsr.core.live_session.LiveSession.prepare itself (its One-Euro smoothing at the frames' spacing, the driver
reference and its lid gaps, the crop, landmarks.motion.retarget_points.retarget_driving), on the bundled driver's tracked
landmarks driving K = 8 shots of the bundled source."""

from __future__ import annotations

import types

import numpy as np
import pytest

CROP = 256
FRAMES = 40
GAP = 17  # a frame without a face: the smoothing restarts, the reference stays
TOLERANCE = 1e-6  # crop pixels


@pytest.fixture(scope="module")
def driver() -> np.ndarray:
    """(T, 68, 2) float32: the bundled driver's first FRAMES faces as the live tracker reads them, frame GAP lost."""
    from landmarks.detect.registry import make_tracker
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_DRIVER

    tracker, points = make_tracker("mesh"), []
    for index, frame in enumerate(iter_frames(REAL_DRIVER)):
        if index >= FRAMES:
            break
        found = tracker.update(np.ascontiguousarray(frame))
        points.append(np.full((68, 2), np.nan, np.float32) if found is None else found)
    points = np.stack(points).astype(np.float32)
    points[GAP] = np.nan
    assert np.isfinite(points).all(axis=(1, 2)).sum() >= FRAMES - 2
    return points


@pytest.fixture(scope="module")
def shots():
    from lsr.core.inputs import load_subject_shots
    from lsr.examples import REAL_SOURCE

    return load_subject_shots(REAL_SOURCE, CROP, k=8)


def timestamps() -> np.ndarray:
    """Capture times of an uneven camera: 25 fps with jitter, one repeated time, one long stall (rate clipped)."""
    rng = np.random.default_rng(3)
    times = np.arange(FRAMES) / 25.0 + rng.uniform(-0.008, 0.008, FRAMES)
    times[9] = times[8]  # no spacing: the last rate stays
    times[25:] += 0.7  # a stall: 1 / 0.74 s, clipped to MIN_FPS
    return times


class _Replay:
    """A tracker that gives back recorded points (None where the face was lost)."""

    def __init__(self, points: np.ndarray) -> None:
        self.points = iter(points)

    def update(self, frame: np.ndarray):
        points = next(self.points)
        return points if np.isfinite(points).all() else None


class _Reenactor:
    """What LiveSession uses of a reenactor up to its network inputs."""

    crop_size, eyes, mouth_interior, lids, detector = CROP, "blend", "shots", "shots", "mesh"  # the retargeting alone

    def network_inputs(self, target, subject=None, gaze=None):
        return None, {}

    def part_tracks(self, subject, relative):
        return None  # no part banks: the retargeting alone


def live_targets(points: np.ndarray, shots, *, smooth: bool, recentre_at: tuple[int, ...] = ()) -> np.ndarray:
    """LiveSession.prepare over the recorded points -> (T, 68, 2) targets (NaN where it had no face)."""
    from lsr.core.live_session import LiveSession, Prepared

    subject = types.SimpleNamespace(shots=shots, reference_landmarks=shots.landmarks[shots.anchor])
    session = LiveSession(_Reenactor(), subject, paste_back=False, smooth=smooth, watermark=False)
    session.tracker = _Replay(points)
    frame, out = np.zeros((4, 4, 3), np.uint8), np.full(points.shape, np.nan)
    for index, now in enumerate(timestamps()[: len(points)]):
        if index in recentre_at:
            session.recentre()
        prepared = session.prepare(frame, float(now))
        if isinstance(prepared, Prepared):
            out[index] = prepared.target
    return out


def live_smoothing(points: np.ndarray) -> np.ndarray:
    """The smoothed points LiveSession.prepare crops (its own steps: rate from the spacing, reset on a gap)."""
    from lsr.core.live_session import MAX_FPS, MIN_FPS
    from landmarks.motion.smooth import OneEuroFilter, driving_cutoffs

    one_euro, last, out = OneEuroFilter(25.0, driving_cutoffs()), None, np.full(points.shape, np.nan)
    for index, now in enumerate(timestamps()[: len(points)]):
        if not np.isfinite(points[index]).all():
            last = None
            one_euro.reset()
            continue
        if last is not None and now > last:
            one_euro.fps = float(np.clip(1.0 / (now - last), MIN_FPS, MAX_FPS))
        out[index] = one_euro(points[index])
        last = now
    return out


def test_smoothing_matches_the_live_session_and_the_filter(web, driver):
    from landmarks.motion.smooth import OneEuroFilter, driving_cutoffs

    live, fixed = web.calls(("smoothSequence", [driver.astype(np.float64), timestamps()]),
                            ("smoothSequence", [driver.astype(np.float64), 30.0]))
    expected = live_smoothing(driver)
    found = np.isfinite(driver).all(axis=(1, 2))
    assert np.isnan(live[~found]).all() and np.isnan(fixed[~found]).all()
    assert np.abs(live[found] - expected[found]).max() <= TOLERANCE
    assert np.abs(live[found] - driver[found]).max() > 0.1  # it smooths
    one_euro = OneEuroFilter(30.0, driving_cutoffs())
    expected_fixed = np.stack([one_euro(frame) for frame in driver])
    assert np.abs(fixed[found] - expected_fixed[found]).max() <= TOLERANCE


def test_retargeting_matches_live_prepare_unsmoothed(web, driver, shots):
    reference = shots.landmarks[shots.anchor].astype(np.float64)
    expected = live_targets(driver, shots, smooth=False)
    got, recentred = web.calls(("retargetSequence", [driver.astype(np.float64), CROP, reference]),
                               ("retargetSequence", [driver.astype(np.float64), CROP, reference, None, [12, 30]]))
    found = np.isfinite(expected).all(axis=(1, 2))
    assert found.sum() == FRAMES - 1 and np.isnan(got[~found]).all()
    assert np.abs(got[found] - expected[found]).max() <= TOLERANCE
    # the driver's motion moved the subject's face: not a copy of the anchor, nor of the driver
    assert np.abs(got[found] - reference).max() > 1.0
    expected_recentred = live_targets(driver, shots, smooth=False, recentre_at=(12, 30))
    assert np.abs(recentred[found] - expected_recentred[found]).max() <= TOLERANCE
    assert np.abs(recentred[30:][found[30:]] - got[30:][found[30:]]).max() > 1e-3  # a new reference face


def test_smoothed_retargeting_matches_live_prepare(web, driver, shots):
    """The whole of prepare after the tracker: the TS smoothing's output cropped and retargeted by the TS path."""
    reference = shots.landmarks[shots.anchor].astype(np.float64)
    smoothed = web.call("smoothSequence", driver.astype(np.float64), timestamps())
    got = web.call("retargetSequence", driver.astype(np.float64), CROP, reference, smoothed)
    expected = live_targets(driver, shots, smooth=True)
    found = np.isfinite(expected).all(axis=(1, 2))
    assert np.abs(got[found] - expected[found]).max() <= TOLERANCE


def test_eyelids_and_mouth_follow_the_driver(web, driver, shots):
    """The pieces retarget_driving is made of, each against its Python function, on frames whose mouth and lids are
    moved further than the recording's (a blink, a wide mouth, a wide stare)."""
    from landmarks.shape.expression import mouth_opening, set_mouth_opening
    from landmarks.parts.eyes.lids import LidReference, lid_gaps, set_lid_gaps
    from landmarks.motion.retarget_points import retarget_driving

    reference = shots.landmarks[shots.anchor].astype(np.float64)
    frames = driver[np.isfinite(driver).all(axis=(1, 2))].astype(np.float64)
    edited = []
    for index, (opening, lids) in enumerate(((0.45, 0.2), (0.0, 1.6), (0.2, 0.05), (0.1, 1.0))):
        face = set_mouth_opening(frames[5 + 7 * index], opening)
        edited.append(set_lid_gaps(face, lid_gaps(face) * lids))
    edited = np.stack(edited)
    gaps = LidReference()
    for face in frames[:10]:
        median = gaps(face)
    calls = [("retargetDriving", [face, frames[0], reference, median]) for face in edited]
    calls += [("retargetDriving", [edited[0], frames[0], reference, None])]
    calls += [("setMouthOpening", [face, 0.3]) for face in edited]
    calls += [("lidGaps", [face]) for face in edited]
    results = web.calls(*calls)
    targets, plain, opened, measured = results[:4], results[4], results[5:9], results[9:]
    for face, target in zip(edited, targets):
        expected = retarget_driving(face, frames[0], reference, median)
        assert np.abs(target - expected).max() <= TOLERANCE
        assert abs(mouth_opening(target) - mouth_opening(face)) < 1e-3  # as open as the driver's
    assert np.abs(plain - retarget_driving(edited[0], frames[0], reference)).max() <= TOLERANCE
    for face, got in zip(edited, opened):
        assert np.abs(got - set_mouth_opening(face, 0.3)).max() <= TOLERANCE
    for face, got in zip(edited, measured):
        np.testing.assert_allclose(got, lid_gaps(face), atol=1e-12)
