"""Laying a real patch into the synthesis: its light matched to the skin around it, under a feathered mask.
Shared by the driver's mouth interior and shut lids and by both part banks."""

from __future__ import annotations

import cv2
import numpy as np

CAST, FADE = 0.5, 2.0
"""The share of the colour cast (the skin ring's mean colour less its grey, the synthesis' against the driver's) the
patch takes on, fading out toward the highlights: a pixel takes ``CAST`` of it up to half the synthesis' brightest
around the lips (its 99th percentile), none at it (``FADE`` = 1 / that half). The whole cast turned white teeth
orange on a ruddier face; none left a driver's bluish lips in another video's light; half of it everywhere tinted
the teeth past what the target's own video shows (on 4 validation pairs re-enacted by ``lsr reenact``, the share
of teeth-like pixels in the open mouths, ``landmarks.parts.appearance.mouth_interior``, fell from 28% to 18%; with the
fade 23%)."""

GAIN = (0.6, 1.6)
"""The brightness gain is clipped to this range (a patch of background or hair in the ring). One gain for the three
channels: a gain per channel matched the skin's tone too, which turned the driver's teeth orange on a ruddier face."""


def match_light(warped: np.ndarray, region: np.ndarray, lips: np.ndarray, ring: int, cast: float = CAST,
                fade: float | None = FADE, colourful: bool = True,
                lights: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The driver's mapped patch ``warped`` (h, w, 3) float32 lit as the target is, against ``region`` (h, w, 3)
    float32, the synthesis there, whose outer lips cover ``lips`` (h, w) bool with a skin ring ``ring`` pixels wide
    around them -> a new (h, w, 3) float32: scaled by one gain so that the ring's brightness matches (clipped to
    ``GAIN``), then shifted by ``cast`` of the difference of the rings' colour casts (mean colour less mean grey),
    fading out toward the synthesis' brightest there (``fade``; None: no fading, skin laid on skin). The patch as it
    is where there is no ring. colourful False: another person's patch, first made no more colourful than the
    target (``colour_ratio``, ``desaturated``), so that a greyscale video takes a grey interior where a shift of the mean cast left a
    colourful driver's red lips and blue make-up inside it. lights: the target's and the patch's mean colours (3,)
    over skin elsewhere (``landmarks.parts.mouth.interior.nose_light``: a beard rings a bearded mouth), matched in
    place of the rings'.

    Tried and dropped: blurring the patch until no sharper than the synthesis, and softening its highlights above
    the synthesis' brightest. On a crisp driver's teeth in a dim, soft video (the FSTH sample's id00017) they looked
    less pasted on, but dlib's 68 points read those mouths less open (on two FSTH pairs' open mouths, the judged
    opening's slope on the target's 1.00 -> 0.75; in ``lsr eval``'s judged table, mouth correlation 0.65 -> 0.61,
    gain 0.64 -> 0.55 at K = 8): the synthesis is softer than the video it stands for."""
    grown = cv2.dilate(lips.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring + 1,) * 2)) > 0
    skin = grown & ~lips
    if not skin.any():
        return warped
    lit = None if lights is None else [np.asarray(light, np.float64) for light in lights]
    if not colourful:
        scale = colour_ratio(warped, region, skin)
        warped = desaturated(warped, scale)
        if lit is not None:  # the driver's light as colourless as its patch now is
            lit[1] = lit[1] - (1.0 - scale) * (lit[1] - lit[1].mean())
    means = (lit if lit is not None
             else [values[skin].mean(axis=0, dtype=np.float64) for values in (region, warped)])  # (3,) each
    gain = float(np.clip((means[0].mean() + 1.0) / (means[1].mean() + 1.0), *GAIN))
    shift = ((means[0] - means[0].mean()) - gain * (means[1] - means[1].mean())) * cast
    result = warped * np.float32(gain)
    if fade is None:
        return (result + shift.astype(np.float32)).astype(np.float32)
    top = float(np.percentile(region.max(axis=-1)[grown], 99.0))
    fading = np.clip(fade * (1.0 - result.mean(axis=-1, keepdims=True) / np.float32(max(top, 1.0))), 0.0, 1.0)
    return (result + fading * shift.astype(np.float32)).astype(np.float32)


def colour_ratio(warped: np.ndarray, region: np.ndarray, skin: np.ndarray) -> float:
    """The target's colourfulness over the patch's, at most 1: the mean length of each pixel's colour (its channels
    less their mean) over ``skin`` (h, w) bool, in ``region`` over in ``warped`` (both (h, w, 3) float32)."""
    colour = [values - values.mean(axis=-1, keepdims=True) for values in (region, warped)]
    target, driven = (float(np.linalg.norm(c[skin], axis=-1).mean(dtype=np.float64)) for c in colour)
    return min(1.0, target / driven) if driven > 0 else 1.0


def desaturated(warped: np.ndarray, scale: float) -> np.ndarray:
    """``warped`` (h, w, 3) float32 with each pixel's colour (its channels less their mean) scaled by ``scale``
    (``colour_ratio``): a new float32 array, or ``warped`` itself at 1 or more."""
    if scale >= 1.0:
        return warped
    return (warped - (1.0 - np.float32(scale)) * (warped - warped.mean(axis=-1, keepdims=True))).astype(np.float32)


def ellipse_mask(centre: np.ndarray, axes: tuple[float, float], along: np.ndarray, shape: tuple[int, int]
                 ) -> np.ndarray:
    """The pixels whose centres lie inside the ellipse of semi-axes ``axes`` (along the unit direction ``along``
    (2,), and across it) around ``centre`` (2,): (h, w) float32 in {0, 1} (the web page computes the same)."""
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    dx, dy = xs - centre[0], ys - centre[1]
    u, v = dx * along[0] + dy * along[1], dy * along[0] - dx * along[1]
    return ((u / axes[0]) ** 2 + (v / axes[1]) ** 2 <= 1.0).astype(np.float32)
