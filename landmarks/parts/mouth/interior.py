"""The inside of an open mouth, from the driver's own frame (issue 40, item 3: a cavity and teeth as the driver
shows them).

Where the target opens its mouth wider than the subject's shots, every shot's warp stretches what is inside its
lips: closed lips, lipstick, a tongue, a row of teeth pulled into vertical stripes. The network and the nearest
shot's mouth (``landmarks.parts.mouth.nearest_mouth``) cannot draw what no shot shows. The driver's frame shows it: the dark
cavity, the teeth and the tongue at this very moment, in the lip shape the target was given (retargeting makes
the target's mouth as open as the driver's). So inside the target's inner lips the synthesis is replaced by the
driver's mouth interior:

* ``cut_driver_mouth``: the driver frame around its lips (``DriverMouth``), cut on the tracking thread;
* ``paste_interior``: that patch mapped onto the target by the affine map that best takes the target's 20 lip
  points onto the driver's (least squares; each target pixel reads the patch there, bicubic), lit as the target
  is (``match_light``: no more colourful than the skin around the target's lips, so a greyscale video takes a grey
  interior, then the brightness and, away from its highlights, half the colour cast of the target's nose against
  the driver's, ``nose_light``), and laid inside the target's inner-lip polygon, feathered by ``FEATHER`` eye
  distances, as far as both mouths are open and the driver faces the camera (``interior_strength``).

The lips stay the synthesis' (the subject's), and so does everything outside them. A closed mouth is left as it is.
What this gives the subject is the driver's teeth and tongue, not the subject's own (MODEL_CARD.md says so).
numpy + OpenCV only: the torch and ONNX runtimes and the web page (``deploy/web/src/interior.ts``) share it.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from landmarks.shape.measures import finite_points
from landmarks.parts.lay_in import match_light
from landmarks.shape.expression import mouth_opening
from landmarks.motion.head_pose import estimate_head_pose
from landmarks.shape.measures import inter_ocular_distance

LIPS = slice(48, 68)
"""The 20 lip points of the 68; of those, the first 12 are the outer lips, the last 8 the inner lips."""
OUTER, INNER = slice(0, 12), slice(12, 20)
OPEN = (0.02, 0.04)
"""Mouth openings (inner-lip gap / eye distance): below the first the interior is the synthesis', from the second
on wholly the driver's (the lesser of the target's and the driver's opening decides)."""
REACH = 0.35
"""The driver's patch: its lips' box grown by this fraction of its eye distance (room for ``RING``)."""
RING = 0.12
"""The skin whose brightness is matched: the target's outer-lip polygon grown by this fraction of its eye distance,
less the lips."""
FEATHER = 0.012
"""The inner-lip polygon's edge is feathered by a Gaussian of this fraction of the target's eye distance."""
NOSE = (27, 31, 32, 33, 34, 35)
"""The nose as a polygon of the 68 points (the top of its bridge, then its base): the skin whose light the interior
takes (``nose_light``). The skin ring around the lips is a beard's on a bearded face: a bearded driver's dark ring
brightened his teeth to a glare in a dim video (the FSTH sample's id00061 driving id00017: gain 1.30, the teeth
at 233-244 where the synthesis' brightest around the lips is 131-135)."""
TURN = (35.0, 50.0)
"""Degrees of the driver's head yaw: from the first the interior fades, at the second it is gone. A mouth seen from
the side shows its teeth edge-on; mapped onto a mouth seen from the front it drew a white blob (on the FSTH sample,
a driver at 47 degrees)."""
@dataclasses.dataclass(frozen=True)
class DriverMouth:
    """A driver frame's mouth, cut out for ``paste_interior``."""

    patch: np.ndarray
    """(h, w, 3) uint8 RGB: the driver frame around its lips."""
    lips: np.ndarray
    """(20, 2) float64: the driver's lip points (48-67 of the 68) in the patch's pixels."""
    opening: float
    """The driver's mouth opening (``landmarks.shape.expression.mouth_opening``)."""
    yaw: float = 0.0
    """The driver's head yaw in degrees (``landmarks.motion.head_pose.estimate_head_pose`` of its 68 points; NaN: not found)."""
    light: np.ndarray | None = None
    """(3,) float64: the driver's mean colour over its nose (``nose_light``); None: the skin ring around its lips."""


def cut_around(frame: np.ndarray, points: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The frame (H, W, 3) uint8 RGB around ``points`` (N, 2): their box grown by ``reach`` pixels, clipped to the
    frame -> (patch (h, w, 3) uint8, a copy; its top-left corner (2,) in the frame's pixels), or None when under 2
    pixels of the box lie in the frame. The callers check the frame."""
    x0, y0 = np.maximum(np.floor(points.min(axis=0) - reach), 0).astype(int)
    x1, y1 = np.minimum(np.ceil(points.max(axis=0) + reach) + 1, (frame.shape[1], frame.shape[0])).astype(int)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    return frame[y0:y1, x0:x1].copy(), np.array([x0, y0])


def cut_driver_mouth(frame: np.ndarray, landmarks: np.ndarray) -> DriverMouth | None:
    """The driver's mouth: frame (H, W, 3) uint8 RGB and its 68 points (frame pixels, as detected) ->
    ``DriverMouth``, or None when the points are not finite, the mouth is closed (below ``OPEN[0]``) or its box
    lies outside the frame."""
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(f"frame must be (H, W, 3) uint8, got {frame.shape} {frame.dtype}")
    points = finite_points(landmarks)
    if points is None:
        return None
    opening = float(mouth_opening(points))
    if not opening >= OPEN[0]:
        return None
    cut = cut_around(frame, points[LIPS], REACH * float(inter_ocular_distance(points)))
    if cut is None:
        return None
    yaw = float(estimate_head_pose(points, frame.shape[:2])[0])
    return DriverMouth(cut[0], points[LIPS] - cut[1], opening, yaw, nose_light(frame, points))


def nose_light(image: np.ndarray, points: np.ndarray) -> np.ndarray | None:
    """(3,) float64: the mean colour of ``image`` (H, W, 3) uint8 inside the nose polygon (``NOSE``) of the 68
    ``points`` (its pixels), or None where it covers no pixel."""
    nose = points[list(NOSE)]
    cut = cut_around(image, nose, 2.0)
    if cut is None:
        return None
    inside = _polygon(nose - cut[1], cut[0].shape[:2]) > 0.5
    return cut[0][inside].mean(axis=0, dtype=np.float64) if inside.any() else None


def interior_strength(landmarks: np.ndarray, mouth: DriverMouth) -> float:
    """How much of the driver's interior to lay in, in [0, 1]: the lesser of the target's opening (landmarks
    (68, 2)) and the driver's, from ``OPEN[0]`` (none) to ``OPEN[1]`` (wholly), and less as the driver's head turns
    from ``TURN[0]`` to ``TURN[1]`` degrees (none where its yaw is unknown)."""
    opening = min(float(mouth_opening(landmarks)), mouth.opening)
    if not (np.isfinite(opening) and np.isfinite(mouth.yaw)):
        return 0.0
    opened = np.clip((opening - OPEN[0]) / (OPEN[1] - OPEN[0]), 0.0, 1.0)
    facing = np.clip((TURN[1] - abs(mouth.yaw)) / (TURN[1] - TURN[0]), 0.0, 1.0)
    return float(opened * facing)


def lip_affine(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The (2, 3) affine map that takes the points ``source`` (N, 2) onto ``target`` (N, 2) in least squares."""
    design = np.hstack([source, np.ones((len(source), 1))])  # (N, 3)
    solution = np.linalg.lstsq(design, target, rcond=None)[0]  # (3, 2)
    return solution.T


def _polygon(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A filled polygon's coverage (h, w) float32 in [0, 1], anti-aliased."""
    mask = np.zeros(shape, np.uint8)
    cv2.fillPoly(mask, [np.round(points * 4).astype(np.int32)], 255, lineType=cv2.LINE_AA, shift=2)
    return mask.astype(np.float32) * (1.0 / 255.0)


def paste_interior(image: np.ndarray, landmarks: np.ndarray, mouth: DriverMouth | None) -> np.ndarray:
    """``image`` (S, S, 3) uint8, the synthesis for the target's 68 points ``landmarks`` (its pixels), with the
    driver's mouth interior inside the target's inner lips (module docstring): a new array, or ``image`` itself
    when there is no ``mouth``, the target's points are not finite or either mouth is closed."""
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
    points = finite_points(landmarks)
    strength = 0.0 if mouth is None or points is None else interior_strength(points, mouth)
    if strength <= 0:
        return image
    eyes = float(inter_ocular_distance(points))
    ring = max(1, round(RING * eyes))
    sigma = max(0.4, FEATHER * eyes)
    lips = points[LIPS]
    margin = ring + int(np.ceil(3 * sigma)) + 1
    height, width = image.shape[:2]
    x0, y0 = np.maximum(np.floor(lips.min(axis=0)) - margin, 0).astype(int)
    x1, y1 = np.minimum(np.ceil(lips.max(axis=0)) + margin + 1, (width, height)).astype(int)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return image
    box = (y1 - y0, x1 - x0)
    local = lips - (x0, y0)
    # each of the box's pixels reads the patch where the target-to-driver fit puts it (bicubic, as the web page does)
    warped = cv2.warpAffine(mouth.patch, lip_affine(local, mouth.lips), (box[1], box[0]),
                            flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE
                            ).astype(np.float32)
    region = image[y0:y1, x0:x1].astype(np.float32)
    target_light = nose_light(image, points) if mouth.light is not None else None
    lights = None if target_light is None else (target_light, mouth.light)
    warped = match_light(warped, region, _polygon(local[OUTER], box) > 0.5, ring, colourful=False, lights=lights)
    weight = cv2.GaussianBlur(_polygon(local[INNER], box), (0, 0), sigma) * strength
    result = image.copy()
    mixed = weight[..., None] * warped + (1.0 - weight[..., None]) * region
    result[y0:y1, x0:x1] = np.clip(np.rint(mixed), 0, 255).astype(np.uint8)
    return result
