"""The web runtime's mouth interior (deploy/web/src/interior.ts) against landmarks.parts.mouth.interior: the bundled
driver's frames and tracked points cut into its mouth, laid into the bundled source's anchor shot at targets
retargeted from the driver (as the live session does, unsmoothed)."""

from __future__ import annotations

import numpy as np
import pytest

from lsr.eval.metrics import psnr

CROP = 256
FRAMES = (2, 16, 30, 37, 51, 60)  # the driver's mouth: parted, open, open, widest, open, shut


@pytest.fixture(scope="module")
def driven(bundled_drive):
    """(the source's anchor crop, [(driver frame, its points, the target in crop pixels)] at FRAMES)."""
    return bundled_drive(FRAMES, CROP)


def test_the_driver_mouth_is_cut_as_python_cuts_it(web, driven):
    from landmarks.parts.mouth.interior import cut_driver_mouth

    _, frames = driven
    got = web.calls(*[("cutDriverMouth", [frame, points]) for frame, points, _ in frames])
    for (frame, points, _), mouth in zip(frames, got):
        expected = cut_driver_mouth(frame, points)
        if expected is None:
            assert mouth is None
            continue
        assert np.array_equal(mouth["patch"], expected.patch)
        np.testing.assert_allclose(mouth["lips"], expected.lips, atol=1e-9)
        assert mouth["opening"] == pytest.approx(expected.opening, abs=1e-12)
        assert mouth["yaw"] == pytest.approx(expected.yaw, abs=0.5)  # the head pose, degrees
        np.testing.assert_allclose(mouth["light"], expected.light, atol=1e-9)
    assert sum(m is not None for m in got) >= 4  # most of FRAMES show an open mouth


def test_the_interior_is_laid_in_as_python_lays_it(web, driven):
    from landmarks.parts.mouth.interior import cut_driver_mouth, lip_affine, paste_interior

    image, frames = driven
    mouths = [cut_driver_mouth(frame, points) for frame, points, _ in frames]
    wire = [None if m is None else {"patch": m.patch, "lips": m.lips, "opening": m.opening, "yaw": m.yaw,
                                    "light": m.light.tolist()} for m in mouths]
    targets = [target for *_, target in frames]
    got = web.calls(*[("pasteInterior", [image, target, mouth]) for target, mouth in zip(targets, wire)],
                    *[("lipAffine", [t[48:68].ravel(), m.lips.ravel()]) for t, m in zip(targets, mouths) if m])
    pasted, affines = got[: len(frames)], got[len(frames):]
    changed = 0
    for target, mouth, result in zip(targets, mouths, pasted):
        expected = paste_interior(image, target, mouth)
        changed += expected is not image
        assert psnr(result, expected) >= 50.0
        assert np.abs(result.astype(int) - expected.astype(int)).max() <= 2
    assert changed >= 3  # the open mouths were laid in
    for target, mouth, affine in zip([t for t, m in zip(targets, mouths) if m], [m for m in mouths if m], affines):
        np.testing.assert_allclose(np.reshape(affine, (2, 3)), lip_affine(target[48:68], mouth.lips), atol=1e-8)


def test_a_greyscale_target_takes_a_grey_interior_as_python_gives_it(web, driven):
    """The bundled driver's colourful mouth laid into a greyscale anchor: no colour inside the lips, on the page as
    in Python (match_light's colourful=False)."""
    from landmarks.parts.mouth.interior import cut_driver_mouth, paste_interior

    image, frames = driven
    grey = np.repeat(image.mean(axis=-1, keepdims=True).round().astype(np.uint8), 3, axis=-1)
    frame, points, target = frames[3]  # the driver's widest mouth
    mouth = cut_driver_mouth(frame, points)
    wire = {"patch": mouth.patch, "lips": mouth.lips, "opening": mouth.opening, "yaw": mouth.yaw,
            "light": mouth.light.tolist()}
    (result,) = web.calls(("pasteInterior", [grey, target, wire]))
    expected = paste_interior(grey, target, mouth)
    assert expected is not grey
    assert psnr(result, expected) >= 50.0 and np.abs(result.astype(int) - expected.astype(int)).max() <= 2
    colour = np.abs(expected.astype(int) - expected.mean(axis=-1, keepdims=True)).max(axis=-1)
    assert colour.max() <= 3  # grey within rounding, where the driver's lips and tongue were red
