"""Eye realism: how far an output eye lies from the nearest of the person's own real eyes (issue 63).

Streaked irises and smudged grey lids are far from every real eye of the person; the judged correlations cannot see
them (dlib reads a smudge's lids as well as a real eye's). Each eye is cut in its own frame by its corners
(``landmarks.parts.eyes.eye_bank.cut_eyes``), made grey, zero-mean and unit-norm (``realism_patches``), and its distance
is 1 - its best normalised cross-correlation with the same patch of every real frame (``eye_realism``). Reported
beside the same distance for the person's real frames against frames a few frames away: its floor. A frozen eye
lies near, which is why realism stands beside the judged correlation and gaze.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from landmarks.parts.eyes.eye_bank import cut_eyes
from landmarks.shape.measures import finite_points

REALISM_PATCH = (64, 32)
"""The patch ``eye_realism`` compares, (width, height) pixels at ``eye_bank.CANON_WIDTH``: the eye and its lids."""


def realism_patches(frame: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Both eyes of a frame, cut as ``eye_realism`` compares them: (2, REALISM_PATCH[1] * REALISM_PATCH[0]) float32,
    grey, each zero-mean and unit-norm (NaN rows where the points are not finite)."""
    points = finite_points(landmarks)
    if points is None:
        return np.full((2, REALISM_PATCH[0] * REALISM_PATCH[1]), np.nan, np.float32)
    grey = cut_eyes(frame, points, REALISM_PATCH).astype(np.float32).mean(axis=-1).reshape(2, -1)
    grey -= grey.mean(axis=1, keepdims=True)
    norms = np.linalg.norm(grey, axis=1, keepdims=True)
    return grey / np.where(norms > 1e-6, norms, np.nan)


def eye_realism(eyes: np.ndarray, real: np.ndarray, exclude: Sequence[Sequence[int]] | None = None) -> np.ndarray:
    """Each eye's distance to the nearest real eye: 1 - the best normalised cross-correlation.

    eyes: (M, 2, P) ``realism_patches`` of the frames judged; real: (N, 2, P) those of the person's real frames;
    exclude: per judged frame, the real frames not to compare with (a real hold-out frame itself and its
    neighbours, for the floor) -> (M, 2) float64 in [0, 2], NaN where an eye or every real one is not found."""
    eyes, real = np.asarray(eyes, np.float32), np.asarray(real, np.float32)
    if eyes.ndim != 3 or real.ndim != 3 or eyes.shape[1:] != real.shape[1:]:
        raise ValueError(f"eyes and real must be (M, 2, P) and (N, 2, P), got {eyes.shape} and {real.shape}")
    distances = np.full(eyes.shape[:2], np.nan)
    for eye in range(2):
        known = np.isfinite(real[:, eye]).all(axis=1)
        correlations = np.nan_to_num(eyes[:, eye]) @ np.where(known[:, None], real[:, eye], 0).T  # (M, N)
        correlations[:, ~known] = -np.inf
        if exclude is not None:
            for row, skipped in enumerate(exclude):
                correlations[row, list(skipped)] = -np.inf
        best = correlations.max(axis=1) if correlations.shape[1] else np.full(len(eyes), -np.inf)
        found = np.isfinite(eyes[:, eye]).all(axis=1) & np.isfinite(best)
        distances[found, eye] = 1.0 - best[found]
    return distances
