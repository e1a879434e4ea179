"""landmarks.parts.coverage: features of a face, K shots chosen to cover a person's range, and the line that says what
a driver asks beyond the shots."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.parts.coverage import FEATURES, MARGINS, beyond_shots, choose_covering, describe, face_features
from landmarks.shape.expression import eye_opening, mouth_opening, set_mouth_opening
from landmarks.motion.head_pose import project_canonical

SIZE = (256, 256)


def face(yaw: float = 0.0, mouth: float = 0.0, eyes: float = 1.0) -> np.ndarray:
    """A canonical face's 68 points: turned by ``yaw`` degrees, the mouth opened to ``mouth`` inter-ocular
    distances, the lids' gaps times ``eyes``."""
    points = set_mouth_opening(project_canonical(yaw, 0.0, 0.0, SIZE).astype(np.float64), mouth)
    for upper, lower in ((37, 41), (38, 40), (43, 47), (44, 46)):
        middle = (points[upper] + points[lower]) / 2
        points[upper] = middle + (points[upper] - middle) * eyes
        points[lower] = middle + (points[lower] - middle) * eyes
    return points


def test_features_read_the_mouth_the_eyes_and_the_turn():
    faces = np.stack([face(), face(mouth=0.3), face(eyes=0.2), face(yaw=25.0)])
    features = face_features(faces, SIZE, gazes=np.array([0.0, 0.1, np.nan, -0.2]))
    assert features.shape == (4, len(FEATURES))
    np.testing.assert_allclose(features[:, 0], mouth_opening(faces))
    np.testing.assert_allclose(features[:, 1], eye_opening(faces))
    assert features[1, 0] == pytest.approx(0.3, abs=1e-3)
    assert abs(features[3, 2]) == pytest.approx(25.0, abs=2.0) and abs(features[0, 2]) < 1.0
    np.testing.assert_array_equal(features[:, 4], [0.0, 0.1, np.nan, -0.2])


def test_features_of_a_missing_face_are_nan_and_bad_shapes_raise():
    faces = np.stack([face(), np.full((68, 2), np.nan)])
    features = face_features(faces, SIZE)
    assert np.isfinite(features[0, :4]).all() and np.isnan(features[1]).all() and np.isnan(features[:, 4]).all()
    with pytest.raises(ValueError, match="68, 2"):
        face_features(np.zeros((2, 5, 2)), SIZE)
    with pytest.raises(ValueError, match="gazes"):
        face_features(faces, SIZE, gazes=np.zeros(3))


def person(count: int = 24) -> tuple[np.ndarray, dict[str, int]]:
    """A talking person: mostly near-neutral frames, and once each a wide mouth, a blink and two turns."""
    rng = np.random.default_rng(0)
    faces = [face(yaw=rng.normal(0, 1.5), mouth=abs(rng.normal(0.05, 0.02)), eyes=rng.uniform(0.9, 1.0))
             for _ in range(count)]
    moments = {"mouth": count // 5, "blink": 2 * count // 5, "left": 3 * count // 5, "right": 4 * count // 5}
    faces[moments["mouth"]] = face(mouth=0.35)
    faces[moments["blink"]] = face(eyes=0.1)
    faces[moments["left"]] = face(yaw=-30.0)
    faces[moments["right"]] = face(yaw=30.0)
    return face_features(np.stack(faces), SIZE), moments


def test_covering_shots_swap_the_persons_extremes_into_an_even_spread():
    features, moments = person()
    chosen = choose_covering(features, 8, first=1)
    even = np.round(np.linspace(0, len(features) - 1, 8)).astype(int).tolist()  # [0, 3, 7, 10, 13, 16, 20, 23]
    assert not set(even) & set(moments.values())
    assert set(moments.values()) <= set(chosen) and 1 in chosen and len(set(chosen)) == 8
    assert beyond_shots(features[even], features).any.sum() == 4  # spread in time: the 4 moments lie beyond
    assert not beyond_shots(features[chosen], features).any.any()  # covering: none does
    assert len(set(chosen) & set(even)) == 3  # the rest of the spread stays: the faces shown most, over time
    assert set(choose_covering(features, 8, first=1, extremes=1)) & set(moments.values()) == {moments["mouth"]}


def test_covering_starts_from_first_keeps_k_distinct_and_all_when_k_is_n():
    features, moments = person(10)
    for k in (1, 3, 10):
        chosen = choose_covering(features, k, first=5)
        assert 5 in chosen and len(set(chosen)) == k and chosen == sorted(chosen)
    features[moments["mouth"]] = np.nan  # a face without landmarks is never taken as an extreme
    assert moments["mouth"] not in choose_covering(features, 4, first=0)


@pytest.mark.parametrize("k, first, match", [(0, 0, "k must"), (11, 0, "k must"), (2, 10, "first")])
def test_covering_rejects_bad_arguments(k, first, match):
    features, _ = person(10)
    with pytest.raises(ValueError, match=match):
        choose_covering(features, k, first)


def test_beyond_flags_only_what_exceeds_the_shots_by_the_margin():
    shots = face_features(np.stack([face(mouth=0.0), face(mouth=0.2, yaw=10.0)]), SIZE, np.array([-0.1, 0.1]))
    targets = face_features(np.stack([
        face(mouth=0.2 + MARGINS["mouth"] / 2),  # inside the margin
        face(mouth=0.2 + 2 * MARGINS["mouth"]),  # wider
        face(eyes=0.2),  # more closed
        face(yaw=-15.0), face(yaw=25.0),  # turned further each way
        face(),  # the gaze further aside
    ]), SIZE, np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.3]))
    flags = beyond_shots(shots, targets)
    np.testing.assert_array_equal(flags.mouth, [0, 1, 0, 0, 0, 0])
    np.testing.assert_array_equal(flags.eyes, [0, 0, 1, 0, 0, 0])
    np.testing.assert_array_equal(flags.yaw_left, [0, 0, 0, 1, 0, 0])
    np.testing.assert_array_equal(flags.yaw_right, [0, 0, 0, 0, 1, 0])
    np.testing.assert_array_equal(flags.gaze, [0, 0, 0, 0, 0, 1])
    np.testing.assert_array_equal(flags.any, [0, 1, 1, 1, 1, 1])


def test_the_line_says_how_much_lies_beyond_and_which_shots_would_help():
    shots = face_features(np.stack([face(), face(mouth=0.1)]), SIZE)
    driver = face_features(np.stack([face(mouth=0.4)] * 3 + [face(eyes=0.1)] + [face()] * 4), SIZE)
    line = describe(shots, driver)
    assert line.startswith("the driver opens the mouth wider than any shot in 38% of frames")
    assert "closes the eyes further in 12% (no shot shows closed eyes)" in line
    assert line.endswith("shots with the mouth wide open and the eyes closed would help")
    assert "\n" not in line
    covered = describe(shots, face_features(np.stack([face(mouth=0.05)] * 3), SIZE))
    assert covered.startswith("the shots cover the driver")
    with_closed = face_features(np.stack([face(), face(eyes=0.3)]), SIZE)
    assert "no shot shows closed eyes" not in describe(with_closed, face_features(face(eyes=0.05)[None], SIZE))


def test_the_picture_marks_the_frames_beyond_in_red_and_says_their_share():
    from landmarks.parts.coverage import COLOURS, FEATURES, ROW_HEIGHT, coverage_picture

    shots = face_features(np.stack([face(), face(mouth=0.1)]), SIZE, np.array([0.0, 0.02]))
    covered = coverage_picture(shots, face_features(np.stack([face(mouth=0.05)] * 4), SIZE))
    assert covered.dtype == np.uint8 and covered.shape == (ROW_HEIGHT * (len(FEATURES) + 1), 720, 3)
    red = np.all(covered == COLOURS["beyond"], axis=-1)
    assert not red.any()
    wide = coverage_picture(shots, face_features(np.stack([face(mouth=0.05)] * 3 + [face(mouth=0.4)]), SIZE))
    mouth_row = wide[ROW_HEIGHT:2 * ROW_HEIGHT]
    assert np.all(mouth_row == COLOURS["beyond"], axis=-1).any()  # the wide mouth's tick (and its share) in red
    assert not np.all(wide[2 * ROW_HEIGHT:] == COLOURS["beyond"], axis=-1).any()  # nothing else is beyond
    no_gaze = face_features(np.stack([face(), face(mouth=0.1)]), SIZE)  # shots without a gaze: no gaze row
    assert coverage_picture(no_gaze, no_gaze).shape[0] == ROW_HEIGHT * len(FEATURES)


def test_the_moment_keeper_keeps_the_best_frame_of_each_moment():
    """On the bundled real source clip (a GRID speaker: she opens her mouth and blinks in these 3 s)."""
    from landmarks.parts.coverage import MOMENTS, MomentKeeper
    from landmarks.detect.registry import make_detector
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_SOURCE

    detector, keeper = make_detector(), MomentKeeper()
    frames = list(iter_frames(REAL_SOURCE))
    for frame in frames:
        faces = detector.detect(frame)
        if faces:
            keeper.add(frame, faces[0].landmarks)
    names = [name for name, _ in keeper.shots()]
    straight = MOMENTS[0][0]
    assert names[0] == straight and {"mouth wide open", "eyes closed"} <= set(names)
    assert mouth_opening(keeper.landmarks["mouth wide open"]) > mouth_opening(keeper.landmarks[straight]) + 0.05
    assert eye_opening(keeper.landmarks["eyes closed"]) < eye_opening(keeper.landmarks[straight])
    assert set(keeper.missing()) == {name for name, _ in MOMENTS} - set(names)
    still = MomentKeeper()  # a still face: straight ahead only
    points = detector.detect(frames[0])[0].landmarks
    for _ in range(5):
        still.add(frames[0], points)
    assert [name for name, _ in still.shots()] == [straight]
    assert still.add(frames[0], np.full((68, 2), np.nan)) == []
