"""One-Euro temporal smoothing of landmark tracks, and a jitter metric.

One-Euro filter (Casiez, Roussel, Vogel, CHI 2012): an exponential low-pass whose
cutoff rises with speed, cutoff = min_cutoff + beta * |speed|, so a still face is
smoothed hard (little jitter) and a moving one lightly (little lag). Speeds are in
pixels per second, one speed per landmark (the norm of its x, y velocity), so the
filter is isotropic. Vectorised over all 68 points.
"""

from __future__ import annotations

import math

import numpy as np

from landmarks.shape.measures import inter_ocular_distance
from landmarks.shape.ibug68 import NUM_LANDMARKS


def _alpha(cutoff: np.ndarray | float, fps: float) -> np.ndarray | float:
    """Smoothing factor of a first-order low-pass at ``cutoff`` Hz sampled at ``fps``."""
    tau = 1.0 / (2.0 * math.pi * np.asarray(cutoff))
    return 1.0 / (1.0 + tau * fps)


EXPRESSIVE_POINTS = tuple(range(36, 68))  # eyelids and lips: blinks and mouth motion last a few frames
EXPRESSIVE_CUTOFF = 12.0  # Hz: a blink (about 150 ms) and a syllable's mouth opening pass: of 4 validation drivers' mouth
# opening, 6 Hz kept 0.84-0.90 and 12 Hz 0.88-0.94 (least-squares slope on the unsmoothed detection)


def driving_cutoffs(rigid: float = 1.0, expressive: float = EXPRESSIVE_CUTOFF) -> np.ndarray:
    """Per-point ``min_cutoff`` for driving landmarks: (68,) Hz, the head steady, eyes and lips quick."""
    cutoffs = np.full(NUM_LANDMARKS, rigid)
    cutoffs[list(EXPRESSIVE_POINTS)] = expressive
    return cutoffs


class OneEuroFilter:
    """Stateful One-Euro filter over (68, 2) point sets (any (P, 2) works).

    fps: sample rate; min_cutoff (Hz): smoothing at rest, one value or one per point ((P,), e.g.
    ``driving_cutoffs()``); beta: speed coefficient (per px/s); d_cutoff (Hz): low-pass on the speed estimate.
    """

    def __init__(self, fps: float, min_cutoff: float | np.ndarray = 1.0, beta: float = 0.05, d_cutoff: float = 1.0) -> None:
        if fps <= 0 or np.any(np.asarray(min_cutoff) <= 0) or beta < 0 or d_cutoff <= 0:
            raise ValueError("need fps > 0, min_cutoff > 0, beta >= 0, d_cutoff > 0")
        self.fps, self.min_cutoff, self.beta, self.d_cutoff = fps, np.asarray(min_cutoff, np.float64), beta, d_cutoff
        self.reset()

    def reset(self) -> None:
        """Forget the past (call across a gap: smoothing must not bridge missing frames)."""
        self._previous: np.ndarray | None = None
        self._speed: np.ndarray | None = None

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """points: (P, 2) float -> filtered (P, 2) float32. A NaN input resets and passes through."""
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 2:
            raise ValueError(f"points must be (P, 2), got {points.shape}")
        if not np.isfinite(points).all():
            self.reset()
            return points.astype(np.float32)
        if self._previous is None:
            self._previous, self._speed = points, np.zeros(points.shape[0])
            return points.astype(np.float32)
        velocity = (points - self._previous) * self.fps  # (P, 2) px/s
        speed = np.linalg.norm(velocity, axis=1)  # (P,)
        self._speed = self._speed + _alpha(self.d_cutoff, self.fps) * (speed - self._speed)
        alpha = _alpha(self.min_cutoff + self.beta * self._speed, self.fps)[:, None]  # (P, 1)
        self._previous = self._previous + alpha * (points - self._previous)
        return self._previous.astype(np.float32)


def smooth_sequence(
    landmarks: np.ndarray, fps: float, min_cutoff: float = 1.0, beta: float = 0.05, d_cutoff: float = 1.0
) -> np.ndarray:
    """landmarks: (N, 68, 2) float with NaN rows for missing frames -> smoothed, same shape, float32.

    The filter restarts after every missing frame; missing rows stay NaN.
    """
    landmarks = np.asarray(landmarks, dtype=np.float32)
    if landmarks.ndim != 3 or landmarks.shape[1:] != (NUM_LANDMARKS, 2):
        raise ValueError(f"landmarks must be (N, 68, 2), got {landmarks.shape}")
    one_euro = OneEuroFilter(fps, min_cutoff, beta, d_cutoff)
    return np.stack([one_euro(frame) for frame in landmarks]) if len(landmarks) else landmarks.copy()


def _mean_step(landmarks: np.ndarray, step) -> float:
    """Mean of ``step(moves)`` ((N-1, 68, 2) frame-to-frame moves -> (N-1,) pixels) over consecutive valid frames, in
    inter-ocular distances. landmarks: (N, 68, 2), NaN rows ignored (pairs touching a missing frame are skipped);
    NaN when fewer than two consecutive valid frames exist."""
    landmarks = np.asarray(landmarks, dtype=np.float64)
    if landmarks.ndim != 3 or landmarks.shape[1:] != (NUM_LANDMARKS, 2):
        raise ValueError(f"landmarks must be (N, 68, 2), got {landmarks.shape}")
    valid = np.isfinite(landmarks).all(axis=(1, 2))
    pairs = valid[1:] & valid[:-1]
    if not pairs.any():
        return float("nan")
    scale = 0.5 * (inter_ocular_distance(landmarks[1:]) + inter_ocular_distance(landmarks[:-1]))
    return float(np.mean(step(landmarks[1:] - landmarks[:-1])[pairs] / scale[pairs]))


def jitter(landmarks: np.ndarray) -> float:
    """Mean frame-to-frame landmark displacement in units of inter-ocular distance.

    landmarks: (N, 68, 2), NaN rows ignored (pairs touching a missing frame are skipped).
    NaN when fewer than two consecutive valid frames exist.
    """
    return _mean_step(landmarks, lambda moves: np.linalg.norm(moves, axis=2).mean(axis=1))


def part_jitter(landmarks: np.ndarray, part: slice) -> float:
    """Mean frame-to-frame motion of one part's points against the whole face's, in inter-ocular distances: how
    much a part (``landmarks.shape.ibug68`` ranges, e.g. the eyes 36-47) moves on its own, pops included.

    landmarks: (N, 68, 2), NaN rows ignored as in ``jitter``; NaN when fewer than two consecutive valid frames."""
    def own(moves: np.ndarray) -> np.ndarray:  # the part's motion less the face's
        return np.linalg.norm(moves[:, part] - moves.mean(axis=1, keepdims=True), axis=2).mean(axis=1)

    return _mean_step(landmarks, own)
