"""What a face's moving parts look like, read from the pixels inside its 68-point part polygons.

These measures look at the image, not at where a landmark detector put the lids or lips, so that they can judge
an output whose landmarks were driven: a lip stretched to a target's shape counts as an open mouth to a landmark
detector, whatever is drawn inside it, and a doubled iris has no landmark at all.

* ``iris_offset``: where the iris sits in each eye, in eye widths from the corners' midpoint (x along the
  corner-to-corner axis, towards the image's right; y across it, downwards). The iris is the dark-weighted
  centroid of the pixels inside the eye polygon (points 36-41, 42-47), found in a patch that maps the corners
  to fixed places; an eye open less than ``OPEN_EYE`` of its width has no iris to find (NaN).
* ``iris_contrast``: (bright - dark) / bright of the eye polygon's grey levels (its 90th and 10th percentiles):
  a sharp iris on a white sclera is near 0.6-0.8; an iris blended with a second one, or with the sclera, is
  lighter and the sclera darker, so the contrast of a doubled iris is about half the real eye's.
* ``mouth_interior``: inside the inner-lip polygon (points 60-67) of an open mouth, its median grey level over
  the face's (``darkness``: a cavity is about 0.2-0.4, lips or a tongue 0.6-0.9) and the share of teeth-like
  pixels (``teeth``: grey at least ``TEETH_GREY`` of the face's, saturation under ``TEETH_SATURATION``).

numpy + OpenCV only; every function takes (H, W, 3) uint8 RGB and (68, 2) x, y pixel landmarks.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from landmarks.shape.ibug68 import NUM_LANDMARKS

EYES = ((36, 39), (42, 45))  # each eye's corners, image-left first; its six points are range(first, first + 6)
OPEN_EYE = 0.15  # lid gap / eye width below which an eye counts as closed: no iris to locate or judge
PATCH_WIDTH = 48  # eye patch: the corners land at x = 8 and x = 40 on row 12 of a 48 x 24 patch
PATCH_HEIGHT = 24
PATCH_CORNERS = ((8.0, 12.0), (40.0, 12.0))
DARK_QUANTILE, BRIGHT_QUANTILE = 0.10, 0.90  # iris_contrast's dark and bright levels
# iris_offset: pixels darker than the eye's 5th percentile weigh 1, lighter than its 55th 0
IRIS_WEIGHT_QUANTILES = (0.05, 0.55)
OPEN_MOUTH = 0.08  # inner-lip gap / inter-ocular distance above which a mouth has an interior to look at
TEETH_GREY = 0.85  # teeth: at least this share of the face's median grey ...
TEETH_SATURATION = 0.30  # ... and less saturated than this (HSV saturation in [0, 1]): lips and tongues are red


def _check(image: np.ndarray, landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    image = np.asarray(image)
    points = np.asarray(landmarks, np.float64)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image must be (H, W, 3) uint8 RGB, got {image.shape} {image.dtype}")
    if points.shape != (NUM_LANDMARKS, 2):
        raise ValueError(f"landmarks must be ({NUM_LANDMARKS}, 2), got {points.shape}")
    return image, points


def _grey(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY).astype(np.float64)


def _eye_patch(grey: np.ndarray, points: np.ndarray, first: int) -> tuple[np.ndarray, np.ndarray] | None:
    """One eye mapped into a PATCH_WIDTH x PATCH_HEIGHT patch with its corners at PATCH_CORNERS -> (grey patch,
    polygon mask), or None for a closed or degenerate eye."""
    eye = points[first:first + 6]
    left, right = eye[0], eye[3]
    width = float(np.linalg.norm(right - left))
    gap = 0.5 * (np.linalg.norm(eye[1] - eye[5]) + np.linalg.norm(eye[2] - eye[4]))
    if not np.isfinite(eye).all() or width < 4.0 or gap < OPEN_EYE * width:
        return None
    source = np.float32([left, right, left + np.array([-(right - left)[1], (right - left)[0]])])
    (x0, y0), (x1, y1) = PATCH_CORNERS
    target = np.float32([[x0, y0], [x1, y1], [x0, y0 + (x1 - x0)]])  # a similarity: the perpendicular follows
    matrix = cv2.getAffineTransform(source, target)
    patch = cv2.warpAffine(grey.astype(np.float32), matrix, (PATCH_WIDTH, PATCH_HEIGHT), flags=cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
    polygon = cv2.transform(eye[None].astype(np.float32), matrix)[0]
    mask = np.zeros((PATCH_HEIGHT, PATCH_WIDTH), np.uint8)
    cv2.fillPoly(mask, [np.round(polygon * 4).astype(np.int32)], 1, shift=2)
    if mask.sum() < 12:
        return None
    return patch, mask.astype(bool)


def iris_offset(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Each eye's iris position, in eye widths from its corners' midpoint (module docstring).

    image: (H, W, 3) uint8 RGB; landmarks: (68, 2) -> (2, 2) float64 [[x, y] of the image-left eye, [x, y] of the
    image-right eye]; NaN rows for a closed eye or non-finite landmarks."""
    image, points = _check(image, landmarks)
    offsets = np.full((2, 2), np.nan)
    if not np.isfinite(points).all():
        return offsets
    grey = _grey(image)
    scale = PATCH_CORNERS[1][0] - PATCH_CORNERS[0][0]
    centre = 0.5 * (np.array(PATCH_CORNERS[0]) + np.array(PATCH_CORNERS[1]))
    for row, (first, _) in enumerate(EYES):
        found = _eye_patch(grey, points, first)
        if found is None:
            continue
        patch, mask = found
        values = patch[mask]
        dark, light = np.quantile(values, IRIS_WEIGHT_QUANTILES)
        if light - dark < 1.0:  # a flat eye: nothing to locate
            continue
        weights = np.clip((light - patch) / (light - dark), 0.0, 1.0) ** 2 * mask  # (H, W)
        total = weights.sum()
        if total <= 0:
            continue
        ys, xs = np.mgrid[0:PATCH_HEIGHT, 0:PATCH_WIDTH]
        found_centre = np.array([(weights * xs).sum(), (weights * ys).sum()]) / total
        offsets[row] = (found_centre - centre) / scale
    return offsets


def gazes(images, landmarks: np.ndarray) -> np.ndarray:
    """The horizontal ``gaze`` of each image: N x (H, W, 3) uint8, (N, 68, 2) -> (N,) float64 (NaN: eyes closed
    or no face)."""
    return np.array([gaze(image, points)[0] for image, points in zip(images, np.asarray(landmarks, np.float64))],
                    np.float64)


def gaze(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """The mean of both eyes' ``iris_offset`` (an eye that is closed left out): (2,) [x, y] in eye widths, NaN
    when neither eye is open."""
    offsets = iris_offset(image, landmarks)
    found = np.isfinite(offsets).all(axis=1)
    return offsets[found].mean(axis=0) if found.any() else np.full(2, np.nan)


def iris_contrast(image: np.ndarray, landmarks: np.ndarray) -> float:
    """(bright - dark) / bright of the open eyes' grey levels inside their polygons (module docstring), the mean
    over the open eyes -> float in [0, 1]; NaN when neither eye is open."""
    image, points = _check(image, landmarks)
    if not np.isfinite(points).all():
        return math.nan
    grey = _grey(image)
    values = []
    for first, _ in EYES:
        found = _eye_patch(grey, points, first)
        if found is None:
            continue
        patch, mask = found
        dark, bright = np.quantile(patch[mask], (DARK_QUANTILE, BRIGHT_QUANTILE))
        if bright > 0:
            values.append((bright - dark) / bright)
    return float(np.mean(values)) if values else math.nan


def polygon_mask(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: inside the polygon ``points`` (N, 2) pixels, filled at quarter-pixel precision."""
    mask = np.zeros(shape, np.uint8)
    cv2.fillPoly(mask, [np.round(points * 4).astype(np.int32)], 1, shift=2)
    return mask.astype(bool)


def mouth_interior(image: np.ndarray, landmarks: np.ndarray) -> tuple[float, float]:
    """An open mouth's inside (module docstring) -> (darkness: median grey inside the inner lips over the face's
    median grey, teeth: share of teeth-like pixels inside); (NaN, NaN) for a closed mouth (inner-lip gap under
    ``OPEN_MOUTH`` inter-ocular distances), too few pixels inside, or non-finite landmarks."""
    from landmarks.shape.expression import mouth_opening

    image, points = _check(image, landmarks)
    if not np.isfinite(points).all() or not mouth_opening(points) >= OPEN_MOUTH:
        return math.nan, math.nan
    shape = image.shape[:2]
    inside = polygon_mask(points[60:68], shape)
    if inside.sum() < 6:
        return math.nan, math.nan
    face = polygon_mask(cv2.convexHull(points.astype(np.float32))[:, 0].astype(np.float64), shape)
    for first, _ in EYES:  # the face's reference grey: skin, not eyes or the mouth
        face &= ~polygon_mask(points[first:first + 6], shape)
    face &= ~polygon_mask(points[48:60], shape)
    grey = _grey(image)
    reference = float(np.median(grey[face])) if face.any() else math.nan
    if not reference > 0:
        return math.nan, math.nan
    saturation = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2HSV)[..., 1].astype(np.float64) / 255.0
    teeth = (grey[inside] >= TEETH_GREY * reference) & (saturation[inside] < TEETH_SATURATION)
    return float(np.median(grey[inside]) / reference), float(teeth.mean())
