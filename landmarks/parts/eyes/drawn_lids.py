"""Shut lids drawn from the subject's own skin (issue 40: the eyes shut where the target's do, drawn, not blended).

A subject whose shots all show open eyes has no shut eye to warp: the warps squeeze the open eye, and the blend of
them still shows the white and the iris. On the validation people, real046 looking down with his lids shut was drawn
with his eyes open and white (self re-enactment, K = 8: 16 hold-outs below ``SHUT[1]``, eye region 16.2 dB). A
driver's frame has shut lids (``landmarks.parts.eyes.driver_lids``, ``--lids driver``), but they are another person's: its
crease, lashes and make-up. A landmark driver and self re-enactment have none. So where the target's lids shut, the
subject's own upper lid is drawn down over the eye (the default, ``--lids drawn``):

* how far: the target's aperture share against the subject's own lids at rest (``driver_lids.aperture_share``
  against the median lid gaps of the shots, ``shot_lid_gaps``), the ramp of the driver's lids (``SHUT``: from
  ``SHUT[1]`` down the lid comes down, at ``SHUT[0]`` and below it meets the lower lid);
* where: between the eye as the shots show it open (the target's lids at the shots' gaps, ``lids.set_lid_gaps``,
  grown by ``GROW`` for the lashes and the white's edge) and the drawn lid's margin, the target's upper lid lowered
  by that strength (a half-shut eye keeps the lower part of its opening);
* with what: the skin around it, filled in (``scene.fill_in``: the lid, the crease and the cheek below, lit as they
  are), darkened along the margin by a lash line (``LASH``, ``DARK``, a little above it: ``LIFT``), feathered
  (``FEATHER``) and faded in with the strength (``RAMP``).

Set on the validation people only (real046's 16 such hold-outs: eye region 16.2 -> 19.5 dB). The lash line's
darkness (``DARK``) was raised from 0.4 to 0.5 there later: at 0.4 real033's eyes at real046's shut ones showed a grey
slit that dlib read about half open (cross-identity, K = 8, 12 sequences: judged eye correlation 0.36 -> 0.40, gain
0.25 -> 0.33; self re-enactment's eye region 28.22 -> 28.23 dB, beyond the shots 19.70 -> 19.82 dB, SSIM 0.519 ->
0.563; 0.6 judged alike but cost 0.07 dB beyond the shots, 0.7 0.52 dB). numpy + OpenCV only: the torch and ONNX
runtimes share it.
"""

from __future__ import annotations

import cv2
import numpy as np

from landmarks.parts.eyes.driver_lids import EYES, SHUT, aperture_share
from landmarks.parts.eyes.lids import lid_gaps, set_lid_gaps
from landmarks.parts.part_window import polygon_mask
from landmarks.scene.compositing import fill_in
from landmarks.shape.measures import inter_ocular_distance

GROW = 0.04
"""The open eye's polygon is grown by this fraction of the eye distance: its lashes and the edge of its white."""
LASH = 0.06
"""The lash line along the drawn lid's margin: a Gaussian across it of 0.6 x this fraction of the eye distance."""
DARK = 0.5
"""The lash line darkens the filled-in skin by this share at its centre: to half the skin's grey, as dark as real lash
lines are (the darkest grey along the shots' upper lids over the cheek's: medians 0.37-0.60 on the validation
people). At 0.4 a shut eye read as a grey, half-open slit, to the eye and to dlib (module docstring)."""
FEATHER = 0.02
"""The drawn lid's edge is feathered by a Gaussian of this fraction of the eye distance."""
RAMP = 2.0
"""The drawn lid is laid in at this multiple of its strength (at most wholly): wholly from half way down."""
REACH = 0.5
"""Each eye's patch: its corners' midpoint +- this fraction of the eye distance."""
LIFT = 0.5
"""The lash line's middle sits this many of its sigmas above the margin, on the lid: what shows under a half-shut
lid keeps more of its light."""


def shot_lid_gaps(shot_landmarks: np.ndarray) -> np.ndarray:
    """The subject's lids at rest: the median ``lids.lid_gaps`` of its shots. (K, 68, 2) -> (2,) float64."""
    gaps = np.array([lid_gaps(points) for points in np.asarray(shot_landmarks, np.float64)])
    return np.nanmedian(gaps, axis=0) if np.isfinite(gaps).any() else np.full(2, np.nan)


def lid_strength(landmarks: np.ndarray, reference_gaps: np.ndarray) -> float:
    """How far to draw the lids down, in [0, 1]: none from an aperture share of ``SHUT[1]`` against
    ``reference_gaps`` (the subject's, ``shot_lid_gaps``), wholly from ``SHUT[0]`` down (0 where not finite)."""
    share = aperture_share(landmarks, reference_gaps)
    return float(np.clip((SHUT[1] - share) / (SHUT[1] - SHUT[0]), 0.0, 1.0)) if np.isfinite(share) else 0.0


def lash_line(points: np.ndarray, sigma: float, shape: tuple[int, int]) -> np.ndarray:
    """exp(-d^2 / 2 sigma^2) of each pixel's distance d to the polyline ``points`` (N, 2) (pixel centres at
    integers) -> (H, W) float32 in [0, 1]."""
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    nearest = np.full(shape, np.inf)
    for a, b in zip(points[:-1], points[1:]):
        d = b - a
        t = np.clip(((xs - a[0]) * d[0] + (ys - a[1]) * d[1]) / max(float(d @ d), 1e-12), 0.0, 1.0)
        nearest = np.minimum(nearest, (xs - a[0] - t * d[0]) ** 2 + (ys - a[1] - t * d[1]) ** 2)
    return np.exp(-nearest / (2.0 * sigma * sigma)).astype(np.float32)


def lid_normal(eye: np.ndarray) -> np.ndarray:
    """The unit normal of an eye's corner line toward its lower lid. eye: (6, 2), corners first and fourth."""
    along = eye[3] - eye[0]
    normal = np.array([-along[1], along[0]]) / max(float(np.linalg.norm(along)), 1e-12)
    return normal if normal @ (eye[[4, 5]].mean(axis=0) - eye[[0, 3]].mean(axis=0)) >= 0 else -normal


def draw_lids(image: np.ndarray, landmarks: np.ndarray, reference_gaps: np.ndarray,
              which: tuple[bool, bool] = (True, True)) -> np.ndarray:
    """The subject's upper lids drawn down over ``image`` where ``landmarks`` shut them (module docstring).

    image: (H, W, 3) uint8 RGB, the synthesis; landmarks: (68, 2) its target landmarks in its pixels;
    reference_gaps: (2,) the subject's lids at rest (``shot_lid_gaps``); which: the eyes drawn (image left first)
    -> (H, W, 3) uint8 (``image`` itself when nothing shuts)."""
    points = np.asarray(landmarks, np.float64)
    strength = lid_strength(points, reference_gaps)
    if strength <= 0.0 or not any(which):
        return image
    gaps = lid_gaps(points)
    opened = set_lid_gaps(points, np.fmax(np.asarray(reference_gaps, np.float64), gaps))
    margin = set_lid_gaps(points, gaps * (1.0 - strength))
    scale = inter_ocular_distance(points[None])[0]
    alpha = min(1.0, RAMP * strength)
    out = image.astype(np.float32)
    height, width = image.shape[:2]
    grow = max(1, round(GROW * scale))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))
    for eye, drawn in zip(EYES, which):
        if not drawn:
            continue
        centre = (points[eye][0] + points[eye][3]) / 2
        x0, y0 = (int(max(0, np.floor(c - REACH * scale))) for c in centre)
        x1, y1 = (int(min(side, np.ceil(c + REACH * scale))) for c, side in zip(centre, (width, height)))
        if x1 - x0 < 2 or y1 - y0 < 2 or not np.isfinite(opened[eye]).all():
            continue
        offset = np.array([x0, y0], np.float64)
        shape = (y1 - y0, x1 - x0)
        hole = cv2.dilate(polygon_mask(opened[eye] - offset, shape), disc)
        hole *= 1.0 - polygon_mask(margin[eye] - offset, shape)  # below the drawn margin the eye stays open
        patch = out[y0:y1, x0:x1]
        filled = fill_in(patch, 1.0 - hole)
        sigma = max(0.5, 0.6 * LASH * scale)
        lid = margin[eye][[0, 1, 2, 3]] - offset  # outer corner, the upper lid's two points, inner corner
        lid[1:3] -= LIFT * sigma * lid_normal(points[eye])  # on the lid's side of its margin
        line = lash_line(lid, sigma, shape)
        filled *= 1.0 - DARK * line[..., None]
        weight = cv2.GaussianBlur(np.maximum(hole, line), (0, 0), max(0.5, FEATHER * scale)) * alpha
        out[y0:y1, x0:x1] = patch + (filled - patch) * weight[..., None]
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)
