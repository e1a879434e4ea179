"""A face part's own window: the square of a face crop that a part generator sees and redraws (issue 40).

The mouth is drawn, not blended: a small generator (``models_def.part_generator``) gets the mouth's window of
the frame synthesis (the blend of warped shots), the target's lips as two masks (the outer-lip polygon and the
open mouth inside the inner lips) and returns the window redrawn; the window is pasted back under a feathered
mask around the lips. This module is the geometry, numpy + OpenCV only, shared by training
(``lsr.train.part_training``), the torch and ONNX runtimes (``lsr.core.engine``) and the tests:

* ``window_transform``: the similarity taking crop pixels to the window's (centred on the part, the eye line
  level, a side of ``span`` eye distances mapped onto ``size`` pixels);
* ``extract``: the window of an image;
* ``lip_masks``: the target's outer-lip and open-mouth masks in the window, antialiased, in [0, 1];
* ``paste_weight``: where the drawn window replaces the crop: the outer lips grown by ``MOUTH_MARGIN`` and
  feathered by ``MOUTH_FEATHER`` eye distances (``landmarks.parts.mouth.nearest_mouth``'s region);
* ``paste``: the drawn window warped back into the crop under that weight.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from landmarks.shape.ibug68 import LEFT_EYE, NUM_LANDMARKS, RIGHT_EYE

OUTER_LIPS = slice(48, 60)
INNER_LIPS = slice(60, 68)
MOUTH_MARGIN = 0.12
"""The outer-lip polygon is grown by this fraction of the eye distance for the paste weight ..."""
MOUTH_FEATHER = 0.035
"""... and feathered by a Gaussian of this fraction of the eye distance."""


@dataclasses.dataclass(frozen=True)
class PartWindow:
    """Where a part's window sits: ``span`` eye distances square, centred on the mean of ``points`` shifted by
    ``offset`` eye distances (x along the eye line, y down), resampled to ``size`` pixels."""

    name: str
    points: slice
    span: float
    size: int
    offset: tuple[float, float] = (0.0, 0.0)


MOUTH = PartWindow("mouth", OUTER_LIPS, span=1.6, size=80)


def _eye_frame(landmarks: np.ndarray) -> tuple[np.ndarray, float]:
    """The unit vector along the eye line (image-left eye to image-right eye) and the eye distance."""
    left = landmarks[LEFT_EYE].mean(axis=0)
    right = landmarks[RIGHT_EYE].mean(axis=0)
    axis = right - left
    distance = float(np.hypot(*axis))
    return axis / max(distance, 1e-6), distance


def window_transform(landmarks: np.ndarray, part: PartWindow = MOUTH) -> np.ndarray | None:
    """(2, 3) float64 affine taking crop pixels to ``part``'s window pixels, or None when the landmarks are not
    finite or the eyes coincide. landmarks: (68, 2) crop pixels (pixel centres at integers)."""
    points = np.asarray(landmarks, np.float64)
    if points.shape != (NUM_LANDMARKS, 2):
        raise ValueError(f"landmarks must be ({NUM_LANDMARKS}, 2), got {points.shape}")
    if not np.isfinite(points).all():
        return None
    (cos, sin), eyes = _eye_frame(points)
    if eyes < 1e-3:
        return None
    scale = part.size / (part.span * eyes)  # window pixels per crop pixel
    centre = points[part.points].mean(axis=0) + eyes * (part.offset[0] * np.array([cos, sin])
                                                         + part.offset[1] * np.array([-sin, cos]))
    rotation = scale * np.array([[cos, sin], [-sin, cos]])  # the eye line becomes the window's x axis
    half = (part.size - 1) / 2.0
    return np.hstack([rotation, (np.array([half, half]) - rotation @ centre)[:, None]])


def to_window(points: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """(..., 2) crop pixels -> window pixels under ``window_transform``'s affine."""
    points = np.asarray(points, np.float64)
    return points @ transform[:, :2].T + transform[:, 2]


def extract(image: np.ndarray, transform: np.ndarray, size: int) -> np.ndarray:
    """The (size, size, C) window of ``image`` (H, W, C) under ``transform``, bilinear; outside the image the
    border is replicated."""
    return cv2.warpAffine(image, transform, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def polygon_mask(points: np.ndarray, shape: int | tuple[int, int]) -> np.ndarray:
    """An anti-aliased filled polygon: points (N, 2) in pixels, shape (H, W) or a side -> (H, W) float32 in [0, 1]."""
    mask = np.zeros((shape, shape) if np.ndim(shape) == 0 else tuple(shape), np.uint8)
    cv2.fillPoly(mask, [np.round(points * 16).astype(np.int32)], 255, lineType=cv2.LINE_AA, shift=4)
    return mask.astype(np.float32) * (1.0 / 255.0)


def lip_masks(window_landmarks: np.ndarray, size: int) -> np.ndarray:
    """(2, size, size) float32 in [0, 1]: the outer-lip polygon and the open mouth (inside the inner lips) of
    landmarks (68, 2) in window pixels. A closed mouth's inner polygon has no area: its mask is (nearly) empty."""
    points = np.asarray(window_landmarks, np.float64)
    return np.stack([polygon_mask(points[OUTER_LIPS], size), polygon_mask(points[INNER_LIPS], size)])


def paste_weight(window_landmarks: np.ndarray, size: int, eye_distance: float) -> np.ndarray:
    """(size, size) float32 in [0, 1]: the outer lips grown by ``MOUTH_MARGIN`` and feathered by ``MOUTH_FEATHER``
    of ``eye_distance`` (in window pixels), faded to 0 at the window's edge so no step is left there."""
    grow = max(1, round(MOUTH_MARGIN * eye_distance))
    sigma = max(0.5, MOUTH_FEATHER * eye_distance)
    mask = (polygon_mask(np.asarray(window_landmarks, np.float64)[OUTER_LIPS], size) * 255).astype(np.uint8)
    mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1)))
    weight = cv2.GaussianBlur(mask.astype(np.float32) * (1.0 / 255.0), (0, 0), sigma)
    ramp = np.minimum(np.arange(size), np.arange(size)[::-1]).astype(np.float32)
    edge = np.clip(ramp / max(1.0, 2 * sigma), 0.0, 1.0)
    return weight * edge[:, None] * edge[None, :]


def window_eye_distance(part: PartWindow = MOUTH) -> float:
    """The eye distance in window pixels (every window of ``part`` has the same)."""
    return part.size / part.span


def paste(image: np.ndarray, drawn: np.ndarray, weight: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """``image`` (H, W, 3) uint8 with the window ``drawn`` (P, P, 3) uint8 put back under ``weight`` (P, P) in
    [0, 1] through the inverse of ``transform``; only the window's bounding box is touched. Returns a new array."""
    size = drawn.shape[0]
    height, width = image.shape[:2]
    inverse = cv2.invertAffineTransform(transform)
    corners = to_window(np.array([[0, 0], [size - 1, 0], [0, size - 1], [size - 1, size - 1]], np.float64),
                        inverse)  # the window's corners in crop pixels
    x0, y0 = np.maximum(np.floor(corners.min(axis=0)).astype(int) - 1, 0)
    x1, y1 = np.minimum(np.ceil(corners.max(axis=0)).astype(int) + 2, (width, height))
    result = image.copy()
    if x1 <= x0 or y1 <= y0:
        return result
    shift = np.array([[1.0, 0.0, x0], [0.0, 1.0, y0]])  # box pixels -> crop pixels
    box_to_window = np.hstack([transform[:, :2], (transform[:, :2] @ shift[:, 2] + transform[:, 2])[:, None]])
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    back = cv2.warpAffine(drawn, box_to_window, (x1 - x0, y1 - y0), flags=flags, borderMode=cv2.BORDER_REPLICATE)
    alpha = cv2.warpAffine(weight.astype(np.float32), box_to_window, (x1 - x0, y1 - y0), flags=flags,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)[..., None]
    box = result[y0:y1, x0:x1].astype(np.float32)
    result[y0:y1, x0:x1] = np.clip(np.rint(alpha * back + (1.0 - alpha) * box), 0, 255).astype(np.uint8)
    return result
