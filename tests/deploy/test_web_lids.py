"""The web runtime's drawn lids (deploy/web/src/lids.ts) against landmarks.parts.eyes.drawn_lids: over the bundled source's
anchor shot at targets retargeted from the bundled driver. Its eyes stay open, so the subject's lids at rest are
given as wider than the target's, from not at all to wholly shut."""

from __future__ import annotations

import numpy as np
import pytest

from lsr.eval.metrics import psnr

CROP = 256
FRAMES = (2, 20, 40, 60)
WIDER = (1.0, 1.9, 2.5, 4.0)  # the lids at rest as this many times the target's own: strength 0, partial, ..., 1


def test_the_lids_are_read_and_drawn_as_python_draws_them(web, bundled_drive):
    from landmarks.parts.eyes.drawn_lids import draw_lids, lash_line, lid_strength, shot_lid_gaps
    from landmarks.parts.eyes.lids import lid_gaps

    image, frames = bundled_drive(FRAMES, CROP)
    targets = [target for _, _, target in frames]
    rests = [wider * lid_gaps(target) for target, wider in zip(targets, WIDER)]
    shots = np.stack([*targets, np.full((68, 2), np.nan)])
    polyline = np.array([[2.0, 5.0], [7.5, 3.2], [12.0, 6.0]])
    got = web.calls(*[("drawLids", [image, target, rest]) for target, rest in zip(targets, rests)],
                    *[("lidStrength", [target, rest]) for target, rest in zip(targets, rests)],
                    ("shotLidGaps", [shots]), ("lashLine", [polyline.ravel(), 1.7, 9, 15]))
    drawn, strengths = got[: len(FRAMES)], got[len(FRAMES): 2 * len(FRAMES)]
    gaps, line = got[-2:]
    changed = 0
    for target, rest, result, strength in zip(targets, rests, drawn, strengths):
        assert strength == pytest.approx(lid_strength(target, rest), abs=1e-12)
        expected = draw_lids(image, target, rest)
        changed += expected is not image
        assert psnr(result, expected) >= 50.0
        assert np.abs(result.astype(int) - expected.astype(int)).max() <= 2
    assert strengths[0] == 0.0 and strengths[-1] == pytest.approx(1.0) and 0 < strengths[1] < 1
    assert changed >= 2
    np.testing.assert_allclose(gaps, shot_lid_gaps(shots), atol=1e-12)
    np.testing.assert_allclose(np.reshape(line, (9, 15)), lash_line(polyline, 1.7, (9, 15)), atol=1e-6)
