"""The shots' irises warped to where the target looks (issue 40: one iris, where the driver looks).

A warp carries each shot's eye onto the target's lids, and its iris with it, wherever that shot looked. Where the
shots looked apart, the blend of their warps shows two irises (or a smudge between them); where they all looked at
the camera, the output keeps looking there whatever the driver does. ``landmarks.parts.eyes.iris.draw_irises`` lays one
subject iris over the finished synthesis, but only where the synthesis draws an eye open enough to hold one.

Here the warps themselves are bent before they sample the shots (``align_irises``): inside each eye of the target
(its 68 points' corners), a band of the eye around the warped iris moves rigidly along the corner line onto the
target's gaze (``landmarks.parts.eyes.iris.gaze_offsets``' first coordinate), and the rest of the eye is stretched on one side
and squeezed on the other, back to the warp as it was at the corners and above and below the lids. Every reference
then shows its own, sharp iris at the same place, so the network gets references that agree.

Where the target's gaze is not known (a landmark driver, an eye closing), the references' irises move to the
nearest shot's (the first reference's), so they still agree. A shot whose iris was not found (its eye closing)
is left as warped.

Only the horizontal gaze is moved: looking up or down moves the lids with the iris, and the mesh warp carries
them already.

numpy + OpenCV only: the torch and ONNX runtimes share it through ``landmarks.warp.piecewise_affine.warp_references_mesh``.
"""

from __future__ import annotations

import cv2
import numpy as np

from landmarks.shape.measures import eye_axes

PLATEAU = 0.25
"""Half-width, in eye widths along the corner line, of the band around the iris that moves rigidly (an iris' radius
is about 0.2 of the eye's width)."""
REACH = 0.6
"""The warp is unchanged from this far from the eye's centre on, along the corner line (eye widths; the corners lie at
0.5)."""
BAND = (0.3, 0.45)
"""Across the corner line: the full shift within the first distance from it, none from the second (eye widths; the
lids lie within about 0.2, the brows beyond 0.6)."""
MAX_SHIFT = 0.25
"""An iris moves at most this many eye widths (a glance aside spans about 0.1; an iris looking hard aside sits about
0.2 from the centre)."""


def landed(map_x: np.ndarray, map_y: np.ndarray, point: np.ndarray, box: tuple[int, int, int, int] | None = None
           ) -> np.ndarray:
    """Where a backward map (output pixel p samples the source at map(p)) puts source ``point`` (2,): the output pixel
    whose map is nearest it (searched within ``box`` (x0, y0, x1, y1) when given), refined by one Newton step on the
    map's local Jacobian -> (2,) float64, NaN when the map never comes within 2 pixels of it there."""
    point = np.asarray(point, np.float64)
    height, width = map_x.shape
    x0, y0, x1, y1 = (0, 0, width, height) if box is None else (max(box[0], 0), max(box[1], 0), min(box[2], width),
                                                                 min(box[3], height))
    if x1 <= x0 or y1 <= y0:
        return np.full(2, np.nan)
    distance = (map_x[y0:y1, x0:x1] - point[0]) ** 2 + (map_y[y0:y1, x0:x1] - point[1]) ** 2
    row, column = np.unravel_index(int(np.argmin(distance)), distance.shape)
    if not distance[row, column] <= 4.0:
        return np.full(2, np.nan)
    row, column = row + y0, column + x0
    r0, r1 = max(row - 1, 0), min(row + 1, height - 1)
    c0, c1 = max(column - 1, 0), min(column + 1, width - 1)
    if r1 == r0 or c1 == c0:
        return np.array([column, row], np.float64)
    jacobian = np.array([[map_x[row, c1] - map_x[row, c0], map_x[r1, column] - map_x[r0, column]],
                         [map_y[row, c1] - map_y[row, c0], map_y[r1, column] - map_y[r0, column]]], np.float64)
    jacobian /= [[c1 - c0, r1 - r0]]
    residual = point - (map_x[row, column], map_y[row, column])
    try:
        step = np.linalg.solve(jacobian, residual)
    except np.linalg.LinAlgError:
        return np.array([column, row], np.float64)
    return np.array([column, row], np.float64) + np.clip(step, -1.5, 1.5)


def _eye_box(centre: np.ndarray, axis: np.ndarray, width: float) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) integer pixel bounds of the region ``shift_iris`` may change around an eye."""
    across = np.array([-axis[1], axis[0]])
    corners = np.array([centre + width * (u * axis + v * across) for u in (-REACH, REACH) for v in (-BAND[1], BAND[1])])
    x0, y0 = np.floor(corners.min(axis=0)).astype(int)
    x1, y1 = np.ceil(corners.max(axis=0)).astype(int) + 1
    return int(x0), int(y0), int(x1), int(y1)


def iris_along(map_x: np.ndarray, map_y: np.ndarray, iris: np.ndarray, landmarks: np.ndarray, eye: int) -> float:
    """Where a shot's iris centre (``iris`` (2,), shot pixels) lands along the target's eye ``eye`` (its 68 points
    ``landmarks``), in eye widths from the eye's centre (``gaze_offsets``' first coordinate); NaN when it does not land
    in the eye's region."""
    if not np.isfinite(iris).all():
        return float("nan")
    centre, axis, width = eye_axes(landmarks, eye)
    if not width >= 1.0:
        return float("nan")
    point = landed(map_x, map_y, iris, _eye_box(centre, axis, width))
    return float((point - centre) @ axis / width) if np.isfinite(point).all() else float("nan")


def shift_iris(map_x: np.ndarray, map_y: np.ndarray, landmarks: np.ndarray, eye: int, start: float, end: float,
               in_place: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The backward map with eye ``eye`` of the target's 68 points ``landmarks`` bent so that what it showed at
    ``start`` along the corner line (eye widths from the eye's centre) shows at ``end`` (module docstring). Maps
    (H, W) float32 -> new (H, W) float32 maps (the inputs untouched), or with ``in_place`` the inputs bent."""
    centre, axis, width = eye_axes(landmarks, eye)
    end = float(np.clip(end, start - MAX_SHIFT, start + MAX_SHIFT))
    plateau = min(PLATEAU, REACH - 0.05 - max(abs(start), abs(end)))
    if not (np.isfinite([start, end]).all() and width >= 1.0 and plateau > 0.02) or abs(end - start) < 1e-3:
        return map_x, map_y
    across = np.array([-axis[1], axis[0]])
    height, image_width = map_x.shape
    x0, y0, x1, y1 = _eye_box(centre, axis, width)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, image_width), min(y1, height)
    if x1 <= x0 or y1 <= y0:
        return map_x, map_y
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float64)
    u = ((xs - centre[0]) * axis[0] + (ys - centre[1]) * axis[1]) / width
    v = ((xs - centre[0]) * across[0] + (ys - centre[1]) * across[1]) / width
    moved = np.where(np.abs(u) < REACH, np.interp(u, [-REACH, end - plateau, end + plateau, REACH],
                                                  [-REACH, start - plateau, start + plateau, REACH]), u)
    weight = np.clip((BAND[1] - np.abs(v)) / (BAND[1] - BAND[0]), 0.0, 1.0)
    shift = weight * (moved - u) * width  # pixels along the axis, output -> where its map is read
    sample_x = (xs + shift * axis[0]).astype(np.float32)
    sample_y = (ys + shift * axis[1]).astype(np.float32)
    out_x, out_y = (map_x, map_y) if in_place else (map_x.copy(), map_y.copy())
    for out in (out_x, out_y):  # the remap reads the box's rim too: read all of it before writing
        out[y0:y1, x0:x1] = cv2.remap(out, sample_x, sample_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out_x, out_y


def align_irises(maps: list[tuple[np.ndarray, np.ndarray]], irises: np.ndarray, landmarks: np.ndarray,
                 gaze: np.ndarray | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Backward maps of the references, nearest first (``maps``: N x (map_x, map_y) (H, W) float32), each bent so
    that its shot's iris (``irises`` (N, 2, 2) shot pixels, image-left eye first, NaN where not found) lands where
    the target looks: ``gaze`` (2, 2) ``landmarks.parts.eyes.iris.gaze_offsets`` of the target's 68 points ``landmarks``
    (first coordinate), or, where an eye's is NaN or no gaze is given, where the first reference's iris lands
    (module docstring). -> N x (map_x, map_y)."""
    irises = np.asarray(irises, np.float64)
    if irises.shape != (len(maps), 2, 2):
        raise ValueError(f"irises must be ({len(maps)}, 2, 2), got {irises.shape}")
    aligned, owned = list(maps), [False] * len(maps)  # owned: a copy made here, bent in place from then on
    for eye in range(2):
        starts = [iris_along(*warp, iris[eye], landmarks, eye) for warp, iris in zip(maps, irises)]
        end = float(gaze[eye, 0]) if gaze is not None and np.isfinite(gaze[eye, 0]) else starts[0]
        if not np.isfinite(end):
            continue
        for number, start in enumerate(starts):
            if np.isfinite(start):
                bent = shift_iris(*aligned[number], landmarks, eye, start, end, in_place=owned[number])
                owned[number] = owned[number] or bent[0] is not aligned[number][0]
                aligned[number] = bent
    return aligned
