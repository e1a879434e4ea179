"""lsr.core.inputs: K shots chosen to cover the person, and the line on what a driver asks beyond them."""

from __future__ import annotations


import numpy as np

from landmarks.parts.coverage import describe, face_features
from lsr.core.inputs import SubjectShots, choose_shots, cover_shots, coverage_features, scale_points



def candidates(drawn_face):
    """Ten drawn frames of one person: mostly alike, one wide-open mouth (2) and one glance aside (5)."""
    faces = [drawn_face((0.0,), mouth=0.03 * (i % 2)) for i in range(10)]
    faces[2] = drawn_face((0.0,), mouth=0.35)
    faces[5] = drawn_face((0.22,), mouth=0.0)
    return [f[0] for f in faces], [f[1].astype(np.float32) for f in faces]


def test_choose_shots_takes_the_wide_mouth_and_the_glance_that_an_even_spread_misses(drawn_face):
    frames, points = candidates(drawn_face)
    chosen = choose_shots(frames, points, 4)  # spread evenly: 0, 3, 6, 9
    assert 2 in chosen and 5 in chosen and len(chosen) == 4
    assert choose_shots(frames, points, 10) == list(range(10))


def test_cover_shots_keeps_the_chosen_frames_with_their_landmarks_and_anchor(drawn_face):
    frames, points = candidates(drawn_face)
    shots = SubjectShots(np.stack(frames), np.stack(points), [f"f{i}" for i in range(10)], anchor=0)
    covered = cover_shots(shots, 3)
    chosen = choose_shots(frames, points, 3)
    assert covered.names == [f"f{i}" for i in chosen]
    np.testing.assert_array_equal(covered.landmarks, np.stack(points)[chosen])
    assert covered.names[covered.anchor] == "f0" if 0 in chosen else covered.anchor == 0
    assert cover_shots(shots, 10) is shots


def test_coverage_line_compares_targets_at_any_crop_size(drawn_face):
    frames, points = candidates(drawn_face)
    shots = SubjectShots(np.stack(frames[:2]), np.stack(points[:2]))  # closed mouths only
    wide = drawn_face(mouth=0.4)[1]
    targets = np.stack([points[0], points[1], wide, np.full((68, 2), np.nan)])  # a frame without a face is left out
    line = describe(*coverage_features(shots, scale_points(targets, 0.5), 256))  # the targets at half the shots' 512 px
    assert line.startswith("the driver opens the mouth wider than any shot in 33% of frames")
    size = frames[0].shape[:2]
    halved = face_features(scale_points(targets[:3], 0.5), (256, 256))
    np.testing.assert_allclose(halved[:, :3], face_features(targets[:3], size)[:, :3], atol=0.1)  # IOD units, degrees
