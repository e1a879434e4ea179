"""An open mouth drawn from the shot whose mouth is open most like the target's (issue 23: expressions).

The warp-guided generator blends the shots nearest in *pose*; where they disagree on the mouth (most are closed,
one is open) the blend draws it about 0.6 as open as asked (``lsr eval``'s mouth gain on validation people).
Here the mouth region (the outer lips' hull, grown by a third of the eye distance, feathered) is taken instead
from one shot, the one whose mouth opening is closest to the target's, TPS-warped onto the target's landmarks
(``landmarks.tps.tps_map``) and colour-matched to the generator's output around it. A nearly closed target
mouth is left to the generator; the region fades in from ``MIN_OPENING`` to ``FULL_OPENING``.

numpy + OpenCV only; the frame loop (``lsr.core.engine``) applies it after the generator, in both runtimes.
"""

from __future__ import annotations

import cv2
import numpy as np

from landmarks.expression import inter_ocular, mouth_opening

OUTER_LIPS = list(range(48, 60))
MIN_OPENING = 0.03
"""Target mouth openings (inner-lip gap / eye distance) below this are left to the generator ..."""
FULL_OPENING = 0.07
"""... and from this one on the mouth region is the matched shot's."""
GROW = 0.35  # the region reaches this many eye distances beyond the outer lips (chin and cheeks move with the jaw)


def mouth_region(target: np.ndarray, side: int) -> np.ndarray:
    """(side, side) float32 weights: 1 over the grown outer-lip hull, a smooth ramp outside it, 0 far away."""
    hull = np.zeros((side, side), np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(np.round(target[OUTER_LIPS]).astype(np.int32)), 1)
    reach = GROW * float(inter_ocular(target))
    outside = cv2.distanceTransform(1 - hull, cv2.DIST_L2, 3)
    ramp = np.clip((reach - outside) / max(reach * 0.6, 1.0), 0.0, 1.0)
    return (ramp * ramp * (3.0 - 2.0 * ramp)).astype(np.float32)


def matched_mouth(image: np.ndarray, target: np.ndarray, shots: np.ndarray, shot_landmarks: np.ndarray) -> np.ndarray:
    """The generator's output with its mouth region taken from the shot opened most like the target (docstring).

    image: (C, C, 3) uint8 the synthesis; target: (68, 2) its landmarks, crop pixels; shots: (K, C, C, 3) uint8,
    shot_landmarks: (K, 68, 2) at the same side. Returns a new image, or ``image`` itself for a nearly closed
    target mouth.
    """
    from landmarks.tps import tps_map

    target = np.asarray(target, np.float64)
    opening = float(mouth_opening(target))
    strength = float(np.clip((opening - MIN_OPENING) / (FULL_OPENING - MIN_OPENING), 0.0, 1.0)) if np.isfinite(opening) else 0.0
    openings = mouth_opening(shot_landmarks)
    if strength <= 0 or not np.isfinite(openings).any():
        return image
    donor = int(np.nanargmin(np.abs(openings - opening)))
    side = image.shape[0]
    warp = tps_map(np.asarray(shot_landmarks[donor], np.float64), target, side, side, grid_step=4)
    mouth = cv2.remap(shots[donor], warp.map_x, warp.map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    alpha = mouth_region(target, side) * strength
    ring = (alpha > 0.02) & (alpha < 0.5 * strength)  # the region's outer edge: match colours there
    base, mouth = image.astype(np.float32), mouth.astype(np.float32)
    if ring.sum() > 8:
        mouth = mouth + (base[ring] - mouth[ring]).mean(0)
    blended = base + (mouth - base) * alpha[..., None]
    return np.clip(np.rint(blended), 0, 255).astype(np.uint8)
