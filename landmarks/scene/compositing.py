"""Composite a re-enacted face into a scene frame: the source's own background, body and hair (issue 23).

A frame is layers that move as they do in life; only the face is synthesised:

* **background and body**: the scene frame, unmoved;
* **head** (hair, ears, the skin around the face): the scene frame moved by the head's rigid motion (the
  similarity scene -> target on ``landmarks.motion.retarget_points.RIGID_INDEX``), which carries the hair, plus a regularised
  TPS (``landmarks.warp.tps.tps_grid_map``) that lands the scene's face outline, brows, nose and eye corners on the
  target's (the lips and eyelids do not count: they are expression). The warp fades smoothly to none at the
  edge of the head region (``head_weight``), so the neck stretches a little and the body never moves. One
  coherent layer: the hair is the scene's, never an average of disagreeing warps, so it cannot ghost, and the
  scene's own cheek and chin sit where the target's are, so none peeks out beside the new face. Given the
  scene's person matte (``SceneLayers``, issue 40's turn matte), only the person moves: the background inside
  the head region stays where it is (no wave at a turn), and what the moved head uncovers is the background
  filled in from around it (``background_plate``); and the head layer reaches further (``PERSON_SCALE``), moving
  the person rigidly down to the chin and fading only toward the body below it (``NECK_FADE``), so hair beyond
  the head ellipse moves with the head instead of folding where the motion fades;
* **face**: the synthesised crop inside the face mask (the hull of the target's landmarks, with the forehead),
  feathered, and colour-matched to the head layer along the seam (a smooth offset field measured just inside
  the face edge).

Sizes are fractions of the face's crop side ``s`` in frame pixels (the VoxCeleb2 framing of
``landmarks.align.crop_transform``), so the composite behaves the same for a 60-pixel face in a full-body
shot and for a close-up. Everything outside the head region is the scene's pixels, bit for bit.

numpy + OpenCV only (no torch): the torch and ONNX runtimes share it through ``lsr.core.engine``.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from landmarks.align import crop_transform, face_geometry, invert_affine, transform_landmarks
from landmarks.shape.ibug68 import NUM_LANDMARKS
from landmarks.motion.retarget_points import RIGID_INDEX, apply_similarity, similarity_procrustes
from landmarks.warp.tps import folded_fraction, tps_grid_map

# Head region (fractions of the crop side s), centred above the eyes/mouth midpoint; a VoxCeleb2 crop has the
# top of the hair about 0.35 s above that point and the chin about 0.22 s below it.
HEAD_CENTRE_UP = 0.08
HEAD_SEMI_AXES = (0.36, 0.46)  # (x, y): hair and ears inside, shoulders outside
HEAD_INNER = 0.7  # inside this fraction of the ellipse the head moves fully; it fades to none at its edge
FOREHEAD_LIFT = 0.3  # brows lifted by this fraction of the eye-to-mouth distance: the forehead is face
FACE_MARGIN = 0.02  # the face mask reaches this far outside the hull (covers the jaw line) ...
FACE_FEATHER = 0.05  # ... with a ramp this wide
COLOUR_BAND = 0.06  # colour offsets are measured in this band just inside the face hull ...
COLOUR_SIGMA = 0.12  # ... and spread smoothly with this Gaussian
COLOUR_LIMIT = 40.0  # grey levels: larger offsets are lighting the face itself, not a seam
STILL = 0.25  # pixels: a head motion smaller than this leaves the head layer untouched
HEAD_WARP_INDEX = [*range(0, 36), 36, 39, 42, 45]  # outline, brows, nose, eye corners: not the lips and lids
HEAD_GRID_CELLS = 48  # the head layer's field is made every side / 48 pixels (at least 4) and interpolated
PERSON_LEVEL = 0.1  # a matte above this is the person (hair's soft edge included): the plate fills it in ...
PERSON_REACH = 0.03  # ... and this far around it (fraction of the face side), where the matte's edge is unsure
PLATE_SIDE = 384  # the plate's fill is made at most this many pixels wide and high
PLATE_TRUST = 16.0
"""The plate's fill carries the background's nearest colours into the person's place (``fill_in``'s ``trust``):
with the plain push-pull (1) the far background's mean showed through as a darker or lighter ghost of the person,
a halo beside a head that moved (real046's grey shadow on a white wall). Chosen on the training and validation
people (``lsr bench plate``: one frame of each of the 60, a band 0.08 of the face side hidden just outside the
person and filled, its mean absolute error against the real background beside the head: 18.12 grey levels at 1,
16.13 at 2, 13.98 at 8, 13.46 at 16, 12.90 at 64); by eye 16 and 64 are alike and 1 leaves the ghost."""
MOVING = 1.0  # pixels: where the head layer moves this far or more, the matte parts person from background
PERSON_SCALE = 1.6  # with the matte, the head layer reaches this many times the head ellipse (hair beyond it) ...
PERSON_INNER = 0.8  # ... moving fully inside this fraction of it ...
NECK_FADE = 0.3  # ... and above the chin, fading to none this far below it (the neck stretches, the body stays)
INNER_RETRIES = (0.0, 0.15, 0.3)  # where the faded motion folds, the inner fraction is lowered by these in turn ...
EDGE_RAMP = 4.0  # ... and where it would show pixels from beyond a frame edge, it fades to none at that edge over
# this many times its largest reach beyond it (a ramp wider than the motion cannot fold)
EDGE_REACH = 0.5  # pixels: a layer reaching less than this beyond an edge is left as it is
EDGE_CELLS = 3  # the edge's ramp spans at least this many of the head layer's grid cells


def face_side(landmarks: np.ndarray) -> float:
    """The face's crop side in frame pixels (``landmarks.align.crop_transform``'s framing): (68, 2) -> float."""
    matrix = crop_transform(landmarks, 1024)
    return 1024.0 / float(np.sqrt(abs(np.linalg.det(matrix[:, :2]))))


def _eyes_mouth(landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(eye midpoint, mouth centre) of a face, frame pixels (``landmarks.align.face_geometry``)."""
    eye_left, eye_right, mouth = face_geometry(landmarks)
    return (eye_left + eye_right) / 2, mouth


def _head_ellipse(landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre (2,), semi-axes (2,)) of a face's head region, frame pixels: centred above the eyes/mouth midpoint,
    its semi-axes fractions of the face's crop side."""
    side = face_side(landmarks)
    eyes, mouth = _eyes_mouth(landmarks)
    return (eyes + mouth) / 2 - np.array([0.0, HEAD_CENTRE_UP * side]), np.asarray(HEAD_SEMI_AXES) * side


def _ellipse_radius(ellipse: tuple[np.ndarray, np.ndarray], shape: tuple[int, int], offset: tuple[int, int]
                    ) -> np.ndarray:
    """Per pixel of a region, its radius in a head ellipse (``_head_ellipse``; 1 on the ellipse): (H, W) float32.

    shape: (H, W) of the region; offset: (x0, y0) of the region in the frame.
    """
    return _radius_at(ellipse, np.arange(shape[1], dtype=np.float32) + offset[0],
                      np.arange(shape[0], dtype=np.float32) + offset[1])


def _radius_at(ellipse: tuple[np.ndarray, np.ndarray], xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """A head ellipse's radius on the grid of frame columns ``xs`` (W,) by rows ``ys`` (H,): (H, W) float32."""
    centre, axes = ellipse
    across = ((np.asarray(xs, np.float32) - np.float32(centre[0])) / np.float32(axes[0]))[None, :]
    down = ((np.asarray(ys, np.float32) - np.float32(centre[1])) / np.float32(axes[1]))[:, None]
    return np.sqrt(across * across + down * down)


def _smooth_weight(radius: np.ndarray, inner: float = HEAD_INNER) -> np.ndarray:
    """Head weight from the ellipse radius: 1 inside ``inner``, smoothstep to 0 on the ellipse."""
    ramp = np.clip((1.0 - radius) / (1.0 - inner), 0.0, 1.0)
    return (ramp * ramp * (3.0 - 2.0 * ramp)).astype(np.float32)  # smoothstep: no kink at either edge


def _inside_heads(ellipses: list[tuple[np.ndarray, np.ndarray]], shape: tuple[int, int], offset: tuple[int, int]
                  ) -> np.ndarray:
    """(H, W) uint8 (1 inside) of a region: inside any of the head ellipses shrunk by 1.5 pixels (rasterised, so
    cheap, and never past the true ellipse). In the 1.5-pixel ring left out the head weight is below
    3 (1.5 / (0.3 b))^2 for the shorter semi-axis b: under 0.015 for a face side of 200 pixels."""
    mask = np.zeros(shape, np.uint8)
    for centre, axes in ellipses:
        centre = np.round((centre - offset) * 16).astype(int)
        axes = np.round(np.maximum(axes - 1.5, 0.0) * 16).astype(int)
        cv2.ellipse(mask, (int(centre[0]), int(centre[1])), (int(axes[0]), int(axes[1])), 0, 0, 360, 1, -1,
                    cv2.LINE_8, 4)
    return mask


def head_weight(landmarks: np.ndarray, shape: tuple[int, int], offset: tuple[int, int] = (0, 0)) -> np.ndarray:
    """How much each pixel moves with the head: (H, W) float32, 1 inside the inner head ellipse, 0 outside it.

    landmarks: (68, 2) frame pixels; shape: (H, W) of the region; offset: (x0, y0) of the region in the frame.
    """
    return _smooth_weight(_ellipse_radius(_head_ellipse(landmarks), shape, offset))


def _person_ellipse(landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The head ellipse grown by ``PERSON_SCALE``: how far the head layer reaches when the matte keeps the
    background still."""
    centre, axes = _head_ellipse(landmarks)
    return centre, axes * PERSON_SCALE


def _person_weight(ellipses: list[tuple[np.ndarray, np.ndarray]], xs: np.ndarray, ys: np.ndarray, chin: float,
                   side: float, inner: float = PERSON_INNER) -> np.ndarray:
    """With the matte, how much each point of the grid of frame columns ``xs`` by rows ``ys`` moves with the head:
    1 inside ``inner`` of the grown ellipses and above the chin row ``chin``, smoothstep to 0 at their edge and
    ``NECK_FADE`` face sides below the chin. (H, W) float32."""
    radius = np.minimum.reduce([_radius_at(ellipse, xs, ys) for ellipse in ellipses])
    ramp = np.clip((1.0 - radius) / (1.0 - inner), 0.0, 1.0) * _neck(ys, chin, side)[:, None]
    return (ramp * ramp * (3.0 - 2.0 * ramp)).astype(np.float32)


def _neck(ys: np.ndarray, chin: float, side: float) -> np.ndarray:
    """Per frame row ``ys`` (H,): 1 above the chin row, falling to 0 ``NECK_FADE`` face sides below it. float32."""
    return np.clip((np.float32(chin + NECK_FADE * side) - np.asarray(ys, np.float32)) / np.float32(NECK_FADE * side),
                   0.0, 1.0).astype(np.float32)


def _edge_fade(grid_x: np.ndarray, grid_y: np.ndarray, shift_x: np.ndarray, shift_y: np.ndarray,
               frame_hw: tuple[int, int], step: float) -> np.ndarray | None:
    """Where the head layer (``shift`` (H, W) on the grid of frame columns ``grid_x`` by rows ``grid_y``) would show
    pixels from beyond a frame edge (a head moving away from the edge, or shrinking), a factor that fades it to none
    at that edge over ``EDGE_RAMP`` times its largest reach beyond it (at least ``EDGE_CELLS`` of the grid's
    ``step``, which the field is interpolated over): the hair at the edge stretches instead of mirroring what lies
    past it. (H, W) float32, or None where no edge is reached ``EDGE_REACH`` pixels or more."""
    height, width = frame_hw
    fade = None
    for distance, beyond in ((grid_x[None, :], -(grid_x[None, :] + shift_x)),  # left: sources left of column 0
                             (grid_y[:, None], -(grid_y[:, None] + shift_y)),  # top
                             (width - 1.0 - grid_x[None, :], grid_x[None, :] + shift_x - (width - 1.0)),  # right
                             (height - 1.0 - grid_y[:, None], grid_y[:, None] + shift_y - (height - 1.0))):  # bottom
        reach = float(beyond.max())
        if reach < EDGE_REACH:
            continue
        ramp = np.clip(distance / max(EDGE_RAMP * reach, EDGE_CELLS * step), 0.0, 1.0)
        ramp = np.broadcast_to(ramp * ramp * (3.0 - 2.0 * ramp), shift_x.shape)
        fade = ramp.astype(np.float32) if fade is None else fade * ramp.astype(np.float32)
    return fade


def _folds(grid_x: np.ndarray, grid_y: np.ndarray, shift_x: np.ndarray, shift_y: np.ndarray) -> bool:
    """Whether the map grid + shift (on the grid of frame columns ``grid_x`` by rows ``grid_y``) folds somewhere
    (``landmarks.warp.tps.folded_fraction``: the TPS's own test, in grid steps)."""
    if len(grid_x) < 2 or len(grid_y) < 2:
        return False
    return folded_fraction(grid_x[None, :] + shift_x, grid_y[:, None] + shift_y) > 0.0


def _fold_free_weight(ellipses: list[tuple[np.ndarray, np.ndarray]], grid_x: np.ndarray, grid_y: np.ndarray,
                      shift_x: np.ndarray, shift_y: np.ndarray, chin: float, side: float, person: bool,
                      box: tuple[int, int, int, int], frame_hw: tuple[int, int]) -> np.ndarray:
    """How much of its motion (``shift``, on the grid) each grid point of the head layer takes: the head weight
    (``_smooth_weight``, with the matte ``_person_weight``), faded toward the frame edges it would reach past
    (``_edge_fade``). A motion larger than the ramp it fades over folds the layer (the hair and collar drawn as
    loops, at a large turn of a close-up): then the ramp starts further in (``INNER_RETRIES``), the head's outer
    part lagging a little, until it does not fold; the outer edge, what a composite may change, stays where it is.
    (H, W) float32."""
    x0, y0, x1, y1 = box
    clipped = x0 == 0 or y0 == 0 or x1 == frame_hw[1] or y1 == frame_hw[0]  # only then can it reach past an edge
    step = float(grid_x[1] - grid_x[0]) if len(grid_x) > 1 else 1.0
    weight = None
    for lower in INNER_RETRIES:
        if person:
            weight = _person_weight(ellipses, grid_x, grid_y, chin, side, PERSON_INNER - lower)
        else:
            weight = np.maximum(*(_smooth_weight(_radius_at(ellipse, grid_x, grid_y), HEAD_INNER - lower)
                                  for ellipse in ellipses))
        fade = _edge_fade(grid_x, grid_y, shift_x * weight, shift_y * weight, frame_hw, step) if clipped else None
        if fade is not None:
            weight = weight * fade
        if not _folds(grid_x, grid_y, shift_x * weight, shift_y * weight):
            break
    return weight


def head_box(landmarks_list: list[np.ndarray], frame_hw: tuple[int, int], margin: int = 2) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) bounding every given face's head region, clipped to the frame; None if outside it."""
    return _box_of([_head_ellipse(points) for points in landmarks_list], frame_hw, margin)


def _box_of(ellipses: list[tuple[np.ndarray, np.ndarray]], frame_hw: tuple[int, int], margin: int = 2
            ) -> tuple[int, int, int, int] | None:
    """``head_box`` of the head ellipses themselves."""
    lows = [centre - axes for centre, axes in ellipses]
    highs = [centre + axes for centre, axes in ellipses]
    x0, y0 = np.floor(np.min(lows, 0)).astype(int) - margin
    x1, y1 = np.ceil(np.max(highs, 0)).astype(int) + margin + 1
    height, width = frame_hw
    x0, y0, x1, y1 = max(int(x0), 0), max(int(y0), 0), min(int(x1), width), min(int(y1), height)
    return None if x0 >= x1 or y0 >= y1 else (x0, y0, x1, y1)


def head_region(landmarks_list: list[np.ndarray], frame_hw: tuple[int, int], person: bool = False) -> np.ndarray:
    """Where any of the given faces' head regions reaches: (H, W) bool. Its complement is the scene a composite
    leaves as it is (the region ``lsr eval``'s scene PSNR and flicker are measured in). person: the region of a
    composite with the scene's matte (``composite_face``'s ``layers``), which reaches further."""
    region = np.zeros(frame_hw, bool)
    if not person:
        box = head_box(landmarks_list, frame_hw)
        if box is not None:
            x0, y0, x1, y1 = box
            for points in landmarks_list:
                region[y0:y1, x0:x1] |= head_weight(points, (y1 - y0, x1 - x0), (x0, y0)) > 0
        return region
    points_list = [np.asarray(points, np.float64) for points in landmarks_list]
    ellipses = [_person_ellipse(points) for points in points_list]
    box = _box_of(ellipses, frame_hw)
    if box is not None:
        x0, y0, x1, y1 = box
        chin, side = max(points[8, 1] for points in points_list), max(face_side(points) for points in points_list)
        region[y0:y1, x0:x1] = _person_weight(ellipses, np.arange(x0, x1, dtype=np.float32),
                                              np.arange(y0, y1, dtype=np.float32), chin, side) > 0
    return region


def face_outline(landmarks: np.ndarray) -> np.ndarray:
    """The face's outline for its mask: the jaw and the brows lifted to the hairline, (27, 2) float64."""
    points = np.asarray(landmarks, np.float64)
    eyes, mouth = _eyes_mouth(points)
    forehead = points[17:27] + FOREHEAD_LIFT * (eyes - mouth)
    return np.concatenate([points[0:17], forehead])


def blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of a float32 map at any sigma: large sigmas run on a shrunk copy (a smooth field needs no
    more), so the cost stays that of a small kernel. (H, W[, C]) float32 -> same."""
    if sigma <= 6:
        return cv2.GaussianBlur(image, (0, 0), max(sigma, 0.1))
    factor = sigma / 3.0
    height, width = image.shape[:2]
    small = cv2.resize(image, (max(1, round(width / factor)), max(1, round(height / factor))), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), 3.0)
    return cv2.resize(small, (width, height), interpolation=cv2.INTER_LINEAR)


@dataclasses.dataclass
class SceneLayers:
    """A scene frame split into what moves with the head and what stays (``background_plate``)."""

    matte: np.ndarray
    """(H, W) float32 in [0, 1]: how much each pixel is the person (``landmarks.scene.person_matte.person_matte``)."""
    plate: np.ndarray
    """(H, W, 3) uint8: the scene without the person, the background filled in where the person was."""


def fill_in(image: np.ndarray, known: np.ndarray, trust: float = 1.0) -> np.ndarray:
    """Fill an image where it is unknown from the known pixels around (push-pull: a pyramid of weighted means,
    each level's holes taken from the next coarser level): (H, W, C) float32, (H, W) float32 weights in [0, 1]
    -> (H, W, C) float32, equal to ``image`` where ``known`` is 1, smooth across the holes. trust: a level's mean
    is taken fully where at least 1 / trust of its footprint is known (1: all of it), so a larger trust carries the
    nearest known colours further into a hole before the coarser levels' means take over."""
    levels = []
    weighted, weight = image * known[..., None], known.astype(np.float32)
    while min(weight.shape) > 2:
        levels.append((weighted, weight))
        weighted, weight = cv2.pyrDown(weighted), cv2.pyrDown(weight)
    filled = weighted.reshape(-1, image.shape[2]).sum(0) / max(float(weight.sum()), 1e-6)
    filled = np.broadcast_to(filled, weighted.shape).astype(np.float32)
    for weighted, weight in reversed(levels):
        coarse = cv2.resize(filled, weight.shape[::-1], interpolation=cv2.INTER_LINEAR).reshape(weighted.shape)
        taken = np.minimum(weight * trust, 1.0)[..., None]  # a level's mean where its pixels saw enough known weight
        filled = weighted / np.maximum(weight, 1e-6)[..., None] * taken + coarse * (1.0 - taken)
    return filled


def plate_hole(matte: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Where the plate fills in: the person (matte above ``PERSON_LEVEL``) and ``PERSON_REACH`` of the face side
    around, where the matte's edge is unsure. matte: (H, W) float32 in [0, 1]; landmarks: (68, 2) frame pixels of
    the face -> (H, W) uint8, 1 in the hole."""
    reach = max(1, round(PERSON_REACH * face_side(landmarks)))
    return cv2.dilate((matte > PERSON_LEVEL).astype(np.uint8), cv2.getStructuringElement(
        cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1)))


def background_plate(scene: np.ndarray, scene_landmarks: np.ndarray, matte: np.ndarray) -> SceneLayers:
    """The scene's layers for ``composite_face``: its person matte, and the background with the person (and a
    margin of ``PERSON_REACH`` of the face side around the matte's edge) filled in from around (``fill_in``, its
    nearest colours carried in: ``PLATE_TRUST``).

    scene: (H, W, 3) uint8; scene_landmarks: (68, 2) frame pixels of its face; matte: (H, W) float32 in [0, 1]."""
    matte = np.clip(np.asarray(matte, np.float32), 0.0, 1.0)
    if matte.shape != scene.shape[:2]:
        raise ValueError(f"the matte must be the scene's size {scene.shape[:2]}, got {matte.shape}")
    person = plate_hole(matte, _check(scene, scene_landmarks, "scene_landmarks"))
    known = (1 - person).astype(np.float32)
    height, width = matte.shape
    shrink = max(1.0, max(height, width) / PLATE_SIDE)  # the fill is smooth: made small, then enlarged
    small_hw = (max(1, round(width / shrink)), max(1, round(height / shrink)))
    small = fill_in(cv2.resize(scene, small_hw, interpolation=cv2.INTER_AREA).astype(np.float32),
                    cv2.resize(known, small_hw, interpolation=cv2.INTER_AREA), PLATE_TRUST)
    filled = cv2.resize(np.clip(np.rint(small), 0, 255).astype(np.uint8), (width, height),
                        interpolation=cv2.INTER_LINEAR)
    return SceneLayers(matte, np.where(person[..., None] > 0, filled, scene))  # the background itself, bit for bit


@dataclasses.dataclass
class Composite:
    """What ``composite_face`` made: the frame and, for inspection, its layers' masks (in the frame's box)."""

    frame: np.ndarray
    """(H, W, 3) uint8: the scene with the re-enacted head."""
    box: tuple[int, int, int, int] | None
    """(x0, y0, x1, y1): the only region that differs from the scene (None: nothing changed)."""
    face_alpha: np.ndarray | None = None
    """(y1 - y0, x1 - x0) float32: the face layer's weight."""
    head_motion: np.ndarray | None = None
    """(2, 3) float64: the head's rigid part, the similarity scene -> target on RIGID_INDEX, frame pixels."""


def _check(frame: np.ndarray, points: np.ndarray, name: str) -> np.ndarray:
    points = np.asarray(points, np.float64)
    if points.shape != (NUM_LANDMARKS, 2) or not np.isfinite(points).all():
        raise ValueError(f"{name} must be finite ({NUM_LANDMARKS}, 2) frame pixels, got {points.shape}")
    return points


def composite_face(scene: np.ndarray, scene_landmarks: np.ndarray, target_landmarks: np.ndarray,
                   face_crop: np.ndarray, crop_matrix: np.ndarray, layers: SceneLayers | None = None) -> Composite:
    """Put a synthesised face into a scene frame, the head (hair) following it rigidly (module docstring).

    scene: (H, W, 3) uint8 the frame to composite into (the source's anchor shot or source video frame);
    scene_landmarks: (68, 2) the scene's own face, frame pixels;
    target_landmarks: (68, 2) where the face is drawn (the retargeted driving landmarks), frame pixels;
    face_crop: (C, C, 3) uint8 the synthesis, a crop of the frame under ``crop_matrix`` ((2, 3) frame -> crop);
    layers: the scene's person matte and background plate (``background_plate``): only the person moves with the
    head, the background stays and fills what the head uncovers. None: everything in the head region moves.
    """
    if scene.ndim != 3 or scene.shape[2] != 3 or scene.dtype != np.uint8:
        raise ValueError(f"scene must be (H, W, 3) uint8, got {scene.shape} {scene.dtype}")
    scene_points = _check(scene, scene_landmarks, "scene_landmarks")
    target_points = _check(scene, target_landmarks, "target_landmarks")
    rigid = list(RIGID_INDEX)
    scale, rotation, translation = similarity_procrustes(scene_points[rigid], target_points[rigid])
    motion = np.concatenate([scale * rotation, translation[:, None]], axis=1)
    heads = [_head_ellipse(scene_points), _head_ellipse(target_points)]  # made once: every layer needs them
    # with the matte the head layer reaches further (hair beyond the head ellipse moves with the head)
    ellipses = heads if layers is None else [_person_ellipse(scene_points), _person_ellipse(target_points)]
    box = _box_of(ellipses, scene.shape[:2])
    if box is None:
        return Composite(scene.copy(), None)
    x0, y0, x1, y1 = box
    roi_hw = (y1 - y0, x1 - x0)
    side = face_side(target_points)
    output = scene.copy()

    # head layer: identity far away, the scene's face outline carried onto the target's inside (a TPS on the jaw,
    # brows, nose and eye corners); one smooth field, so no seam and no hole, and no old cheek left beside the new.
    # The rigid motion carries the whole head (hair included); the TPS, pinned at the box's edge, adds what is not.
    # The field is smooth, so it is made (TPS, rigid part, head weight) on a grid every side / HEAD_GRID_CELLS pixels
    # and densified once: the per-pixel work is one interpolation and the remap.
    offset = np.array([x0, y0], np.float64)
    moved = apply_similarity(scene_points, scale, rotation, translation)
    step = max(4, round(side / HEAD_GRID_CELLS))
    warp = tps_grid_map(moved[HEAD_WARP_INDEX] - offset, target_points[HEAD_WARP_INDEX] - offset, y1 - y0, x1 - x0,
                        grid_step=step)
    inverse = invert_affine(motion)
    grid_x, grid_y = warp.grid.xs + x0, warp.grid.ys + y0  # frame pixels of the grid's columns and rows
    moved_x, moved_y = warp.map_x + x0, warp.map_y + y0  # frame pixels of the moved head each grid point shows
    shift_x = inverse[0, 0] * moved_x + inverse[0, 1] * moved_y + inverse[0, 2] - grid_x[None, :]
    shift_y = inverse[1, 0] * moved_x + inverse[1, 1] * moved_y + inverse[1, 2] - grid_y[:, None]
    if max(np.abs(shift_x).max(), np.abs(shift_y).max()) > STILL:
        chin, sides = max(scene_points[8, 1], target_points[8, 1]), max(side, face_side(scene_points))
        weight = _fold_free_weight(ellipses, grid_x, grid_y, shift_x, shift_y, chin, sides, layers is not None,
                                   (x0, y0, x1, y1), scene.shape[:2])
        source_x = warp.densify(shift_x * weight)
        source_x += np.arange(x0, x1, dtype=np.float32)[None, :]
        source_y = warp.densify(shift_y * weight)
        source_y += np.arange(y0, y1, dtype=np.float32)[:, None]
        moved_head = cv2.remap(scene, source_x, source_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        if layers is not None:
            moved_head = _keep_background(moved_head, layers, source_x, source_y, box)
        del source_x, source_y
        # interpolated, the field leaks a sub-pixel shift just past the ellipses: the scene stays there, bit for bit
        outside = _inside_heads(ellipses, roi_hw, (x0, y0)) == 0
        if layers is not None:  # ... and below the neck's fade
            outside[_neck(np.arange(y0, y1, dtype=np.float32), chin, sides) <= 0] = True
        cv2.copyTo(scene[y0:y1, x0:x1], outside.view(np.uint8), moved_head)  # in place (numpy's masked copy: 5x slower)
        output[y0:y1, x0:x1] = moved_head
        del moved_head, outside

    # face layer, in the face's own box (the hull, its margin and feather): the synthesis, exactly inverse-warped
    reach = int(np.ceil((FACE_MARGIN + FACE_FEATHER) * side)) + 2
    outline = face_outline(target_points)
    fx0, fy0 = np.maximum(np.floor(outline.min(0)).astype(int) - reach, [x0, y0])
    fx1, fy1 = np.minimum(np.ceil(outline.max(0)).astype(int) + reach + 1, [x1, y1])
    if fx0 >= fx1 or fy0 >= fy1:
        return Composite(output, box, None, motion)
    face_hw = (int(fy1 - fy0), int(fx1 - fx0))
    face_matrix = np.asarray(crop_matrix, np.float64).copy()
    face_matrix[:, 2] += face_matrix[:, :2] @ np.array([fx0, fy0], np.float64)
    crop_side = face_crop.shape[0]
    face = cv2.warpAffine(face_crop, face_matrix, face_hw[::-1], flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE).astype(np.float32)
    inside_crop = np.zeros((crop_side, crop_side), np.float32)
    edge = max(1, crop_side // 32)
    inside_crop[edge:-edge, edge:-edge] = 1.0
    footprint = cv2.warpAffine(inside_crop, face_matrix, face_hw[::-1], flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)

    hull = np.zeros(face_hw, np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(np.round(outline - [fx0, fy0]).astype(np.int32)), 1)
    outside = cv2.distanceTransform(1 - hull, cv2.DIST_L2, 3)  # pixels to the hull (0 inside)
    ramp = np.clip((FACE_MARGIN * side + FACE_FEATHER * side / 2 - outside) / (FACE_FEATHER * side), 0.0, 1.0)
    alpha = ramp * ramp * (3.0 - 2.0 * ramp) * footprint * _within_head(heads, face_hw, (fx0, fy0))
    del outside, ramp

    # colour match: a smooth offset that makes the face's edge agree with the head layer around it
    head_layer = output[fy0:fy1, fx0:fx1].astype(np.float32)
    inside = cv2.distanceTransform(hull, cv2.DIST_L2, 3)
    band = ((hull > 0) & (inside < COLOUR_BAND * side) & (footprint > 0.99)).astype(np.float32)
    if band.sum() > 16:
        sigma = COLOUR_SIGMA * side
        difference = (head_layer - face) * band[..., None]
        global_offset = np.array(cv2.sumElems(difference)[:3]) / cv2.sumElems(band)[0]  # numpy's strided sum: 10x slower
        spread = blur(band, sigma)
        colour = blur(difference, sigma)
        del difference
        colour /= np.maximum(spread, 1e-3)[..., None]
        colour[spread <= 1e-3] = global_offset
        face += np.clip(colour, -COLOUR_LIMIT, COLOUR_LIMIT, out=colour)
        del colour
    face -= head_layer  # blend in place: head + (face - head) * alpha
    face *= alpha[..., None]
    face += head_layer
    output[fy0:fy1, fx0:fx1] = np.clip(np.rint(face, out=face), 0, 255).astype(np.uint8)
    full_alpha = np.zeros(roi_hw, np.float32)
    full_alpha[fy0 - y0 : fy1 - y0, fx0 - x0 : fx1 - x0] = alpha
    return Composite(output, box, full_alpha, motion)


def _keep_background(moved_head: np.ndarray, layers: SceneLayers, source_x: np.ndarray, source_y: np.ndarray,
                     box: tuple[int, int, int, int]) -> np.ndarray:
    """The moved head layer (the box's pixels) where the moved matte says person; elsewhere the background plate,
    where the layer moves (``MOVING`` pixels or more; less, the layer stays as it was). (h, w, 3) uint8 -> same."""
    x0, y0, x1, y1 = box
    moving = np.hypot(source_x - np.arange(x0, x1, dtype=np.float32)[None, :],
                      source_y - np.arange(y0, y1, dtype=np.float32)[:, None])
    moving = np.minimum(moving, MOVING, out=moving) / MOVING
    moved_matte = cv2.remap(layers.matte, source_x, source_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    background = (1.0 - moved_matte) * moving
    blended = moved_head.astype(np.float32)
    blended += background[..., None] * (layers.plate[y0:y1, x0:x1].astype(np.float32) - blended)
    return np.clip(np.rint(blended), 0, 255).astype(np.uint8)


def _within_head(ellipses: list[tuple[np.ndarray, np.ndarray]], shape: tuple[int, int], offset: tuple[int, int]
                 ) -> np.ndarray | float:
    """1 inside the head regions, ramping to 0 over their outermost 5 %: the face layer never leaves them (a
    close-up's face can be as large as the frame), so ``head_region``'s complement is the scene, bit for bit.
    (H, W) float32, or 1.0 when the whole region lies inside one of them (an ellipse is convex: its corners do)."""
    corners_x = np.array([offset[0], offset[0] + shape[1] - 1], np.float32)
    corners_y = np.array([offset[1], offset[1] + shape[0] - 1], np.float32)
    if any(_radius_at(ellipse, corners_x, corners_y).max() <= 0.95 for ellipse in ellipses):
        return 1.0
    radius = np.minimum(*(_ellipse_radius(ellipse, shape, offset) for ellipse in ellipses))
    return np.clip((1.0 - radius) / 0.05, 0.0, 1.0)


def place_in_frame(crop_landmarks: np.ndarray, crop_matrix: np.ndarray) -> np.ndarray:
    """Crop-pixel landmarks -> frame pixels under a (2, 3) frame -> crop matrix: (..., 2) -> (..., 2)."""
    return transform_landmarks(crop_landmarks, invert_affine(crop_matrix))
