"""Shut eyes from the driver's own frame (issue 40: the eyes shut at the driver's blink).

A subject whose shots all show open eyes has no shut eye to warp. Lowering the warped lids (``landmarks.parts.eyes.lids``)
squeezes the open eye into a slit that still shows the iris and the white: on the validation people, a driver
who looks down with his lids nearly shut (real046) left real033's blue irises wide open, and dlib's 68 points read
the output's lids at a fraction of the driver's motion. The driver's frame shows the shut lids: skin, crease and
lash line at this very moment. So where the driver's eyes shut, its eye region is laid over the synthesis:

* ``cut_driver_eyes``: the driver frame around its eyes (``DriverEyes``), cut on the tracking thread, with how
  shut they are against the driver's own lids at rest (``shut_strength``: from the share ``SHUT[1]`` of its
  aperture none, from ``SHUT[0]`` on wholly; the aperture runs from its closed gap, ``lids.closed_gaps``, to
  its reference gap, ``lids.LidReference``), and less as the driver's head turns (``TURN``);
* ``paste_eyes``: per eye, the patch mapped onto the target by the similarity that takes the driver's eye corners
  onto the target's (each target pixel reads the patch there, bicubic), lit as the target is
  (``landmarks.parts.lay_in.match_light``, against a skin ring around the region, with the whole colour cast and no fading:
  skin laid on skin; the interior's half cast, fading toward the highlights, left real036's shut lids lavender
  under real046's), and laid inside an ellipse over the eye (``REGION``), feathered by ``FEATHER`` eye widths.

An open eye is left as it is: the subject keeps its own eyes, irises and gaze, and takes the driver's lids only
where they shut, as a blink passes in a few frames. What this gives the subject is the driver's shut lids, lit as
the subject's face (MODEL_CARD.md says so). numpy + OpenCV only: the torch and ONNX runtimes share it.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from landmarks.parts.lay_in import ellipse_mask
from landmarks.parts.eyes.lids import closed_gaps, lid_gaps
from landmarks.parts.mouth.interior import TURN, cut_around
from landmarks.shape.measures import finite_points
from landmarks.parts.lay_in import match_light
from landmarks.motion.head_pose import estimate_head_pose
from landmarks.shape.measures import inter_ocular_distance

EYES = (slice(36, 42), slice(42, 48))
"""Each eye's 6 of the 68 points: the outer corner first, the inner corner fourth."""
SHUT = (0.25, 0.5)
"""The driver's aperture share (its lid gap less its closed gap, over its reference gap less its closed gap, the
mean of both eyes): at the second or above its eyes are not laid in, at the first or below wholly. The mesh's lids
never meet: real046's shut eyes read at 0.14-0.4, his open ones at 0.8-1.2 (the validation people)."""
REACH = 0.35
"""The driver's patch: its eyes' box grown by this fraction of its eye distance (room for the region and ring)."""
REGION = (0.7, 0.45)
"""The ellipse laid in over each eye: semi-axes along and across the corner line, in eye widths (corner to
corner), centred between the corners: the lids, the crease and the lash line, not the brow."""
FEATHER = 0.12
"""The ellipse's edge is feathered by a Gaussian of this fraction of the eye's width."""
RING = 0.08
"""The skin whose light is matched (``match_light``): the ellipse grown by this fraction of the eye distance."""


@dataclasses.dataclass(frozen=True)
class DriverEyes:
    """A driver frame's shut eyes, cut out for ``paste_eyes``."""

    patch: np.ndarray
    """(h, w, 3) uint8 RGB: the driver frame around its eyes."""
    corners: np.ndarray
    """(2, 2, 2) float64: each eye's outer and inner corner in the patch's pixels."""
    strength: float
    """How much of them to lay in, in (0, 1] (``shut_strength``)."""


def aperture_share(landmarks: np.ndarray, reference_gaps: np.ndarray) -> float:
    """How open the driver's eyes are against its own (``SHUT``): the mean over both eyes of (lid gap - closed gap)
    / (reference gap - closed gap). landmarks: (68, 2); reference_gaps: (2,) ``lids.lid_gaps`` at rest -> float
    (NaN when either is not finite or an eye's reference is no wider than its closed gap)."""
    reference = np.asarray(reference_gaps, np.float64)
    shut = closed_gaps(reference)
    with np.errstate(divide="ignore", invalid="ignore"):
        shares = (lid_gaps(landmarks) - shut) / np.where(reference > shut, reference - shut, np.nan)
    return float(np.mean(shares))


def shut_strength(landmarks: np.ndarray, reference_gaps: np.ndarray, yaw: float) -> float:
    """How much of the driver's eyes to lay in, in [0, 1]: none from an aperture share (``aperture_share``) of
    ``SHUT[1]``, wholly from ``SHUT[0]`` down, and less as its head turns from ``TURN[0]`` to ``TURN[1]`` degrees of
    ``yaw`` (none where the share or the yaw is not finite)."""
    share = aperture_share(landmarks, reference_gaps)
    if not (np.isfinite(share) and np.isfinite(yaw)):
        return 0.0
    shut = np.clip((SHUT[1] - share) / (SHUT[1] - SHUT[0]), 0.0, 1.0)
    facing = np.clip((TURN[1] - abs(yaw)) / (TURN[1] - TURN[0]), 0.0, 1.0)
    return float(shut * facing)


def cut_driver_eyes(frame: np.ndarray, landmarks: np.ndarray, reference_gaps: np.ndarray) -> DriverEyes | None:
    """The driver's shut eyes: frame (H, W, 3) uint8 RGB, its 68 points (frame pixels, as detected) and its lid
    gaps at rest (2,) (``lids.LidReference``) -> ``DriverEyes``, or None where they are not shut
    (``shut_strength`` 0, most frames: nothing is cut), the points are not finite or the box lies outside the frame."""
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(f"frame must be (H, W, 3) uint8, got {frame.shape} {frame.dtype}")
    points = finite_points(landmarks)
    if points is None:
        return None
    if not aperture_share(points, reference_gaps) < SHUT[1]:  # open (most frames): not even the head pose
        return None
    strength = shut_strength(points, reference_gaps, float(estimate_head_pose(points, frame.shape[:2])[0]))
    if strength <= 0:
        return None
    cut = cut_around(frame, points[36:48], REACH * float(inter_ocular_distance(points)))
    if cut is None:
        return None
    return DriverEyes(cut[0], np.stack([points[eye][[0, 3]] for eye in EYES]) - cut[1], strength)


def similarity(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The (2, 3) similarity (rotation, uniform scale, shift) that takes the two points ``source`` (2, 2) onto
    ``target`` (2, 2) exactly."""
    step = complex(*(target[1] - target[0])) / complex(*(source[1] - source[0]))
    linear = np.array([[step.real, -step.imag], [step.imag, step.real]])
    return np.hstack([linear, (target[0] - linear @ source[0])[:, None]])


def paste_eyes(image: np.ndarray, landmarks: np.ndarray, eyes: DriverEyes | None) -> np.ndarray:
    """``image`` (S, S, 3) uint8, the synthesis for the target's 68 points ``landmarks`` (its pixels), with the
    driver's shut eyes laid over its own (module docstring): a new array, or ``image`` itself when there are no
    ``eyes`` or the target's points are not finite."""
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
    points = finite_points(landmarks)
    if eyes is None or points is None or eyes.strength <= 0:
        return image
    ring = max(1, round(RING * float(inter_ocular_distance(points))))
    height, width = image.shape[:2]
    result = image.copy()
    for eye, driver_corners in zip(EYES, eyes.corners):
        corners = points[eye][[0, 3]]
        along = corners[1] - corners[0]
        eye_width = float(np.hypot(*along))
        if eye_width < 1.0:
            continue
        axes = (REGION[0] * eye_width, REGION[1] * eye_width)
        sigma = max(0.5, FEATHER * eye_width)
        margin = axes[0] + ring + 3 * sigma + 1
        centre = corners.mean(axis=0)
        x0, y0 = np.maximum(np.floor(centre - margin), 0).astype(int)
        x1, y1 = np.minimum(np.ceil(centre + margin) + 1, (width, height)).astype(int)
        if x1 - x0 < 2 or y1 - y0 < 2:
            continue
        box = (y1 - y0, x1 - x0)
        # each of the box's pixels reads the patch where the corners' similarity puts it
        warped = cv2.warpAffine(eyes.patch, similarity(corners - (x0, y0), driver_corners), (box[1], box[0]),
                                flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE
                                ).astype(np.float32)
        region = result[y0:y1, x0:x1].astype(np.float32)
        inside = ellipse_mask(centre - (x0, y0), axes, along / eye_width, box)
        warped = match_light(warped, region, inside > 0.5, ring, cast=1.0, fade=None)
        weight = (cv2.GaussianBlur(inside, (0, 0), sigma) * eyes.strength)[..., None]
        result[y0:y1, x0:x1] = np.clip(np.rint(weight * warped + (1.0 - weight) * region), 0, 255).astype(np.uint8)
    return result
