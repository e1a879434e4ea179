"""Measures on a face's 68 points that every stage reads: the inter-ocular distance, finite points, each eye's
axes and lid aperture, and how far two faces' landmarks lie apart (the nearest shots to a target)."""

from __future__ import annotations

import numpy as np

from landmarks.shape.ibug68 import LEFT_EYE, NUM_LANDMARKS, RIGHT_EYE


def inter_ocular_distance(landmarks: np.ndarray) -> np.ndarray:
    """(..., 68, 2) -> (...) distance between the two eye centres."""
    left = landmarks[..., LEFT_EYE, :].mean(axis=-2)
    right = landmarks[..., RIGHT_EYE, :].mean(axis=-2)
    return np.linalg.norm(right - left, axis=-1)


def finite_points(landmarks: np.ndarray) -> np.ndarray | None:
    """One face's 68 points as (68, 2) float64, or None where any is not finite (a ValueError for another shape)."""
    points = np.asarray(landmarks, np.float64)
    if points.shape != (NUM_LANDMARKS, 2):
        raise ValueError(f"landmarks must be ({NUM_LANDMARKS}, 2), got {points.shape}")
    return points if np.isfinite(points).all() else None


def landmark_distance(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Mean point distance over ``second``'s eye-centre distance (NMKE without alignment).

    first, second: (..., 68, 2) broadcastable -> (...) float64; NaN where either has NaN rows or no eye distance.
    """
    first, second = np.asarray(first, np.float64), np.asarray(second, np.float64)
    mean_distance = np.linalg.norm(first - second, axis=-1).mean(axis=-1)
    eyes = np.linalg.norm(second[..., LEFT_EYE, :].mean(axis=-2) - second[..., RIGHT_EYE, :].mean(axis=-2), axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(eyes > 0, mean_distance / np.where(eyes > 0, eyes, 1.0), np.nan)


def nearest_shots(shot_landmarks: np.ndarray, target_landmarks: np.ndarray, count: int) -> np.ndarray:
    """Indices of the ``count`` shots nearest to the target (``landmark_distance``, ties by index).

    shot_landmarks: (K, 68, 2) (NaN rows = shot without a face; chosen last); target_landmarks: (68, 2)
    -> (min(count, K),) int. Raw landmarks, not aligned: the warped pixels keep their position, so a shot
    whose head sits elsewhere in the frame is a worse reference even if the pose matches.
    """
    distances = landmark_distance(shot_landmarks, np.asarray(target_landmarks)[None])
    distances = np.where(np.isnan(distances), np.inf, distances)
    return np.argsort(distances, kind="stable")[: max(1, min(count, len(shot_landmarks)))]

EYES = ((36, 39, False), (42, 45, True))
"""Per eye of the 68 points, image left first: its corners (outer or inner, left to right in the image) and whether
the iris net sees it mirrored (the net knows image-left eyes)."""

EYE_RINGS = (tuple(range(36, 42)), tuple(range(42, 48)))
"""Each eye's lid polygon in the 68 points."""


def eye_axes(landmarks: np.ndarray, eye: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(centre (2,), unit axis along the corners (2,), width) of eye ``eye`` (0 = image left) of (68, 2) points."""
    first, last, _ = EYES[eye]
    start, end = np.asarray(landmarks[first], np.float64), np.asarray(landmarks[last], np.float64)
    width = float(np.linalg.norm(end - start))
    axis = (end - start) / max(width, 1e-9)
    return (start + end) / 2.0, axis, width


def eye_apertures(landmarks: np.ndarray) -> np.ndarray:
    """(2,) each eye's lid gap (the mean of its two vertical point pairs) over its width."""
    points = np.asarray(landmarks, np.float64)
    gaps = []
    for eye, ring in enumerate(EYE_RINGS):
        _, _, width = eye_axes(points, eye)
        upper, lower = points[[ring[1], ring[2]]], points[[ring[5], ring[4]]]
        gaps.append(float(np.mean(np.linalg.norm(upper - lower, axis=1))) / max(width, 1e-9))
    return np.array(gaps)
