"""Tracking through video, One-Euro smoothing and the jitter metric."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.motion.smooth import OneEuroFilter, jitter, smooth_sequence
from landmarks.detect.dlib_tracker import LandmarkTracker, box_iou
from landmarks.io.video import iter_frames
from lsr.bench.bench_landmarks import static_jitter


class TestOneEuro:
    def test_constant_input_is_unchanged(self):
        points = np.random.default_rng(1).uniform(0, 100, (68, 2))
        sequence = np.repeat(points[None], 10, axis=0)
        assert np.allclose(smooth_sequence(sequence, 25.0), sequence, atol=1e-4)

    def test_noise_is_reduced_and_output_shape_kept(self, rng):
        base = rng.uniform(100, 200, (68, 2))
        noisy = base + rng.normal(0, 1.0, (60, 68, 2))
        smoothed = smooth_sequence(noisy, 25.0, min_cutoff=1.0, beta=0.0)
        assert smoothed.shape == noisy.shape and smoothed.dtype == np.float32
        assert np.abs(np.diff(smoothed, axis=0)).mean() < 0.5 * np.abs(np.diff(noisy, axis=0)).mean()

    def test_fast_motion_follows_with_beta(self):
        # A point moving at 500 px/s: high beta keeps the lag small, beta 0 lags far behind.
        track = np.zeros((40, 68, 2))
        track[:, :, 0] = np.arange(40)[:, None] * 20.0
        lag_fast = np.abs(smooth_sequence(track, 25.0, beta=1.0)[-1] - track[-1]).max()
        lag_slow = np.abs(smooth_sequence(track, 25.0, beta=0.0)[-1] - track[-1]).max()
        assert lag_fast < 0.2 * lag_slow

    def test_resets_across_missing_frames(self):
        track = np.zeros((6, 68, 2), np.float32)
        track[3] = np.nan
        track[4:] = 100.0  # the face reappears elsewhere: no smoothing across the gap
        smoothed = smooth_sequence(track, 25.0)
        assert np.isnan(smoothed[3]).all()
        assert np.allclose(smoothed[4:], 100.0)

    def test_bad_arguments_raise(self):
        with pytest.raises(ValueError):
            OneEuroFilter(fps=0)
        with pytest.raises(ValueError, match="N, 68, 2"):
            smooth_sequence(np.zeros((3, 5, 2)), 25.0)


class TestJitter:
    def test_scale_free_and_ignores_missing(self, rng):
        points = rng.uniform(0, 100, (5, 68, 2))
        assert jitter(points * 3.0) == pytest.approx(jitter(points))
        with_gap = np.concatenate([points, np.full((1, 68, 2), np.nan), points])
        pairs = [jitter(points)] * 2
        assert jitter(with_gap) == pytest.approx(np.mean(pairs))
        assert np.isnan(jitter(points[:1]))

    def test_static_is_zero(self):
        assert jitter(np.ones((4, 68, 2)) * np.arange(68)[None, :, None]) == 0.0


def test_tracker_follows_a_moving_face_with_one_detection(detector, astronaut):
    frames = [np.roll(astronaut, (2 * index, 3 * index), axis=(0, 1)) for index in range(12)]
    result = LandmarkTracker(detector).track_frames(frames)
    assert result.landmarks.shape == (12, 68, 2) and not result.missing.any()
    assert result.detections == 1
    reference = detector.detect_one(astronaut).landmarks
    for index, points in enumerate(result.landmarks):
        assert np.abs(points - (reference + [3 * index, 2 * index])).mean() < 3.0


def test_tracker_marks_lost_frames_and_recovers(detector, astronaut, rng):
    noise = [rng.integers(0, 256, astronaut.shape, dtype=np.uint8) for _ in range(3)]
    frames = [astronaut] * 3 + noise + [np.full_like(astronaut, 128)] + [astronaut] * 3
    result = LandmarkTracker(detector).track_frames(frames)
    assert result.missing.tolist() == [False] * 3 + [True] * 4 + [False] * 3
    assert np.isnan(result.landmarks[3:7]).all() and np.isfinite(result.landmarks[7:]).all()
    assert result.detections == 6  # the first frame, the four lost frames, the first frame back
    assert box_iou(np.array([0, 0, 10, 10]), np.array([5, 0, 15, 10])) == pytest.approx(1 / 3)


def test_smoothing_lowers_static_jitter(astronaut):
    raw, smoothed, missing = static_jitter(astronaut, repeats=30, noise_sigma=4.0)
    assert missing == 0
    assert 0 < smoothed < 0.6 * raw


@pytest.mark.slow
def test_real_clip_tracks_95_percent(shared_data, detector):
    clip = shared_data / "clips" / "tpsmm_driving.mp4"
    result = LandmarkTracker(detector).track_frames(iter_frames(clip))
    assert len(result.missing) == 169
    assert result.missing.mean() <= 0.05
    assert result.detections < 20  # tracked, not re-detected every frame
    # Tracked landmarks stay on the face: compare with full detections on a few frames.
    frames = [frame for index, frame in enumerate(iter_frames(clip)) if index in (0, 60, 120)]
    for frame, index in zip(frames, (0, 60, 120)):
        if result.missing[index]:
            continue
        detected = detector.detect_one(frame).landmarks
        inter_ocular = np.linalg.norm(detected[42:48].mean(0) - detected[36:42].mean(0))
        assert np.abs(result.landmarks[index] - detected).mean() < 0.15 * inter_ocular
    smoothed = smooth_sequence(result.landmarks, 25.0)
    assert jitter(smoothed) < jitter(result.landmarks)
