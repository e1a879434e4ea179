"""The mouth from the nearest warped shot, over the warp-guided synthesis (issue 23: expressions beyond the shots).

The warp-guided generator blends its N warped shots per pixel. Where the target's mouth opens wider than most of
the shots', the shots disagree inside the lips (one shows teeth and a dark gap, the others stretched lips), and
the blend and the median detail (``models_def.composite``) settle between them: the output's mouth opens only
two thirds as wide as the driver's (mouth gain 0.70 on the validation people, 0.64 on the FSTH sample at K = 8),
while the nearest shot warped alone reaches 0.94. A blend of disagreeing mouths is also what averaging warps
does (``mesh_mean3``: 0.73).

So the mouth region, the target's outer-lip polygon grown by ``MOUTH_MARGIN`` and feathered by
``MOUTH_FEATHER`` (fractions of the target's eye distance), is taken from the nearest shot warped onto the
target (the first reference: ``landmarks.shape.measures.nearest_shots``' order), where that warp is valid, and as far as
the target opens its mouth wider than the references' median (``mouth_strength``: fully from ``CLOSED_MOUTH``
beyond it). Where the target's mouth is one most references show, their blend is right and more accurate than
one shot (taken always, the nearest shot's mouth cost 0.3 dB of face PSNR in self re-enactment on the FSTH
sample); everything else stays the network's. Measured at K = 8 (BENCHMARKS.md, MODEL_CARD.md): mouth gain 0.81
on the FSTH sample (0.64 with the blend's mouth) and 0.86 on the validation people (0.69), face PSNR in self
re-enactment 0.06 dB below the blend's on the FSTH sample.

A nearest shot unlike the synthesis around the mouth would be pasted as a patch: on the FSTH sample, id00081's shots
included frames of his interviewer (the video cuts away; ``landmarks.detect.same_person`` now leaves such shots out), and a
nearest shot's mouth came out as bright orange lips on the other person's darker face. So the shot's mouth is taken
less where its skin around the mouth (the region's feathered edge) differs from the synthesis' (``mismatch``, from
``MISMATCH[0]`` = 15 grey levels) and not at all from ``MISMATCH[1]`` = 25 on (another person, or another lighting);
the network's own blend hedges between the shots. The largest difference on the 4 validation people is 13.7 (their
outputs are unchanged); on the FSTH sample id00812's reach 12.6 and id00081's, with the interviewer's frames among
the shots, a median of 30.6. Colour-matching the shot to the synthesis (a gain per channel from the edge) instead
left the shot's doubled lip outline there.

numpy + OpenCV only: the torch and ONNX runtimes share it through ``lsr.core.engine``.
"""

from __future__ import annotations

import cv2
import numpy as np

from landmarks.shape.expression import CLOSED_MOUTH, mouth_opening
from landmarks.shape.ibug68 import NUM_LANDMARKS
from landmarks.shape.measures import inter_ocular_distance
from landmarks.shape.measures import nearest_shots

OUTER_LIPS = slice(48, 60)
MOUTH_MARGIN = 0.15
"""The outer-lip polygon is grown by this fraction of the eye distance (the lips' edges and the skin next to them
come from the same shot, so no seam runs along the lip line) ..."""
MOUTH_FEATHER = 0.04
"""... and feathered by a Gaussian of this fraction of the eye distance."""
MISMATCH = (15.0, 25.0)
"""Grey levels: a nearest shot whose skin around the mouth (``mismatch``) differs from the synthesis' by more than the
first is taken less, by the second not at all (another person or lighting: its mouth would be a patch)."""


def mouth_weight(landmarks: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, tuple[int, int, int, int]] | None:
    """The mouth region's weight in [0, 1] over its bounding box. landmarks: (68, 2) pixels of an image of
    ``shape`` (H, W) -> (weight (y1 - y0, x1 - x0) float32, box (x0, y0, x1, y1)), or None when the landmarks are
    not finite or the region lies outside the image."""
    points = np.asarray(landmarks, np.float64)
    if points.shape != (NUM_LANDMARKS, 2):
        raise ValueError(f"landmarks must be ({NUM_LANDMARKS}, 2), got {points.shape}")
    if not np.isfinite(points).all():
        return None
    eyes = float(inter_ocular_distance(points))
    grow, sigma = max(1, round(MOUTH_MARGIN * eyes)), max(0.5, MOUTH_FEATHER * eyes)
    reach = grow + int(np.ceil(3 * sigma)) + 1
    lips = points[OUTER_LIPS]
    height, width = shape
    x0, y0 = (np.floor(lips.min(axis=0)) - reach).astype(int)
    x1, y1 = (np.ceil(lips.max(axis=0)) + reach + 1).astype(int)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
    if x1 <= x0 or y1 <= y0:
        return None
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillPoly(mask, [np.round((lips - (x0, y0)) * 4).astype(np.int32)], 255, lineType=cv2.LINE_AA, shift=2)
    mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1)))
    weight = cv2.GaussianBlur(mask.astype(np.float32) * (1.0 / 255.0), (0, 0), sigma)
    return weight, (int(x0), int(y0), int(x1), int(y1))


def mouth_strength(landmarks: np.ndarray, shot_landmarks: np.ndarray, count: int) -> float:
    """How much of the nearest shot's mouth to take: (target opening - the median opening of the ``count`` shots
    nearest to the target, as the references are chosen) / ``CLOSED_MOUTH``, clipped to [0, 1]. landmarks: (68, 2);
    shot_landmarks: (K, 68, 2), both in the same pixels -> float (0 when an opening is not finite)."""
    chosen = np.resize(nearest_shots(shot_landmarks, landmarks, count), count)  # repeated when K < count
    excess = float(mouth_opening(landmarks)) - float(np.median(mouth_opening(np.asarray(shot_landmarks)[chosen])))
    return float(np.clip(excess / CLOSED_MOUTH, 0.0, 1.0)) if np.isfinite(excess) else 0.0


def mismatch(image: np.ndarray, nearest: np.ndarray, nearest_valid: np.ndarray,
             region: tuple[np.ndarray, tuple[int, int, int, int]]) -> float:
    """How unlike the synthesis the nearest shot is around the mouth: the mean absolute difference, in grey levels
    (RGB mean), over the region's feathered edge (weight 0.02-0.5: the skin beyond the lips) where the shot's warp
    is valid. image, nearest: (S, S, 3) uint8; nearest_valid: (S, S); region: ``mouth_weight``'s -> float (0 when
    the edge has no valid pixel)."""
    weight, (x0, y0, x1, y1) = region
    edge = (weight > 0.02) & (weight < 0.5) & (nearest_valid[y0:y1, x0:x1] > 0.5)
    if not edge.any():
        return 0.0
    difference = np.abs(nearest[y0:y1, x0:x1].astype(np.float32) - image[y0:y1, x0:x1].astype(np.float32))
    return float(difference.mean(axis=-1)[edge].mean())


def keep_nearest_mouth(image: np.ndarray, nearest: np.ndarray, nearest_valid: np.ndarray, landmarks: np.ndarray,
                       strength: float = 1.0) -> np.ndarray:
    """``image`` with the mouth region (``mouth_weight`` of ``landmarks``) taken from ``nearest`` where that is valid,
    at ``strength`` (``mouth_strength``; 1 = wholly), less where ``nearest`` is unlike the synthesis around the
    mouth (``mismatch`` from ``MISMATCH[0]``, none from ``MISMATCH[1]`` on).

    image, nearest: (S, S, 3) uint8 (the synthesis and the nearest shot warped onto the same target);
    nearest_valid: (S, S) float in [0, 1] (the warp's validity); landmarks: (68, 2) target pixels -> (S, S, 3)
    uint8, a new array (``image`` itself when there is no mouth region or the strength is 0)."""
    if image.shape != nearest.shape or image.dtype != np.uint8 or nearest.dtype != np.uint8:
        raise ValueError(f"image and nearest must be two (S, S, 3) uint8 arrays, got {image.shape} {image.dtype} "
                         f"and {nearest.shape} {nearest.dtype}")
    found = mouth_weight(landmarks, image.shape[:2]) if strength > 0 else None
    if found is None:
        return image
    low, high = MISMATCH
    strength *= float(np.clip((high - mismatch(image, nearest, nearest_valid, found)) / (high - low), 0.0, 1.0))
    if strength <= 0:
        return image
    weight, (x0, y0, x1, y1) = found
    weight = (min(strength, 1.0) * weight * np.clip(nearest_valid[y0:y1, x0:x1], 0.0, 1.0))[..., None]
    result = image.copy()
    mixed = weight * nearest[y0:y1, x0:x1] + (1.0 - weight) * image[y0:y1, x0:x1]
    result[y0:y1, x0:x1] = np.clip(np.rint(mixed), 0, 255).astype(np.uint8)
    return result
