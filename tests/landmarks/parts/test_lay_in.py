"""Laying a real patch into the synthesis (landmarks.parts.lay_in): another person's patch no more colourful than the
target (colour_ratio and desaturated, match_light's colourful=False)."""

from __future__ import annotations

import cv2
import numpy as np

from landmarks.parts.lay_in import colour_ratio, desaturated, match_light

SIZE = 40


def scene(colour: tuple[float, float, float], seed: int = 0) -> np.ndarray:
    """(SIZE, SIZE, 3) float32 skin of one colour with a little noise."""
    noise = np.random.default_rng(seed).normal(0.0, 2.0, (SIZE, SIZE, 1))
    return (np.array(colour, np.float32) + noise).astype(np.float32)


def lips() -> np.ndarray:
    mask = np.zeros((SIZE, SIZE), bool)
    mask[15:25, 10:30] = True
    return mask


def match_colourfulness(patch: np.ndarray, region: np.ndarray, lips: np.ndarray, ring: int) -> np.ndarray:
    """The patch made no more colourful than the target over the skin ring ``ring`` pixels wide around ``lips``, as
    match_light makes it."""
    grown = cv2.dilate(lips.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring + 1,) * 2)) > 0
    return desaturated(patch, colour_ratio(patch, region, grown & ~lips))


def colourfulness(values: np.ndarray) -> float:
    return float(np.linalg.norm(values - values.mean(axis=-1, keepdims=True), axis=-1).mean())


def test_a_greyscale_target_turns_a_colourful_patch_grey_and_keeps_its_brightness():
    patch = scene((200.0, 120.0, 100.0))
    patch[18:22, 12:28] = (220.0, 30.0, 60.0)  # red lips
    result = match_colourfulness(patch, scene((130.0, 130.0, 130.0)), lips(), ring=4)
    assert result.dtype == np.float32 and result.shape == patch.shape
    assert colourfulness(result) < 0.05 * colourfulness(patch)
    np.testing.assert_allclose(result.mean(axis=-1), patch.mean(axis=-1), atol=1e-3)  # only the colour goes


def test_a_target_as_colourful_as_the_patch_or_more_keeps_it_as_it_is():
    patch = scene((180.0, 130.0, 110.0))
    assert match_colourfulness(patch, scene((220.0, 110.0, 80.0), seed=1), lips(), ring=4) is patch
    same = match_colourfulness(patch, scene((180.0, 130.0, 110.0), seed=1), lips(), ring=4)
    np.testing.assert_allclose(same, patch, atol=1e-3)


def test_a_target_half_as_colourful_halves_the_patchs_colour():
    patch = scene((190.0, 130.0, 100.0))
    result = match_colourfulness(patch, scene((160.0, 130.0, 115.0)), lips(), ring=4)
    ratio = colourfulness(result) / colourfulness(patch)
    assert 0.4 < ratio < 0.6


def test_no_skin_ring_leaves_the_patch():
    patch = scene((190.0, 130.0, 100.0))
    assert match_light(patch, scene((128.0, 128.0, 128.0)), np.ones((SIZE, SIZE), bool), ring=4, colourful=False) is patch
