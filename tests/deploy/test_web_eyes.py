"""The web runtime's shut eyes (deploy/web/src/eyes.ts) against landmarks.parts.eyes.driver_lids: the bundled driver's frames
and tracked points cut around its eyes, laid over the bundled source's anchor shot at targets retargeted from the
driver (as the live session does, unsmoothed). The bundled driver never shuts its eyes, so its lids at rest are
given as wider than they are, from not at all to wholly shut."""

from __future__ import annotations

import numpy as np
import pytest

from lsr.eval.metrics import psnr

CROP = 256
FRAMES = (2, 20, 40, 60)
WIDER = (1.0, 1.9, 2.5, 4.0)  # the lids at rest as this many times the frame's own: strength 0, partial, ..., 1


@pytest.fixture(scope="module")
def driven(bundled_drive):
    """(the source's anchor crop, [(driver frame, its points, the target in crop pixels, lids at rest)] at FRAMES)."""
    from landmarks.parts.eyes.lids import lid_gaps

    image, frames = bundled_drive(FRAMES, CROP)
    return image, [(frame, points, target, wider * lid_gaps(points))
                   for (frame, points, target), wider in zip(frames, WIDER)]


def test_the_driver_eyes_are_cut_and_read_as_python_does(web, driven):
    from landmarks.parts.eyes.driver_lids import aperture_share, cut_driver_eyes

    _, frames = driven
    got = web.calls(*[("cutDriverEyes", [frame, points, wider]) for frame, points, _, wider in frames],
                    *[("apertureShare", [points, wider]) for _, points, _, wider in frames])
    cut, shares = got[: len(frames)], got[len(frames):]
    strengths = []
    for (frame, points, _, wider), eyes, share in zip(frames, cut, shares):
        assert share == pytest.approx(aperture_share(points, wider), abs=1e-12)
        expected = cut_driver_eyes(frame, points, wider)
        if expected is None:
            assert eyes is None
            strengths.append(0.0)
            continue
        assert np.array_equal(eyes["patch"], expected.patch)
        np.testing.assert_allclose(eyes["corners"], expected.corners, atol=1e-9)
        assert eyes["strength"] == pytest.approx(expected.strength, abs=0.01)  # through the head pose's yaw
        strengths.append(expected.strength)
    assert strengths[0] == 0.0 and strengths[-1] == pytest.approx(1.0) and 0 < strengths[1] < 1


def test_the_shut_eyes_are_laid_in_as_python_lays_them(web, driven):
    from landmarks.parts.eyes.driver_lids import cut_driver_eyes, paste_eyes, similarity

    image, frames = driven
    cut = [cut_driver_eyes(frame, points, wider) for frame, points, _, wider in frames]
    wire = [None if e is None else {"patch": e.patch, "corners": e.corners, "strength": e.strength, "yaw": 0.0}
            for e in cut]
    targets = [target for _, _, target, _ in frames]
    source, onto = np.array([10.0, 20.0, 30.0, 25.0]), np.array([100.0, 50.0, 90.0, 80.0])
    got = web.calls(*[("pasteEyes", [image, target, eyes]) for target, eyes in zip(targets, wire)],
                    ("similarity", [source, onto]))
    pasted, matrix = got[: len(frames)], got[len(frames)]
    changed = 0
    for target, eyes, result in zip(targets, cut, pasted):
        expected = paste_eyes(image, target, eyes)
        changed += expected is not image
        assert psnr(result, expected) >= 50.0
        assert np.abs(result.astype(int) - expected.astype(int)).max() <= 2
    assert changed >= 2
    np.testing.assert_allclose(np.reshape(matrix, (2, 3)), similarity(source.reshape(2, 2), onto.reshape(2, 2)),
                               atol=1e-12)
