"""Expression measures on 68 landmarks (mouth and eye opening) and the choice of a neutral anchor shot.

Openings are normalised by the inter-ocular distance (eye centre to eye centre, points 36-41 and 42-47), so
they compare across face sizes and people:

* mouth opening: mean vertical gap of the inner lips, |61-67|, |62-66|, |63-65| (iBUG, 0-based), / IOD;
* eye opening: mean lid gap of both eyes, |37-41|, |38-40|, |43-47|, |44-46|, / IOD.

Both work on any leading shape (..., 68, 2); NaN landmarks give NaN. The cross-identity metrics of ``lsr eval``
(``lsr.eval.cross``) and the anchor choice below use them.
"""

from __future__ import annotations

import numpy as np

from landmarks.shape.ibug68 import LEFT_EYE, NUM_LANDMARKS, RIGHT_EYE
from landmarks.shape.measures import inter_ocular_distance

INNER_LIP_PAIRS = ((61, 67), (62, 66), (63, 65))
EYE_LID_PAIRS = ((37, 41), (38, 40), (43, 47), (44, 46))
CLOSED_MOUTH = 0.05
"""Mouth opening below which a shot counts as closed-mouthed (about a third of a talking mouth's range)."""
BLINKING = 0.7
"""Eyes opened less than this share of a person's median opening count as closing (a blink, shut lids)."""


def _points(landmarks: np.ndarray) -> np.ndarray:
    points = np.asarray(landmarks, np.float64)
    if points.ndim < 2 or points.shape[-2:] != (NUM_LANDMARKS, 2):
        raise ValueError(f"landmarks must be (..., {NUM_LANDMARKS}, 2), got {np.shape(landmarks)}")
    return points


def _gap(points: np.ndarray, pairs: tuple[tuple[int, int], ...]) -> np.ndarray:
    first, second = zip(*pairs)
    return np.linalg.norm(points[..., list(first), :] - points[..., list(second), :], axis=-1).mean(-1)


def mouth_opening(landmarks: np.ndarray) -> np.ndarray:
    """Inner-lip gap / inter-ocular distance (module docstring): (..., 68, 2) -> (...) float64."""
    points = _points(landmarks)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _gap(points, INNER_LIP_PAIRS) / inter_ocular_distance(points)


def eye_opening(landmarks: np.ndarray) -> np.ndarray:
    """Mean eyelid gap of both eyes / inter-ocular distance: (..., 68, 2) -> (...) float64."""
    points = _points(landmarks)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _gap(points, EYE_LID_PAIRS) / inter_ocular_distance(points)


def pick_anchor(landmarks: np.ndarray, image_size: tuple[int, int]) -> int:
    """The most frontal shot with a closed mouth and open eyes: the scene a re-enactment is composited into.

    landmarks: (K, 68, 2) shots' landmarks (NaN rows never chosen unless all are); image_size: (H, W) of the
    frames they live in. Score (lower is better): head rotation hypot(yaw, pitch) / 10 degrees, plus the mouth
    opening above ``CLOSED_MOUTH`` in units of it, plus eyes opened less than ``BLINKING`` of the shots' median.
    """
    from landmarks.motion.head_pose import estimate_head_pose

    points = _points(landmarks)
    if points.ndim != 3 or len(points) == 0:
        raise ValueError(f"landmarks must be (K, 68, 2) with K >= 1, got {points.shape}")
    valid = np.isfinite(points).all(axis=(1, 2))
    if not valid.any():
        return 0
    mouths, eyes = mouth_opening(points), eye_opening(points)
    typical_eye = float(np.median(eyes[valid]))
    scores = np.full(len(points), np.inf)
    for index in np.flatnonzero(valid):
        yaw, pitch, _ = estimate_head_pose(points[index], image_size)
        rotation = np.hypot(yaw, pitch) / 10.0 if np.isfinite(yaw) else 10.0
        mouth = max(0.0, mouths[index] - CLOSED_MOUTH) / CLOSED_MOUTH
        eye = max(0.0, BLINKING * typical_eye - eyes[index]) / max(0.1 * typical_eye, 1e-6)
        scores[index] = rotation + mouth + eye
    return int(np.argmin(scores))


# How far each point moves when the jaw drops the lower inner lip by one unit (the rest of the face stays).
_JAW_DROP = {65: 1.0, 66: 1.0, 67: 1.0, 55: 1.0, 56: 1.0, 57: 1.0, 58: 1.0, 59: 1.0, 60: 0.5, 64: 0.5, 48: 0.4,
             54: 0.4, 6: 0.9, 7: 1.0, 8: 1.0, 9: 1.0, 10: 0.9, 5: 0.7, 11: 0.7, 4: 0.4, 12: 0.4, 3: 0.15, 13: 0.15}


def signed_mouth_gap(landmarks: np.ndarray, down: np.ndarray) -> np.ndarray:
    """Mean height of the lower inner lip below the upper one along ``down`` (unit (..., 2)), over the inter-ocular
    distance: (..., 68, 2) -> (...) float64. Negative: the lips cross (the lower one above the upper)."""
    points = _points(landmarks)
    upper, lower = zip(*INNER_LIP_PAIRS)
    gaps = ((points[..., list(lower), :] - points[..., list(upper), :]) * down[..., None, :]).sum(-1).mean(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return gaps / inter_ocular_distance(points)


def set_mouth_opening(landmarks: np.ndarray, opening: np.ndarray | float) -> np.ndarray:
    """Open or close a face's mouth to a given ``mouth_opening``, moving the lower lip and the jaw along the face's
    down direction (eyes to mouth) as a jaw drop does; the rest of the face stays. The lips never cross.

    First the lower lip is put ``opening`` below the upper one along the down direction (``signed_mouth_gap``: this
    also uncrosses lips that a relative retargeting crossed, where the distance-based opening would read a crossed
    mouth as open and push the lip the wrong way); then a few steps settle a slanted mouth's point distances, never
    lifting the lower lip above the upper one (a closed mouth whose lips are offset sideways stays at gap 0).

    landmarks: (..., 68, 2); opening: (...) or a float. Returns a new float64 array of the same shape.
    """
    points = _points(landmarks).copy()
    distance = inter_ocular_distance(points)
    target = np.maximum(np.broadcast_to(np.asarray(opening, np.float64), distance.shape), 0.0)
    eyes = (points[..., LEFT_EYE, :].mean(-2) + points[..., RIGHT_EYE, :].mean(-2)) / 2
    down = points[..., [48, 54], :].mean(-2) - eyes
    down = down / np.maximum(np.linalg.norm(down, axis=-1, keepdims=True), 1e-9)
    index, amounts = list(_JAW_DROP), np.asarray(list(_JAW_DROP.values()))[:, None]

    def drop(step: np.ndarray) -> None:  # step: (...) in inter-ocular distances, positive = open
        points[..., index, :] += amounts * (np.nan_to_num(step * distance)[..., None] * down)[..., None, :]

    drop(target - signed_mouth_gap(points, down))  # the lower inner lip moves by exactly the step: one step
    for _ in range(3):  # point distances, not heights: settle a slanted mouth, the gap kept >= 0
        drop(np.maximum(target - mouth_opening(points), -signed_mouth_gap(points, down)))
    return points
