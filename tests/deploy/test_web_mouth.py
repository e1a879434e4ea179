"""The web runtime's nearest mouth (deploy/web/src/mouth.ts) against lsr.core.finish.finish_mouth in mode "nearest"
(landmarks.parts.mouth.nearest_mouth): K = 8 shots of the bundled source, TPS-warped onto targets retargeted from the bundled
driver (some with the mouth opened wider than any shot's), a blend of the warped shots standing in for the network's
synthesis."""

from __future__ import annotations

import numpy as np
import pytest

from lsr.eval.metrics import psnr

CROP = 256
COUNT = 8  # warped references, as the warp-guided model takes them
OPENINGS = (None, None, 0.2, 0.3, 0.45, None, 0.6)  # None: the driver's own mouth


@pytest.fixture(scope="module")
def shots():
    from lsr.core.inputs import load_subject_shots
    from lsr.examples import REAL_SOURCE

    return load_subject_shots(REAL_SOURCE, CROP, k=8)


@pytest.fixture(scope="module")
def targets(shots) -> np.ndarray:
    """(len(OPENINGS), 68, 2) crop-pixel targets: the bundled driver's faces retargeted onto the anchor as the live
    session does it (unsmoothed), some with the mouth set wider (landmarks.shape.expression.set_mouth_opening)."""
    from landmarks.align import crop_transform, transform_landmarks
    from landmarks.detect.registry import make_tracker
    from landmarks.shape.expression import set_mouth_opening
    from landmarks.motion.retarget_mesh import DriverReference
    from landmarks.motion.retarget_points import retarget_driving
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_DRIVER

    tracker, reference, out = make_tracker("mesh"), DriverReference(), []
    for index, frame in enumerate(iter_frames(REAL_DRIVER)):
        if len(out) == len(OPENINGS):
            break
        points = tracker.update(np.ascontiguousarray(frame))
        if points is None or index % 5:
            continue
        gaps, _ = reference.lids(points)
        crop = transform_landmarks(points, crop_transform(points, CROP))
        reference.start(crop)
        target = retarget_driving(crop, reference.landmarks, shots.landmarks[shots.anchor], gaps)
        opening = OPENINGS[len(out)]
        out.append(target if opening is None else set_mouth_opening(target, opening))
    return np.stack(out)


def warped_inputs(shots, target: np.ndarray):
    """The TPS warp's references for one target, and a synthesis like the network's: their masked mean."""
    from landmarks.warp.tps import warp_references

    warped, masks, indices = warp_references(shots.frames, shots.landmarks, target, COUNT)
    weights = masks[..., None]
    blend = (warped * weights).sum(0) / np.maximum(weights.sum(0), 1e-6)
    return warped, masks, indices.astype(np.int32), np.clip(np.rint(blend), 0, 255).astype(np.uint8)


def test_mouth_weight_and_strength_match_python(web, shots, targets):
    from landmarks.parts.mouth.nearest_mouth import mouth_strength, mouth_weight
    from landmarks.shape.measures import nearest_shots

    faces = np.concatenate([targets, targets * 2.0])  # also at a 512 crop
    sides = [CROP] * len(targets) + [2 * CROP] * len(targets)
    calls = [("mouthWeight", [face, side, side]) for face, side in zip(faces, sides)]
    shot_landmarks = shots.landmarks.astype(np.float64)
    calls += [("mouthStrength", [face, shot_landmarks, COUNT]) for face in targets]
    calls += [("mouthStrength", [face, shot_landmarks, np.resize(nearest_shots(shots.landmarks, face, COUNT), COUNT)
                                 .astype(np.int32)]) for face in targets]
    results = web.calls(*calls)
    regions, strengths = results[: len(faces)], results[len(faces):]
    for face, side, region in zip(faces, sides, regions):
        weight, box = mouth_weight(face, (side, side))
        assert tuple(region["box"]) == box
        assert np.abs(region["weight"] - weight).max() < 1e-5  # OpenCV's mask, element and blur, to float rounding
    expected = [mouth_strength(face, shots.landmarks, COUNT) for face in targets]
    np.testing.assert_allclose(strengths[: len(targets)], expected, atol=1e-9)
    np.testing.assert_allclose(strengths[len(targets):], expected, atol=1e-9)
    assert min(expected) == 0 and max(expected) == 1  # the shots show some mouths, not the widest


def test_finish_mouth_nearest_matches_python(web, shots, targets):
    from landmarks.parts.mouth.nearest_mouth import mouth_strength
    from lsr.core.images import from_network, to_network
    from lsr.core.finish import finish_mouth

    acted = 0
    for target in targets:
        warped, masks, indices, synthesis = warped_inputs(shots, target)
        assert (from_network(to_network(warped[0])) == warped[0]).all()  # the network's references hold the same pixels
        inputs = {"references": to_network(warped)[None], "reference_masks": masks[None, :, None]}
        expected = finish_mouth(synthesis, "nearest", inputs, target, shots.landmarks, COUNT, None)
        got = web.call("finishMouthNearest", synthesis, warped, masks, indices, target,
                       shots.landmarks.astype(np.float64))
        assert got.dtype == np.uint8 and got.shape == synthesis.shape
        if mouth_strength(target, shots.landmarks, COUNT) > 0:
            acts = psnr(expected, synthesis) < 60
            acted += acts
            assert psnr(got, expected) >= 40.0
            assert np.abs(got.astype(int) - expected).max() <= 2  # rounding of the feathered edge at most
        else:
            assert (got == synthesis).all() and (expected == synthesis).all()
    assert acted >= 2  # the nearest shot's mouth replaced the blend's on the wide-open targets
