"""The irises: found by the iris net, carried as a gaze, drawn once (landmarks.parts.eyes.iris)."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.parts.eyes.iris import PATCH, IrisDonor, draw_irises, find_irises, gaze_offsets, retarget_gaze
from landmarks.shape.measures import EYE_RINGS, eye_apertures

SIDE = 128
WHITE, SKIN, IRIS = 235, 150, 30


def _eyes(gap: float = 14.0) -> np.ndarray:
    """68 points with two eyes (corners 30 px apart, lids ``gap`` px apart), the rest far below them."""
    points = np.tile(np.array([[64.0, 110.0]]), (68, 1))
    for ring, left in zip(EYE_RINGS, (20.0, 78.0)):
        y = 50.0
        points[list(ring)] = [[left, y], [left + 10, y - gap / 2], [left + 20, y - gap / 2], [left + 30, y],
                              [left + 20, y + gap / 2], [left + 10, y + gap / 2]]
    return points


def _doubled(points: np.ndarray) -> np.ndarray:
    """Skin, white eyes, and in each two dark irises (a blend of shots that looked two ways)."""
    import cv2

    image = np.full((SIDE, SIDE, 3), SKIN, np.uint8)
    for ring in EYE_RINGS:
        lids = points[list(ring)]
        cv2.fillPoly(image, [np.round(lids).astype(np.int32)], (WHITE,) * 3)
        for x in (lids[0, 0] + 9, lids[0, 0] + 21):
            cv2.circle(image, (int(x), 50), 4, (IRIS,) * 3, -1)
    return image


def _donor() -> IrisDonor:
    """A dark iris centred in each patch, on white, as wide as 0.2 eye widths."""
    import cv2

    patch = np.full((PATCH, PATCH, 3), WHITE, np.uint8)
    cv2.circle(patch, (PATCH // 2, PATCH // 2), int(PATCH / 2.6), (IRIS,) * 3, -1)
    return IrisDonor(np.stack([patch, patch]), np.array([0.2, 0.2]), np.array([float(WHITE)] * 2), shot=0)


def _dark_blobs(image: np.ndarray, points: np.ndarray, eye: int) -> tuple[int, np.ndarray]:
    """(dark blobs inside the eye's box, the centroid of its dark pixels (x, y))."""
    import cv2

    lids = points[list(EYE_RINGS[eye])]
    x0, y0 = np.floor(lids.min(axis=0)).astype(int)
    x1, y1 = np.ceil(lids.max(axis=0)).astype(int)
    dark = (image[y0:y1, x0:x1].mean(axis=2) < 100).astype(np.uint8)
    count, _ = cv2.connectedComponents(dark)
    ys, xs = np.nonzero(dark)
    return count - 1, np.array([xs.mean() + x0, ys.mean() + y0])


@pytest.mark.parametrize("look", [-0.15, 0.0, 0.15])
def test_one_iris_is_drawn_where_the_gaze_says(look):
    points = _eyes()
    image = _doubled(points)
    assert _dark_blobs(image, points, 0)[0] == 2
    drawn = draw_irises(image, points, np.array([[look, 0.0], [look, 0.0]]), _donor())
    for eye in range(2):
        blobs, centroid = _dark_blobs(drawn, points, eye)
        corners = points[[36, 39]] if eye == 0 else points[[42, 45]]
        expected = corners.mean(axis=0) + [look * 30.0, 0.0]
        assert blobs == 1 and np.abs(centroid - expected).max() < 1.5
    outside = np.ones((SIDE, SIDE), bool)
    outside[30:70, 10:120] = False
    assert (drawn[outside] == image[outside]).all()  # only the eyes change


def test_a_closed_eye_or_one_without_a_gaze_is_left_as_it_is():
    closed = _eyes(gap=2.0)
    assert (eye_apertures(closed) < 0.12).all()
    image = _doubled(_eyes())
    assert (draw_irises(image, closed, np.zeros((2, 2)), _donor()) == image).all()
    points = _eyes()
    one = draw_irises(image, points, np.array([[np.nan, np.nan], [0.0, 0.0]]), _donor())
    assert _dark_blobs(one, points, 0)[0] == 2 and _dark_blobs(one, points, 1)[0] == 1
    assert (draw_irises(image, points, np.full((2, 2), np.nan), _donor()) == image).all()


def test_gaze_offsets_measure_in_eye_widths_along_and_across_the_eye():
    points = _eyes()
    irises = np.array([[35.0 + 3.0, 50.0 + 1.5, 3.0, 0.3], [93.0 - 6.0, 50.0, 3.0, 0.2]])
    np.testing.assert_allclose(gaze_offsets(irises, points), [[0.1, 0.05], [-0.2, 0.0]])
    assert np.isnan(gaze_offsets(np.full((2, 4), np.nan), points)).all()
    closing = gaze_offsets(irises, points, open_apertures=np.array([0.3, 0.3]))  # the second eye at 2/3 of open
    np.testing.assert_allclose(closing[0], [0.1, 0.05])
    assert np.isnan(closing[1]).all()


def test_relative_gaze_moves_the_source_by_the_drivers_change():
    source = np.array([[0.05, 0.0], [0.05, 0.0]])
    reference = np.array([[-0.1, 0.02], [-0.1, 0.02]])
    driver = np.array([[[0.0, 0.02], [0.0, 0.02]]])
    np.testing.assert_allclose(retarget_gaze(driver, reference, source), [[[0.15, 0.0], [0.15, 0.0]]])
    np.testing.assert_allclose(retarget_gaze(driver, np.full((2, 2), np.nan), source), driver)  # absolute


def test_the_iris_net_finds_the_bundled_speakers_irises_inside_her_eyes():
    from landmarks.detect.registry import make_detector
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_SOURCE

    frame = next(iter(iter_frames(REAL_SOURCE)))
    points = make_detector().detect(frame)[0].landmarks
    irises = find_irises(frame, points)
    assert np.isfinite(irises).all() and (0.15 < irises[:, 3]).all() and (irises[:, 3] < 0.6).all()
    for eye, ring in enumerate(EYE_RINGS):
        lids = points[list(ring)]
        assert (lids.min(axis=0) <= irises[eye, :2]).all() and (irises[eye, :2] <= lids.max(axis=0)).all()
        width = np.linalg.norm(lids[3] - lids[0])
        assert 0.12 * width < irises[eye, 2] < 0.35 * width
    assert (np.abs(gaze_offsets(irises, points)) < 0.25).all()  # she looks at the camera
    assert np.isnan(find_irises(frame, np.full((68, 2), np.nan))).all()


def test_the_mesh_tracker_keeps_the_irises_it_found_refining_the_eyes():
    """The tracker's iris net pass gives the irises that find_irises would (free for drawn eyes)."""
    from landmarks.detect.registry import make_tracker
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_SOURCE

    tracker = make_tracker("mesh")
    for frame in list(iter_frames(REAL_SOURCE))[:3]:
        points = tracker.update(frame)
    own = find_irises(frame, points)
    assert tracker.irises.shape == (2, 4) and np.isfinite(tracker.irises).all()
    assert np.abs(tracker.irises[:, :2] - own[:, :2]).max() < 1.0  # pixels
    assert np.abs(tracker.irises[:, 3] / own[:, 3] - 1).max() < 0.2  # apertures: over the mesh's corner distance there
    tracker.update(np.zeros_like(frame))
    assert tracker.irises is None


def test_the_donor_is_the_most_open_shot_whose_irises_look_like_irises():
    from landmarks.detect.registry import make_detector
    from landmarks.parts.eyes.iris import iris_donor
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_SOURCE

    frames = list(iter_frames(REAL_SOURCE))[:40:8]
    detector = make_detector()
    points = np.stack([detector.detect(frame)[0].landmarks for frame in frames])
    donor = iris_donor(np.stack(frames), points)
    assert donor is not None and donor.patches.shape == (2, PATCH, PATCH, 3)
    assert (0.1 < donor.radii).all() and (donor.radii < 0.35).all() and (donor.whites > 100).all()
    grey = donor.patches.mean(axis=-1)
    assert (grey[:, PATCH // 2, PATCH // 2] < 0.7 * donor.whites).all()  # a dark iris at the centre
    blurred = np.stack([np.full_like(frame, 150) for frame in frames])  # flat skin: the net's irises are no irises
    assert iris_donor(blurred, points) is None
