"""The landmark image: 68 points rasterised as coloured polylines, one colour per face part.

LSR conditions its layout and image generators on this picture of the driving landmarks
(thesis §4.3, §4.6; the input representation is taken over from FSTH). The drawing here
reproduces the official pre-processing (``NNNNN_contour.png`` of the LSR release), which we
measured on its 224x224 images (see ``tests/landmarks/shape/test_raster.py``):

* colours are matplotlib's named colours: jaw ``green`` (0,128,0), brows ``orange`` (255,165,0),
  nose bridge and base ``blue`` (0,0,255), eyes ``red`` (255,0,0), outer lips ``purple``
  (128,0,128), inner lips ``pink`` (255,192,203); drawn in that order on black;
* every part is an OPEN polyline (no ink on the 41->36, 47->42, 59->48 or 67->60 segments),
  with round joins and projecting (square) end caps;
* the stroke is 2 pt at 100 dpi = 2.78 px wide at 224 px (measured ink area / polyline length:
  2.76 px on the jaw), anti-aliased. We scale it with the image: ``2.78 * min(H, W) / 224``.

Points are ``(x, y)`` pixel coordinates, integer values at pixel centres (dlib / OpenCV).

Implementation: OpenCV's thick ``polylines`` only offers a few widths (its thickness 2 draws
3.4 px, 3 draws 5.4 px), so a stroke is built from one anti-aliased convex quad per segment
plus a disc per joint, drawn with sub-pixel precision (``shift``). All geometry is vectorised
in numpy; only the cv2 calls loop (about 0.2 ms at 256x256).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from landmarks.shape.ibug68 import NUM_LANDMARKS, PART_NAMES, PARTS

# part name -> RGB colour of the official landmark image (matplotlib named colours)
PART_COLORS: dict[str, tuple[int, int, int]] = {
    "jaw": (0, 128, 0),  # green
    "brow_left": (255, 165, 0),  # orange
    "brow_right": (255, 165, 0),
    "nose_bridge": (0, 0, 255),  # blue
    "nose_base": (0, 0, 255),
    "eye_left": (255, 0, 0),  # red
    "eye_right": (255, 0, 0),
    "lips_outer": (128, 0, 128),  # purple
    "lips_inner": (255, 192, 203),  # pink
}

REFERENCE_SIZE = 224  # side of the official landmark images
REFERENCE_STROKE_PX = 2.0 * 100.0 / 72.0  # matplotlib lw=2 pt at dpi=100 = 2.78 px at 224 px

# OpenCV's anti-aliased fill spreads every edge by ~0.68 px, so a quad of geometric width w
# inks an area of (w + 1.36) px per unit length (measured for w >= 1 over 7 angles); we
# subtract it so that ``thickness`` is the true ink width, as in matplotlib.
_CV_AA_SPREAD_PX = 1.36
_SHIFT = 4  # sub-pixel bits for cv2 drawing: 1/16 px precision
_ONE = 1 << _SHIFT


def default_thickness(size: int | tuple[int, int]) -> float:
    """Ink width in pixels used for an image of ``size``: 2.78 px per 224 px of the short side."""
    height, width = _check_size(size)
    return REFERENCE_STROKE_PX * min(height, width) / REFERENCE_SIZE


@dataclass(frozen=True)
class _StrokePlan:
    """Index arrays for drawing all parts at once (precomputed once per ``close_contours``)."""

    seg_start: np.ndarray  # (S,) int: first point of each segment
    seg_end: np.ndarray  # (S,) int: second point of each segment
    cap_start: np.ndarray  # (S,) bool: segment starts an open polyline (projecting cap)
    cap_end: np.ndarray  # (S,) bool: segment ends an open polyline
    joints: np.ndarray  # (J,) int: points where two segments meet (round join)
    seg_bounds: tuple[tuple[int, int], ...]  # per part: [lo, hi) into the segment arrays
    joint_bounds: tuple[tuple[int, int], ...]  # per part: [lo, hi) into ``joints``


@lru_cache(maxsize=2)
def _stroke_plan(close_contours: bool) -> _StrokePlan:
    seg_start, seg_end, cap_start, cap_end, joints = [], [], [], [], []
    seg_bounds, joint_bounds = [], []
    for name in PART_NAMES:
        first, stop, closed_in_scheme = PARTS[name]
        closed = close_contours and closed_in_scheme
        points = list(range(first, stop))
        starts = points if closed else points[:-1]
        ends = points[1:] + points[:1] if closed else points[1:]
        lo = len(seg_start)
        seg_start += starts
        seg_end += ends
        cap_start += [not closed and i == 0 for i in range(len(starts))]
        cap_end += [not closed and i == len(starts) - 1 for i in range(len(starts))]
        seg_bounds.append((lo, len(seg_start)))
        jlo = len(joints)
        joints += points if closed else points[1:-1]
        joint_bounds.append((jlo, len(joints)))
    as_int = lambda values: np.asarray(values, dtype=np.intp)  # noqa: E731
    return _StrokePlan(
        as_int(seg_start), as_int(seg_end), np.asarray(cap_start), np.asarray(cap_end),
        as_int(joints), tuple(seg_bounds), tuple(joint_bounds),
    )


def _check_size(size: int | tuple[int, int]) -> tuple[int, int]:
    if isinstance(size, (int, np.integer)):
        height = width = int(size)
    else:
        try:
            height, width = (int(v) for v in size)
        except (TypeError, ValueError):
            raise ValueError(f"size must be an int or a (height, width) pair, got {size!r}") from None
    if height < 1 or width < 1:
        raise ValueError(f"size must be positive, got (height, width) = ({height}, {width})")
    return height, width


def _check_landmarks(landmarks: np.ndarray) -> np.ndarray:
    points = np.asarray(landmarks)
    if points.shape != (NUM_LANDMARKS, 2):
        raise ValueError(
            f"landmarks must have shape ({NUM_LANDMARKS}, 2) (x, y per iBUG-68 point), got {points.shape}"
        )
    if not np.issubdtype(points.dtype, np.number):
        raise ValueError(f"landmarks must be numeric, got dtype {points.dtype}")
    return points.astype(np.float64)


def _stroke_geometry(
    points: np.ndarray, thickness: float, plan: _StrokePlan, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, int]:
    """Fixed-point quads (S, 4, 2) int32, joint centres (J, 2) int32 and joint radius."""
    # Far-off points would overflow cv2's fixed point; nothing beyond a few image sizes is visible.
    limit = 8 * max(size)
    points = np.clip(points, -limit, limit)
    half_width = max(thickness - _CV_AA_SPREAD_PX, 0.0) / 2.0
    start, end = points[plan.seg_start], points[plan.seg_end]  # (S, 2) each
    direction = end - start
    length = np.linalg.norm(direction, axis=1, keepdims=True)  # (S, 1)
    unit = np.divide(direction, length, out=np.zeros_like(direction), where=length > 1e-9)
    normal = np.stack([-unit[:, 1], unit[:, 0]], axis=1) * half_width  # (S, 2)
    # Projecting caps (matplotlib's default for solid lines): extend open ends by half the width.
    start = start - unit * (half_width * plan.cap_start)[:, None]
    end = end + unit * (half_width * plan.cap_end)[:, None]
    quads = np.stack([start + normal, end + normal, end - normal, start - normal], axis=1)  # (S, 4, 2)
    quads_fixed = np.round(quads * _ONE).astype(np.int32)
    joints_fixed = np.round(points[plan.joints] * _ONE).astype(np.int32)  # (J, 2)
    return quads_fixed, joints_fixed, int(round(half_width * _ONE))


def _draw_part(canvas: np.ndarray, quads: np.ndarray, joints: np.ndarray, radius: int, color) -> None:
    # One call per segment: cv2.fillPoly with several polygons XORs their overlaps, which
    # would erase coinciding upper/lower inner-lip segments of a closed mouth.
    for quad in quads:
        cv2.fillConvexPoly(canvas, quad, color, cv2.LINE_AA, _SHIFT)
    if radius > 0:
        for x, y in joints.tolist():
            cv2.circle(canvas, (x, y), radius, color, -1, cv2.LINE_AA, _SHIFT)


def _prepare(landmarks, size, thickness, close_contours):
    height, width = _check_size(size)
    points = _check_landmarks(landmarks)
    if thickness is None:
        thickness = default_thickness((height, width))
    elif not (np.isfinite(thickness) and thickness > 0):
        raise ValueError(f"thickness must be a positive number of pixels, got {thickness!r}")
    if not np.isfinite(points).all():
        return (height, width), None  # a missing frame: nothing to draw
    plan = _stroke_plan(bool(close_contours))
    return (height, width), (plan, *_stroke_geometry(points, float(thickness), plan, (height, width)))


def draw_landmarks(
    landmarks: np.ndarray,
    size: int | tuple[int, int],
    *,
    thickness: float | None = None,
    close_contours: bool = False,
) -> np.ndarray:
    """Rasterise 68 landmarks as the official coloured landmark image.

    landmarks: (68, 2) float (x, y) pixel coordinates in the output image. Any NaN/inf means a
        missing frame (no face found) and gives an all-black image instead of an error.
    size: output side ``S`` or ``(H, W)``.
    thickness: ink width in pixels; default ``2.78 * min(H, W) / 224`` (the reference width,
        scaled). Widths below ~1.5 px all draw about 1.5-1.7 px (the anti-aliasing footprint).
    close_contours: False (default) matches the reference: every part open. True closes the eyes
        and both lip contours (the ``closed`` flags of ``landmarks.shape.ibug68.PARTS``).
    returns: (H, W, 3) uint8 RGB, black background, parts in ``PART_NAMES`` order (later on top).
    raises: ValueError for a wrong landmark shape, size or thickness.
    """
    (height, width), geometry = _prepare(landmarks, size, thickness, close_contours)
    canvas = np.zeros((height, width, 3), np.uint8)
    if geometry is None:
        return canvas
    plan, quads, joints, radius = geometry
    for name, (lo, hi), (jlo, jhi) in zip(PART_NAMES, plan.seg_bounds, plan.joint_bounds):
        _draw_part(canvas, quads[lo:hi], joints[jlo:jhi], radius, PART_COLORS[name])
    return canvas


def landmark_channels(
    landmarks: np.ndarray,
    size: int | tuple[int, int],
    *,
    thickness: float | None = None,
    close_contours: bool = False,
) -> np.ndarray:
    """The same drawing as ``draw_landmarks``, one channel per part instead of colours.

    landmarks, size, thickness, close_contours: as in ``draw_landmarks``.
    returns: (P, H, W) float32 in [0, 1], P = 9 channels in ``PART_NAMES`` order; channel p is
        the anti-aliased coverage of part p alone (parts do not occlude each other here).
        All zeros for a missing (NaN) frame.
    """
    (height, width), geometry = _prepare(landmarks, size, thickness, close_contours)
    channels = np.zeros((len(PART_NAMES), height, width), np.uint8)
    if geometry is not None:
        plan, quads, joints, radius = geometry
        for index, ((lo, hi), (jlo, jhi)) in enumerate(zip(plan.seg_bounds, plan.joint_bounds)):
            _draw_part(channels[index], quads[lo:hi], joints[jlo:jhi], radius, 255)
    return channels.astype(np.float32) * np.float32(1.0 / 255.0)
