"""The irises: found by MediaPipe's iris net, carried as a gaze, drawn from one shot (issue 40: one iris, where the
driver looks).

A blend of warped shots whose irises sit in different places shows two irises, or a smudge between them, and none
of them looks where the driver looks. Here the gaze is measured apart from the 68 points and the eye is drawn with
one iris:

1. **Found** (``find_irises``): the iris net (``landmarks.detect.mediapipe_mesh``'s, on the same 64x64 eye squares, levelled on each
   eye's corners of the 68 points) gives each iris' centre and radius and the lid gap of its own eye contour. The
   mesh tracker runs the same net on the same eyes and keeps what it found (``tracker.irises``), so a tracked
   driver costs nothing more.
2. **Carried** (``gaze_offsets``): the centre in the eye's own frame (from its corners' midpoint, along and across
   the corner line), in eye widths: a gaze that moves onto any face, whatever its size or roll. An eye closing
   (its gap below ``CLOSED`` of its gap when open) has none.
3. **Drawn** (``draw_irises``): in the synthesis, inside the target's eye aperture (the 68 points' lid polygon),
   where the synthesis shows the eye's white (``SCLERA``), one iris, cut from the subject's own shot with the most
   open eyes (``IrisDonor``), is laid at the target's eye centre plus the gaze, sized by the eye's width and
   clipped by the lids, with a soft edge; another iris of the blend, a dark blob away from it (where the shots
   looked elsewhere), is filled from the white around it (``cv2.inpaint``). The rest of the eye (the lash line,
   the lids' shadow) stays the blend's: filling every dark pixel inside the lids cost the validation people's eye
   regions 1.2 dB.

Numpy and OpenCV only (the inference core's rule); the iris net runs on onnxruntime.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from landmarks.shape.measures import EYE_RINGS, EYES, eye_apertures, eye_axes
from landmarks.parts.part_window import polygon_mask

PATCH = 24
"""Side of a donor iris patch in pixels; it spans ``PATCH_SPAN`` iris radii."""
PATCH_SPAN = 2.6
MIN_APERTURE = 0.12
"""A target eye whose lid gap (its 68 points') is below this fraction of its width: nothing is drawn in it."""
CLOSED = 0.8
"""A driver's eye whose lid gap by the iris net is below this fraction of its gap when open is closing: no gaze (the
net's lids close about a third at a blink: 0.19-0.22 of the eye's width against 0.28-0.32 open, validation people)."""
EDGE = 0.9
"""Soft edge of the drawn iris, in pixels of the target."""
WHITE_QUANTILE = 0.85
"""An eye's white: this quantile of the grey levels inside its lid polygon."""
DARK = 0.8
"""Inside the lids, pixels darker than this fraction of the white may be another iris of the blend (``_ghosts``)."""
IRIS_RAMP = 0.25
"""A donor pixel is laid fully where it is this fraction of its eye's white darker than the white, not at all where
it is as bright: the patch's ring of lid or skin around the iris stays out."""
DONOR_DARK = 0.7
"""A donor's iris: its centre at most this fraction of its eye's white (``_looks_like_an_iris``)."""
SCLERA = 1.1
"""An eye is drawn only where the synthesis shows its white: the bright of its lids' inside (``WHITE_QUANTILE``) at
least this many times the skin around it. A blend that draws the eye shut or narrow has none, and an iris drawn
there is a dark spot on the lid."""
GHOST_AREA = 0.3
"""A dark blob inside the lids, outside the drawn iris, is another iris when at least this share of an iris' area..."""
GHOST_HEIGHT = 0.8
"""... and at least this share of its radius tall."""


def find_irises(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Each eye's iris in ``image`` ((H, W, 3) uint8 RGB) with 68 points ``landmarks`` in its pixels -> (2, 4)
    float64 [x, y, radius, aperture]: the iris in those pixels and the eye's lid gap over its width, both by the iris
    net, image-left eye first; NaN rows where the points are not finite or an eye has no width. The second eye runs
    on the mesh's eye thread (``landmarks.detect.mediapipe_mesh``) while this one runs the first: about 3 ms for both on 2 cores."""
    from landmarks.detect.mediapipe_mesh import eye_thread

    points = np.asarray(landmarks, np.float64)
    if points.shape != (68, 2) or not np.isfinite(points).all():
        return np.full((2, 4), np.nan)
    second = eye_thread().submit(_find_iris, image, points, 1)
    return np.stack([_find_iris(image, points, 0), second.result()])


def _find_iris(image: np.ndarray, points: np.ndarray, eye: int) -> np.ndarray:
    """``find_irises``' row for one eye (``landmarks.detect.mediapipe_mesh.eye_iris``), on this thread's iris net session."""
    from landmarks.detect.mediapipe_mesh import EYE_ROI_SCALE, Region, eye_input, eye_iris, iris_outputs

    centre, axis, width = eye_axes(points, eye)
    if width < 1.0:
        return np.full(4, np.nan)
    region = Region((float(centre[0]), float(centre[1])), width * EYE_ROI_SCALE, float(np.arctan2(axis[1], axis[0])))
    mirrored = EYES[eye][2]
    return eye_iris(*iris_outputs(eye_input(image, region, mirrored)), region, mirrored)


def gaze_offsets(irises: np.ndarray, landmarks: np.ndarray, open_apertures: np.ndarray | None = None) -> np.ndarray:
    """``find_irises``' (2, 4) -> (2, 2) float64: each iris centre from its eye's centre, [along the corner line,
    across it (down)], in eye widths; NaN where not found, or where the eye is closing: its aperture below
    ``CLOSED`` x ``open_apertures`` ((2,): that eye's aperture when open, e.g. the median over the person's frames;
    at a blink the net still places an iris, which no one sees, and its lids meet less than the real ones)."""
    offsets = np.full((2, 2), np.nan)
    points = np.asarray(landmarks, np.float64)
    for eye in range(2):
        if not np.isfinite(irises[eye, :3]).all():
            continue
        if open_apertures is not None and not irises[eye, 3] >= CLOSED * open_apertures[eye]:
            continue
        centre, axis, width = eye_axes(points, eye)
        if width < 1.0:
            continue
        delta = irises[eye, :2] - centre
        offsets[eye] = (delta @ axis / width, delta @ np.array([-axis[1], axis[0]]) / width)
    return offsets


@dataclasses.dataclass(frozen=True)
class IrisDonor:
    """One shot's irises to draw with: per eye (image left first) a (PATCH, PATCH, 3) uint8 patch centred on the
    iris, ``PATCH_SPAN`` radii wide, the iris radius in that eye's widths, and the grey level of that eye's white
    (its lighting, matched where the iris is drawn); ``shot``: which shot gave them."""

    patches: np.ndarray
    radii: np.ndarray
    whites: np.ndarray
    shot: int


def iris_donor(frames: np.ndarray, landmarks: np.ndarray, found: np.ndarray | None = None) -> IrisDonor | None:
    """The irises of the shot whose eyes are most open (both found, both dark against their eye's white):
    frames (K, S, S, 3) uint8, landmarks (K, 68, 2) in their pixels -> ``IrisDonor``, or None when no shot has
    both. found: the shots' ``find_irises`` (K, 2, 4), when already at hand."""
    order = np.argsort(-np.array([eye_apertures(points).min() for points in landmarks]), kind="stable")
    for shot in order:
        irises = find_irises(frames[shot], landmarks[shot]) if found is None else found[shot]
        if not np.isfinite(irises).all():
            continue
        patches, radii, whites = [], [], []
        for eye in range(2):
            whites.append(_white(frames[shot], landmarks[shot], eye))
            x, y, radius = irises[eye, :3]
            scale = PATCH / (PATCH_SPAN * radius)  # donor pixels -> patch pixels, iris centred
            matrix = np.array([[scale, 0.0, PATCH / 2 - 0.5 - scale * x], [0.0, scale, PATCH / 2 - 0.5 - scale * y]])
            patches.append(cv2.warpAffine(frames[shot], matrix, (PATCH, PATCH), flags=cv2.INTER_AREA if scale < 1
                                          else cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
            radii.append(radius / eye_axes(landmarks[shot], eye)[2])
        if all(_looks_like_an_iris(patch, white) for patch, white in zip(patches, whites)):
            return IrisDonor(np.stack(patches), np.array(radii), np.array(whites), int(shot))
    return None


def _looks_like_an_iris(patch: np.ndarray, white: float) -> bool:
    """A donor patch whose centre (the inner half of the iris) is darker than ``DONOR_DARK`` of its eye's white: on
    a blurred or lid-covered eye the net still places an iris, and that patch would be lid or skin."""
    grey = cv2.cvtColor(patch, cv2.COLOR_RGB2GRAY).astype(np.float32)
    middle = PATCH // 2
    reach = max(1, round(PATCH / PATCH_SPAN / 2))
    return bool(np.isfinite(white) and grey[middle - reach:middle + reach, middle - reach:middle + reach].mean()
                < DONOR_DARK * white)


def _white(image: np.ndarray, landmarks: np.ndarray, eye: int) -> float:
    """The grey level of eye ``eye``'s white: the ``WHITE_QUANTILE`` of the grey inside its lid polygon."""
    points = np.asarray(landmarks, np.float64)[list(EYE_RINGS[eye])]
    x0, y0 = np.maximum(np.floor(points.min(axis=0)).astype(int) - 1, 0)
    x1, y1 = np.ceil(points.max(axis=0)).astype(int) + 2
    box = image[y0:y1, x0:x1]
    if box.size == 0:
        return math.nan
    inside = polygon_mask(points - (x0, y0), box.shape[:2]) > 0.5
    return _white_level(cv2.cvtColor(np.ascontiguousarray(box), cv2.COLOR_RGB2GRAY), inside)


def _white_level(grey: np.ndarray, inside: np.ndarray) -> float:
    """The ``WHITE_QUANTILE`` of ``grey`` inside the lids (``inside``, bool); NaN with fewer than 4 pixels there."""
    return float(np.quantile(grey[inside], WHITE_QUANTILE)) if inside.sum() >= 4 else math.nan


def retarget_gaze(driver: np.ndarray, driver_reference: np.ndarray, source: np.ndarray) -> np.ndarray:
    """Relative gaze: the source's own (its anchor shot's ``gaze_offsets``, (2, 2)) moved by the driver's since its
    reference frame: driver (T, 2, 2) or (2, 2) -> the same shape, float64. Where the reference or the source has
    no gaze (NaN), the driver's own (absolute) offsets are kept."""
    driver = np.asarray(driver, np.float64)
    shift = np.asarray(source, np.float64) - np.asarray(driver_reference, np.float64)
    return driver + np.where(np.isfinite(shift), shift, 0.0)


def _skin(grey: np.ndarray, aperture: np.ndarray) -> float:
    """The median grey of the skin just around an eye: a ring 2-5 pixels outside its lid polygon (``aperture``)."""
    lids = (aperture > 0.05).astype(np.uint8)
    ring = cv2.dilate(lids, np.ones((11, 11), np.uint8)) & ~cv2.dilate(lids, np.ones((5, 5), np.uint8)).astype(bool)
    return float(np.median(grey[ring.astype(bool)])) if ring.any() else 0.0


def _ghosts(grey: np.ndarray, inside: np.ndarray, white: float, iris: np.ndarray, radius: float) -> np.ndarray:
    """The blend's other irises in an eye's box, outside the drawn one's disc (``iris``, bool, grown a little):
    dark blobs (below ``DARK`` x ``white``) inside the lids and away from the lid line (one pixel in) that are at
    least ``GHOST_AREA`` of an iris' area and ``GHOST_HEIGHT`` of its radius tall -> bool mask. The lash line and
    the lids' shadow (thin, along the lids) stay."""
    core = cv2.erode(inside.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    dark = ((grey < DARK * white) & core & ~iris).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(dark, connectivity=8)
    keep = [label for label in range(1, count) if stats[label, cv2.CC_STAT_AREA] >= GHOST_AREA * np.pi * radius ** 2
            and stats[label, cv2.CC_STAT_HEIGHT] >= GHOST_HEIGHT * radius]
    return np.isin(labels, keep) if keep else np.zeros(grey.shape, bool)


def draw_irises(image: np.ndarray, landmarks: np.ndarray, offsets: np.ndarray, donor: IrisDonor) -> np.ndarray:
    """``image`` (C, C, 3) uint8 with one iris per open eye (module docstring, step 3): landmarks (68, 2) in its
    pixels, offsets (2, 2) ``gaze_offsets`` (an eye with NaN, not found or closing, is left as it is) -> a new
    (C, C, 3) uint8 image; only the eyes' boxes change."""
    offsets = np.array(offsets, np.float64)
    points = np.asarray(landmarks, np.float64)
    result = image.copy()
    apertures = eye_apertures(points)
    height, width = image.shape[:2]
    for eye, ring in enumerate(EYE_RINGS):
        if apertures[eye] < MIN_APERTURE or not np.isfinite(offsets[eye]).all():
            continue
        centre, axis, eye_width = eye_axes(points, eye)
        across = np.array([-axis[1], axis[0]])
        radius = donor.radii[eye] * eye_width
        iris_centre = centre + offsets[eye, 0] * eye_width * axis + offsets[eye, 1] * eye_width * across
        lids = points[list(ring)]
        low = np.floor(np.minimum(lids.min(axis=0), iris_centre - radius) - 3).astype(int)
        high = np.ceil(np.maximum(lids.max(axis=0), iris_centre + radius) + 4).astype(int)
        x0, y0 = np.maximum(low, 0)
        x1, y1 = np.minimum(high, (width, height))
        if x1 - x0 < 3 or y1 - y0 < 3:
            continue
        box = result[y0:y1, x0:x1]
        shape = box.shape[:2]
        aperture = polygon_mask(lids - (x0, y0), shape)
        grey = cv2.cvtColor(box, cv2.COLOR_RGB2GRAY).astype(np.float32)
        inside = aperture > 0.5
        white = _white_level(grey, inside)
        if not np.isfinite(white):
            continue
        if white < SCLERA * _skin(grey, aperture):  # the synthesis shows this eye shut: an iris would sit on the lid
            continue
        local = iris_centre - (x0, y0)
        ys, xs = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float32)
        distance = np.hypot(xs - local[0], ys - local[1])
        disc = np.clip((radius - distance) / EDGE + 0.5, 0.0, 1.0)
        # another iris of the blend, away from this one (where the shots looked elsewhere), filled from the white
        ghosts = _ghosts(grey, inside, white, distance < radius + 1.5, radius)
        clean = cv2.inpaint(box, cv2.dilate(ghosts.astype(np.uint8), np.ones((3, 3), np.uint8)), 2,
                            cv2.INPAINT_TELEA) if ghosts.any() else box
        # one iris, the donor's, scaled and placed (the donor's roll is undone: its patch is upright in the shot)
        scale = PATCH / (PATCH_SPAN * radius)  # target pixels -> patch pixels
        matrix = np.array([[scale, 0.0, PATCH / 2 - 0.5 - scale * local[0]], [0.0, scale, PATCH / 2 - 0.5 - scale * local[1]]])
        iris = cv2.warpAffine(donor.patches[eye], matrix, (shape[1], shape[0]), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REPLICATE).astype(np.float32)
        darkness = np.ones(shape, np.float32)
        if np.isfinite(donor.whites[eye]) and donor.whites[eye] > 0:
            # only the donor's iris itself: its pixels darker than its eye's white (not the lid or skin around it)
            darkness = np.clip((donor.whites[eye] - iris.mean(axis=2)) / (IRIS_RAMP * donor.whites[eye]), 0.0, 1.0)
            iris = iris * float(np.clip(white / donor.whites[eye], 0.8, 1.25))  # the donor's lighting to the target's
        alpha = (disc * aperture * darkness)[..., None]
        eye_box = alpha * iris + (1.0 - alpha) * clean.astype(np.float32)
        # only inside the aperture (soft at the lids) does the drawn eye replace the synthesis
        keep = aperture[..., None]
        result[y0:y1, x0:x1] = np.clip(np.rint(keep * eye_box + (1.0 - keep) * box.astype(np.float32)), 0, 255).astype(np.uint8)
    return result
