"""Piecewise-affine image warping over the 468-point face mesh (numpy + OpenCV): the dense counterpart of ``landmarks.warp.tps``.

Used by the ``mesh`` / ``mesh_mean3`` baselines of ``lsr eval`` (``lsr.eval.baselines``); the torch version of the
same map is ``models_def.mesh_warp.mesh_warp_maps`` (tested against this one).

The map is a backward map like ``landmarks.warp.tps.tps_map``'s: output pixel p samples the source image at map(p).
  * **Inside the face**: the target mesh is cut into triangles (``triangulation``); a pixel inside target
    triangle t samples the source at A_t p, the affine map taking t's corners onto the same triangle of the
    source mesh. Triangles are rasterised once (``rasterise_triangles``: each pixel centre gets the index of the
    triangle that contains it) and the affines applied in one gather.
  * **Outside the face** the 68-point TPS of ``landmarks.warp.tps`` (by default on ``landmarks.shape.mesh68.mesh_to_68`` of both
    meshes, frame border fixed; the ``mesh`` baseline passes the ``tps`` baseline's own map) takes over, feathered
    into the piecewise-affine
    map over ``feather`` pixels inside the face outline and around dropped triangles (``feather_weights``;
    default ``FEATHER_IOD`` of the target's inter-ocular distance), so there is no seam.
  * A triangle that is degenerate (area under ``min_area`` square pixels) or folded (mirrored against the canonical
    face) in either mesh is dropped: the weight dips around it as at the outline, and its pixels take the
    Gaussian average of their kept neighbours' correction (the piecewise-affine map minus the TPS), so a small
    hole leaves no speck and a large one fades into the TPS.

The triangulation is ours: a Delaunay triangulation of the frontal canonical face (``frontal_canonical``: the x, y
of ``landmarks.motion.mesh_rotation``'s canonical mesh, the mean face of the project's training people, which looks at the
camera), without the slivers whose smallest angle is under ``MIN_ANGLE_DEGREES`` (they fold under the mesh's
per-vertex noise). Qhull's output order may change between versions, so the triangles are stored in
``landmarks/assets/mesh_triangles.json``; rebuild it (after a new canonical mesh) with

    python -c "from landmarks.warp.piecewise_affine import write_triangulation; write_triangulation()"

(tests check that the stored triangles are what ``build_triangles`` gives from the canonical mesh).

Cross-identity driving moves meshes the way ``landmarks.motion.retarget_points.retarget_driving`` moves 68 points:
``landmarks.motion.retarget_mesh``.

Shapes: meshes (468, 2 or 3) float x, y frame pixels (z, smaller = nearer, orders overlapping target triangles and
feeds ``mesh_to_68``'s yaw-dependent jaw); maps (H, W) float32 source pixel coordinates.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from landmarks.shape import measures
from landmarks.warp import tps
from landmarks.exceptions import ModelFilesError
from landmarks.parts.mouth.opening_gain import EXPRESSION_GAIN, amplify_mouth, mouth_gain
from landmarks.parts.eyes.lids import LID_CLOSED, close_lids, lid_gaps
from landmarks.shape.mesh68 import mesh_to_68

TRIANGLES_FILE = Path(__file__).resolve().parents[1] / "assets" / "mesh_triangles.json"
MESH_POINTS = 468
MIN_ANGLE_DEGREES = 5.0  # canonical triangles thinner than this are slivers: dropped from the triangulation
MIN_AREA = 1e-3  # square pixels: a flatter (or folded) triangle in either mesh goes to the TPS fallback. Small is
# fine (a pixel inside a target triangle samples inside its source triangle); only a collapsed one has no affine
FEATHER = 3.0  # pixels: the narrowest blend of the TPS outside the face into the piecewise-affine map
# The blend's width by default, in target inter-ocular distances: where the triangles fold (a turned head's far cheek,
# driven across identities) the TPS fills holes among kept triangles, and a blend narrower than a triangle leaves a
# torn edge there. On the FSTH sample (K = 8, 12 hold-outs per identity): 3 px -> 0.3 IOD kept the face PSNR (21.65 ->
# 21.64 dB; tps 21.55) and cut the cross-identity face sharpness from 1.13 to 1.06 of the anchor's (tps: 0.98).
FEATHER_IOD = 0.3
WEIGHT_SNAP = 1e-5  # feather weights this close to 1 are 1


# ---- the triangulation -----------------------------------------------------------------------------------


def normalise_mesh(mesh: np.ndarray) -> np.ndarray:
    """A mesh in its eyes' frame: eye midpoint at 0, the eye line level, inter-ocular distance 1 (eye centres of
    the 68 points, ``mesh_to_68``). (468, >=2) -> (468, 2) float64."""
    points = np.asarray(mesh, np.float64)[:, :2]
    landmarks = mesh_to_68(points).astype(np.float64)
    left, right = landmarks[36:42].mean(0), landmarks[42:48].mean(0)
    axis = right - left
    scale = float(np.linalg.norm(axis))
    if not scale > 0:
        raise ValueError("the mesh's eyes coincide: cannot normalise it")
    cos, sin = axis / scale
    level = np.array([[cos, sin], [-sin, cos]])  # rotates the eye line onto +x
    return (points - (left + right) / 2.0) @ level.T / scale


@functools.lru_cache(maxsize=1)
def frontal_canonical() -> np.ndarray:
    """(468, 2) float64: ``landmarks.motion.mesh_rotation``'s canonical mesh seen from the front (its x, y; image axes, y down),
    eye-normalised (``normalise_mesh``). Its mouth is open (the mean of talking faces), so the lips do not touch."""
    from landmarks.motion.mesh_rotation import canonical

    frontal = normalise_mesh(canonical()[0])
    frontal.setflags(write=False)
    return frontal


def signed_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Signed triangle areas in image axes (x right, y down): positive for the canonical orientation.

    vertices: (..., V, 2); triangles: (T, 3) int -> (..., T) float64."""
    corners = np.asarray(vertices, np.float64)[..., triangles, :]  # (..., T, 3, 2)
    first, second = corners[..., 1, :] - corners[..., 0, :], corners[..., 2, :] - corners[..., 0, :]
    return 0.5 * (first[..., 0] * second[..., 1] - first[..., 1] * second[..., 0])


def smallest_angles(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V, 2), (T, 3) -> (T,) smallest interior angle of each triangle in degrees."""
    corners = np.asarray(vertices, np.float64)[triangles]  # (T, 3, 2)
    angles = []
    for corner in range(3):
        first = corners[:, (corner + 1) % 3] - corners[:, corner]
        second = corners[:, (corner + 2) % 3] - corners[:, corner]
        cosine = np.sum(first * second, -1) / np.maximum(np.linalg.norm(first, axis=-1) * np.linalg.norm(second, axis=-1), 1e-300)
        angles.append(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
    return np.min(angles, axis=0)


def build_triangles(canonical: np.ndarray, min_angle: float = MIN_ANGLE_DEGREES) -> np.ndarray:
    """Delaunay triangulation of the canonical mesh without slivers. canonical: (468, 2) -> (T, 3) int32.

    Every triangle is oriented with a positive ``signed_areas`` on the canonical mesh and starts at its smallest
    vertex index; rows are sorted, so the result does not depend on Qhull's output order."""
    from scipy.spatial import Delaunay

    canonical = np.asarray(canonical, np.float64)
    triangles = Delaunay(canonical).simplices.astype(np.int64)
    flipped = signed_areas(canonical, triangles) < 0
    triangles[flipped] = triangles[flipped][:, [0, 2, 1]]
    triangles = triangles[smallest_angles(canonical, triangles) >= min_angle]
    start = np.argmin(triangles, axis=1)
    triangles = np.stack([np.roll(row, -shift) for row, shift in zip(triangles, start)])  # same orientation
    return triangles[np.lexsort(triangles.T[::-1])].astype(np.int32)


def write_triangulation(out: str | Path = TRIANGLES_FILE) -> dict[str, Any]:
    """Rebuild the asset: ``build_triangles`` of ``frontal_canonical``, written compactly to ``out``. Returns the
    record."""
    from landmarks.io.image_files import atomic_output

    triangles = build_triangles(frontal_canonical())
    record = {
        "about": "Delaunay triangulation of the frontal canonical face mesh (landmarks.motion.mesh_rotation), slivers dropped; "
                 "built by landmarks.warp.piecewise_affine.write_triangulation",
        "min_angle_degrees": MIN_ANGLE_DEGREES,
        "triangles": triangles.tolist(),
    }
    with atomic_output(out) as temp:
        temp.write_text(json.dumps(record, separators=(",", ":")) + "\n")
    return record


@functools.lru_cache(maxsize=1)
def triangulation() -> np.ndarray:
    """(T, 3) int32 vertex indices, positively oriented (``signed_areas``) on the frontal canonical face: the stored
    triangles (``landmarks/assets/mesh_triangles.json``)."""
    if not TRIANGLES_FILE.is_file():
        raise ModelFilesError(f"{TRIANGLES_FILE} is missing; reinstall the package (or rebuild it: see landmarks/warp/piecewise_affine.py)")
    triangles = np.asarray(json.loads(TRIANGLES_FILE.read_text())["triangles"], np.int32)
    triangles.setflags(write=False)
    return triangles


# ---- the piecewise-affine map ----------------------------------------------------------------------------


def triangle_affines(source: np.ndarray, target: np.ndarray, triangles: np.ndarray,
                     min_area: float = MIN_AREA) -> tuple[np.ndarray, np.ndarray]:
    """Per triangle, the affine map taking its target corners onto its source corners, in its first corner's
    frame: p -> source_0 + L (p - target_0) (no large translation to cancel, as in the float32 torch version).

    source, target: (V, 2) float pixels; triangles: (T, 3) int -> (affines (T, 2, 4) float64: columns L (2x2),
    target_0, source_0; usable (T,) bool: area >= ``min_area`` in both meshes, i.e. neither degenerate nor
    folded). Unusable triangles get the identity."""
    target_corners = np.asarray(target, np.float64)[triangles]  # (T, 3, 2), gathered once
    source_corners = np.asarray(source, np.float64)[triangles]
    target_edges = (target_corners[:, 1:] - target_corners[:, :1]).transpose(0, 2, 1)  # (T, 2, 2) edge columns
    source_edges = (source_corners[:, 1:] - source_corners[:, :1]).transpose(0, 2, 1)
    # signed areas (``signed_areas``) from the edges; a NaN corner gives a NaN area, which is never >= min_area
    (a, b), (c, d) = target_edges[:, 0].T, target_edges[:, 1].T
    determinant = a * d - b * c  # twice the target's signed area
    source_determinant = source_edges[:, 0, 0] * source_edges[:, 1, 1] - source_edges[:, 0, 1] * source_edges[:, 1, 0]
    usable = (0.5 * determinant >= min_area) & (0.5 * source_determinant >= min_area)
    # L target_edges = source_edges: L = source_edges @ inverse(target_edges), the 2x2 inverses written out
    # (np.linalg.solve on 890 2x2 systems took 0.5 ms a source); unusable triangles get the identity
    determinant = np.where(usable, determinant, 1.0)
    inverse = np.stack([np.stack([d, -b], -1), np.stack([-c, a], -1)], 1) / determinant[:, None, None]
    inverse[~usable] = np.eye(2)
    source_edges[~usable] = np.eye(2)
    linear = source_edges @ inverse
    return np.concatenate([linear, target_corners[:, 0, :, None], source_corners[:, 0, :, None]], axis=2), usable


def _edge_coefficients(corners: np.ndarray) -> np.ndarray:
    """corners: (..., 3, 2) -> (..., 3, 3) rows (a, b, c) per edge u -> v with a x + b y + c = cross(v - u, p - u),
    >= 0 for a pixel p inside a positively oriented triangle (edges included)."""
    start, end = corners, np.roll(corners, -1, axis=-2)
    a = -(end[..., 1] - start[..., 1])
    b = end[..., 0] - start[..., 0]
    c = -(a * start[..., 0] + b * start[..., 1])
    return np.stack([a, b, c], axis=-1)


def triangle_ranks(priority: np.ndarray | None, count: int) -> np.ndarray:
    """(T,) rank of each triangle where triangles overlap: the highest rank wins a pixel. priority: (T,) float
    (e.g. minus the target triangles' depth: the nearest wins), ties by index; None = the index itself."""
    if priority is None:
        return np.arange(count)
    ranks = np.empty(count, np.int64)
    ranks[np.argsort(np.asarray(priority, np.float64), kind="stable")] = np.arange(count)
    return ranks


def rasterise_triangles(vertices: np.ndarray, triangles: np.ndarray, usable: np.ndarray, height: int, width: int,
                        priority: np.ndarray | None = None) -> np.ndarray:
    """Which triangle holds each pixel centre: (V, 2), (T, 3), (T,) bool, H, W -> (H, W) int32, -1 = none.

    A pixel under several triangles (an edge they share, or overlapping ones: a turned head's nose over its far
    cheek) gets the one of highest ``triangle_ranks(priority)``. All candidate (triangle, pixel) pairs of the
    triangles' bounding boxes are tested at once: ~2x the face's area of work."""
    index = np.full((height, width), -1, np.int32)
    chosen = np.flatnonzero(usable)
    if chosen.size == 0:
        return index
    ranks = triangle_ranks(priority, len(triangles))
    corners = np.asarray(vertices, np.float64)[triangles[chosen]]  # (n, 3, 2)
    low = np.maximum(np.ceil(corners.min(1)), 0).astype(np.int64)  # (n, 2) first pixel x, y
    high = np.minimum(np.floor(corners.max(1)), [width - 1, height - 1]).astype(np.int64)
    spans = np.maximum(high - low + 1, 0)  # (n, 2)
    counts = spans[:, 0] * spans[:, 1]
    owner = np.repeat(np.arange(len(chosen)), counts)  # (pairs,) one per pixel of each bounding box
    offset = np.arange(owner.size) - np.repeat(np.cumsum(counts) - counts, counts)
    row_length = np.maximum(spans[owner, 0], 1)
    xs = (low[owner, 0] + offset % row_length).astype(np.float64)
    ys = (low[owner, 1] + offset // row_length).astype(np.float64)
    edges = _edge_coefficients(corners).reshape(-1, 9)[owner]  # (pairs, 9): one gather, rows a, b, c per edge
    inside = np.ones(owner.size, bool)
    for edge in range(3):
        a, b, c = edges[:, 3 * edge], edges[:, 3 * edge + 1], edges[:, 3 * edge + 2]
        inside &= a * xs + b * ys + c >= 0
    flat = (ys[inside] * width + xs[inside]).astype(np.int64)
    winner = np.full(height * width, -1, np.int64)
    np.maximum.at(winner, flat, ranks[chosen[owner[inside]]])  # the highest rank per pixel
    by_rank = np.argsort(ranks)  # rank -> triangle
    found = winner >= 0
    index.reshape(-1)[found] = by_rank[winner[found]]
    return index


def rasterise_triangles_reference(vertices: np.ndarray, triangles: np.ndarray, usable: np.ndarray,
                                  height: int, width: int, priority: np.ndarray | None = None) -> np.ndarray:
    """Plain reference of ``rasterise_triangles``: every pixel against every triangle, one triangle at a time in
    rank order (a later one overwrites)."""
    index = np.full((height, width), -1, np.int32)
    grid_y, grid_x = np.mgrid[0:height, 0:width].astype(np.float64)
    for number in np.argsort(triangle_ranks(priority, len(triangles))):
        if not usable[number]:
            continue
        edges = _edge_coefficients(np.asarray(vertices, np.float64)[triangles[number]])  # (3, 3)
        inside = np.ones((height, width), bool)
        for a, b, c in edges:
            inside &= a * grid_x + b * grid_y + c >= 0
        index[inside] = number
    return index


def piecewise_affine_reference(source: np.ndarray, target: np.ndarray, triangles: np.ndarray, usable: np.ndarray,
                               point: tuple[float, float]) -> np.ndarray | None:
    """Plain reference of the map inside the face, one pixel at a time: the source point with the same barycentric
    coordinates in the source triangle as ``point`` has in the (largest-index, usable) target triangle holding it.
    (V, 2), (V, 2), (T, 3), (T,) bool, (x, y) -> (2,) float64, or None outside every usable triangle."""
    x, y = point
    for number in reversed(range(len(triangles))):  # the default ranks: the larger index first
        if not usable[number]:
            continue
        (ax, ay), (bx, by), (cx, cy) = np.asarray(target, np.float64)[triangles[number]]
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        second = ((x - ax) * (cy - ay) - (y - ay) * (cx - ax)) / area  # weight of corner b
        third = ((bx - ax) * (y - ay) - (by - ay) * (x - ax)) / area  # weight of corner c
        if min(second, third, 1.0 - second - third) >= 0:
            corners = np.asarray(source, np.float64)[triangles[number]]
            return (1.0 - second - third) * corners[0] + second * corners[1] + third * corners[2]
    return None


def gaussian_kernel(feather: float) -> np.ndarray:
    """The 1-D feathering kernel: Gaussian of sigma feather / 2, radius ceil(3 sigma), summing to 1 -> (taps,) float64."""
    sigma = feather / 2.0
    radius = max(1, math.ceil(3.0 * sigma))
    taps = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (taps / sigma) ** 2)
    return kernel / kernel.sum()


def _blur(values: np.ndarray, feather: float) -> np.ndarray:
    """(H, W) or (H, W, C) float32 -> the same, blurred by ``gaussian_kernel`` (reflect-101 border)."""
    kernel = gaussian_kernel(feather).astype(np.float32)
    return cv2.sepFilter2D(values, cv2.CV_32F, kernel, kernel, borderType=cv2.BORDER_REFLECT_101)


def feather_weights(inside: np.ndarray, feather: float = FEATHER, blurred: np.ndarray | None = None) -> np.ndarray:
    """Weight of the piecewise-affine map: 0 outside the face and at its outline, rising to 1 about ``feather``
    pixels inside: clip(2 * blur(inside) - 1, 0, 1), the blur Gaussian (``gaussian_kernel``, reflect-101 border),
    snapped to 1 within ``WEIGHT_SNAP``. Around a dropped triangle among kept ones it dips the same way (a pixel of
    a small hole keeps a weight: ``mesh_warp_map`` fills its correction). inside: (H, W) bool -> (H, W) float32;
    blurred: blur(inside) when already at hand."""
    mask = np.asarray(inside, np.float32)
    if feather <= 0:
        return mask
    blurred = _blur(mask, feather) if blurred is None else blurred
    weights = np.clip(2.0 * blurred - 1.0, 0.0, 1.0)
    weights[weights > 1.0 - WEIGHT_SNAP] = 1.0  # the float32 blur of an all-ones patch is 1 - 1e-7: deep inside is exact
    return weights


@dataclasses.dataclass
class MeshWarpMap:
    """map_x, map_y: (H, W) float32 source coordinates (like ``landmarks.warp.tps.WarpMap``); face_weight: (H, W) float32
    weight of the piecewise-affine map (1 - weight: the TPS fallback); fallback: the TPS map used outside the face;
    feather: the blend's width in pixels; triangles: usable / all triangles of the triangulation."""

    map_x: np.ndarray
    map_y: np.ndarray
    face_weight: np.ndarray
    fallback: tps.WarpMap
    feather: float
    usable_triangles: int
    triangles: int

    def valid(self, source_height: int, source_width: int) -> np.ndarray:
        """(H, W) bool: the map samples inside the source image (``landmarks.warp.tps.WarpMap.valid``'s test)."""
        return tps.WarpMap.valid(self, source_height, source_width)  # type: ignore[arg-type]  # reads map_x, map_y


def check_mesh(mesh: np.ndarray, name: str, *, depth: bool = False) -> np.ndarray:
    """A (468, 2 or 3) mesh as float64: its x, y (468, 2), or with ``depth`` its (468, 3), which it must then have;
    anything else raises ValueError naming ``name``."""
    points = np.asarray(mesh, np.float64)
    if points.ndim != 2 or points.shape[0] != MESH_POINTS or points.shape[1] not in ((3,) if depth else (2, 3)):
        raise ValueError(f"{name} must be ({MESH_POINTS}, {'3' if depth else '2 or 3'}), got {points.shape}")
    return points if depth else points[:, :2]


@dataclasses.dataclass(frozen=True)
class TargetLayout:
    """What a warp onto one target mesh needs of the target alone, made once for several sources
    (``target_layout``; the references of a frame), on the grid of ``grid_step`` pixels (``grid_shape``): index:
    (h, w) int32 triangle per grid point (-1: none), rasterised over the triangles usable in the target; weight:
    (h, w) float32 feathered weight; blurred: the blurred mask; feather: the blend's width in pixels (of the frame);
    grid_step: 1 = every pixel; s > 1 = the centres of s x s blocks (``grid_points``); frame_shape: (H, W)."""

    index: np.ndarray
    weight: np.ndarray
    blurred: np.ndarray
    feather: float
    grid_step: int
    frame_shape: tuple[int, int]

    @functools.cached_property
    def frame_weight(self) -> np.ndarray:
        """(H, W) float32: ``weight`` at every pixel of the frame (``upsample``), made once per target."""
        return upsample(self.weight, self.grid_step, *self.frame_shape)


def grid_shape(height: int, width: int, grid_step: int) -> tuple[int, int]:
    """Rows and columns of the grid ``grid_points`` lays over an (H, W) frame: (ceil(H / s), ceil(W / s))."""
    if grid_step < 1:
        raise ValueError(f"grid_step must be >= 1, got {grid_step}")
    return -(-height // grid_step), -(-width // grid_step)


def grid_points(count: int, grid_step: int) -> np.ndarray:
    """Frame coordinates of ``count`` grid points along one axis: the centres of ``grid_step``-pixel blocks,
    s * i + (s - 1) / 2 (pixel i itself for s = 1). Bilinear upsampling by s (``upsample``) interpolates between
    exactly these points. -> (count,) float64."""
    return grid_step * np.arange(count, dtype=np.float64) + (grid_step - 1) / 2.0


@functools.lru_cache(maxsize=8)
def _grid_coordinates(rows: int, cols: int, grid_step: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) float32 x and y frame coordinates of the ``grid_points`` (read-only, made once per grid)."""
    grid_x, grid_y = np.meshgrid(grid_points(cols, grid_step).astype(np.float32),
                                 grid_points(rows, grid_step).astype(np.float32))
    grid_x.setflags(write=False)
    grid_y.setflags(write=False)
    return grid_x, grid_y


def upsample(values: np.ndarray, grid_step: int, height: int, width: int) -> np.ndarray:
    """Grid values (h, w[, C]) float32 -> (H, W[, C]) float32, bilinear between the ``grid_points`` (constant past the
    outermost ones). grid_step 1: the values themselves."""
    if grid_step == 1:
        return values
    rows, cols = values.shape[:2]
    big = cv2.resize(values, (cols * grid_step, rows * grid_step), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(big[:height, :width])


def _feather_of(target: np.ndarray, feather: float | None) -> float:
    if feather is not None:
        return feather
    points = mesh_to_68(target).astype(np.float64)
    return max(FEATHER, FEATHER_IOD * float(np.linalg.norm(points[36:42].mean(0) - points[42:48].mean(0))))


def _layout(target: np.ndarray, depth: np.ndarray | None, usable: np.ndarray, height: int, width: int,
            feather: float, grid_step: int = 1) -> TargetLayout:
    triangles = triangulation()
    # where target triangles overlap (a turned head), the nearest one (smaller z) shows
    priority = -depth[triangles].mean(1) if depth is not None and np.isfinite(depth).all() else None
    rows, cols = grid_shape(height, width, grid_step)
    on_grid = (target - (grid_step - 1) / 2.0) / grid_step  # grid point (i, j) sits at integer pixel (j, i)
    index = rasterise_triangles(on_grid, triangles, usable, rows, cols, priority)
    inside = index >= 0
    mask = inside.astype(np.float32)
    grid_feather = feather / grid_step
    blurred = _blur(mask, grid_feather) if feather > 0 else mask
    return TargetLayout(index, feather_weights(inside, grid_feather, blurred), blurred, float(feather), grid_step,
                        (height, width))


def target_layout(target_mesh: np.ndarray, height: int, width: int, *, feather: float | None = None,
                  min_area: float = MIN_AREA, grid_step: int = 1) -> TargetLayout:
    """The target's share of ``mesh_warp_map`` for several sources: triangles kept when usable in the target (a
    source's folded triangles then become holes, filled as a dropped triangle's are). grid_step: as in
    ``mesh_warp_map``."""
    target = check_mesh(target_mesh, "target_mesh")
    usable = (signed_areas(target, triangulation()) >= min_area) & np.isfinite(target[triangulation()]).all(axis=(1, 2))
    depth = np.asarray(target_mesh, np.float64)[:, 2] if np.shape(target_mesh)[1] == 3 else None
    return _layout(target, depth, usable, height, width, _feather_of(target, feather), grid_step)


def mesh_warp_map(
    source_mesh: np.ndarray,
    target_mesh: np.ndarray,
    height: int,
    width: int,
    *,
    fallback: tps.WarpMap | None = None,
    feather: float | None = None,
    min_area: float = MIN_AREA,
    regularization: float = tps.DEFAULT_REGULARIZATION,
    grid_step: int = 1,
    layout: TargetLayout | None = None,
) -> MeshWarpMap:
    """The backward map of the warp that moves ``source_mesh`` onto ``target_mesh`` in an (H, W) frame (module
    docstring): piecewise affine over the triangulation inside the target face, the 68-point TPS outside.

    source_mesh, target_mesh: (468, 2 or 3) frame pixels; the target's depth, when given, decides which of two
    overlapping triangles shows (the nearer one). fallback: the map outside the face; default
    ``tps.tps_map`` of the meshes' 68 points (border fixed; ``regularization`` as there). grid_step: 1 = exact at
    every pixel; s > 1 = the piecewise-affine correction of the TPS is made at the centres of s x s blocks and
    upsampled bilinearly (the map is continuous across triangles, so the error is where two triangles' affines
    differ, at most about s / 2 times the jump of their gradients: sub-pixel at s = 2 on a face), and a default
    fallback is ``tps_map``'s coarse-grid one. feather: the blend's width in pixels; None = ``FEATHER_IOD`` of the
    target's inter-ocular distance, at least ``FEATHER``. layout: ``target_layout`` of this target, shared by
    several sources (then ``feather`` and ``grid_step`` are the layout's).
    """
    source, target = check_mesh(source_mesh, "source_mesh"), check_mesh(target_mesh, "target_mesh")
    step = layout.grid_step if layout is not None else grid_step
    if fallback is None:  # the meshes as given: with depth, the 68 points' jaw follows the head's yaw
        fallback = tps.tps_map(mesh_to_68(np.asarray(source_mesh)), mesh_to_68(np.asarray(target_mesh)), height, width,
                               regularization=regularization, grid_step=step)
    if fallback.map_x.shape != (height, width):
        raise ValueError(f"fallback map must be ({height}, {width}), got {fallback.map_x.shape}")
    triangles = triangulation()
    affines, usable = triangle_affines(source, target, triangles, min_area)
    if layout is None:
        depth = np.asarray(target_mesh, np.float64)[:, 2] if np.shape(target_mesh)[1] == 3 else None
        layout = _layout(target, depth, usable, height, width, _feather_of(target, feather), step)
        index = layout.index
    else:  # the shared raster: this source's unusable (folded) triangles are holes
        index = np.where((layout.index >= 0) & usable[np.maximum(layout.index, 0)], layout.index, -1)
    feather, blurred, weight = layout.feather, layout.blurred, layout.weight
    rows_count, cols_count = index.shape
    if step > 1:  # the TPS at the grid points (block centres), bilinearly
        grid_x, grid_y = _grid_coordinates(rows_count, cols_count, step)
        fallback_grid = np.stack([cv2.remap(values, grid_x, grid_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                                  for values in (fallback.map_x, fallback.map_y)], axis=-1)  # (h, w, 2)
    else:
        fallback_grid = np.stack([fallback.map_x, fallback.map_y], axis=-1)  # (H, W, 2) float32
    inside = index >= 0
    # the piecewise-affine map as a correction of the TPS: correction = affine(p) - fallback(p) on the triangles
    correction = np.zeros((rows_count, cols_count, 2), np.float32)
    rows, cols = np.nonzero(inside)
    coefficients = affines.reshape(-1, 8)[index[rows, cols]]  # (n, 8): one gather of the 2x4 rows
    offset = (step - 1) / 2.0
    dx, dy = step * cols + offset - coefficients[:, 2], step * rows + offset - coefficients[:, 6]  # p - target_0
    affine_x = coefficients[:, 3] + coefficients[:, 0] * dx + coefficients[:, 1] * dy
    affine_y = coefficients[:, 7] + coefficients[:, 4] * dx + coefficients[:, 5] * dy
    correction[rows, cols] = np.stack([affine_x, affine_y], axis=-1) - fallback_grid[rows, cols]
    holes = (weight > 0) & ~inside
    if holes.any():  # a dropped triangle's pixels: its kept neighbours' correction, Gaussian-averaged (no speck)
        # blurred in a window reaching the kernel's radius past the holes: the same values as over the whole frame
        grid_feather = feather / step
        reach = len(gaussian_kernel(grid_feather)) // 2 + 1
        hole_rows, hole_cols = np.nonzero(holes)
        top, left = max(hole_rows.min() - reach, 0), max(hole_cols.min() - reach, 0)
        bottom, right = min(hole_rows.max() + reach + 1, rows_count), min(hole_cols.max() + reach + 1, cols_count)
        window = np.ascontiguousarray(correction[top:bottom, left:right])
        averaged = _blur(window, grid_feather) / np.maximum(blurred[top:bottom, left:right], 1e-6)[..., None]
        correction[hole_rows, hole_cols] = averaged[hole_rows - top, hole_cols - left]
    correction *= weight[..., None]
    map_x, map_y = (fallback_axis + upsample(np.ascontiguousarray(correction[..., axis]), step, height, width)
                    for axis, fallback_axis in enumerate((fallback.map_x, fallback.map_y)))
    return MeshWarpMap(map_x, map_y, layout.frame_weight, fallback, float(feather), int(usable.sum()), len(triangles))


def warp_mesh(image: np.ndarray, source_mesh: np.ndarray, target_mesh: np.ndarray,
              **settings: Any) -> tuple[np.ndarray, MeshWarpMap]:
    """Warp ``image`` so that ``source_mesh`` lands on ``target_mesh`` (``mesh_warp_map``, then bicubic ``cv2.remap``
    as ``landmarks.warp.tps`` does). image: (H, W, 3) uint8 -> ((H, W, 3) uint8, the map)."""
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
    warp = mesh_warp_map(source_mesh, target_mesh, image.shape[0], image.shape[1], **settings)
    moved = cv2.remap(image, warp.map_x, warp.map_y, tps.INTERPOLATION, borderMode=cv2.BORDER_REPLICATE)
    return moved, warp


# ---- the warp-guided generator's references -----------------------------------------------------------------


def warp_references_mesh(shots: np.ndarray, shot_meshes: np.ndarray, shot_landmarks: np.ndarray,
                         target_mesh: np.ndarray, target_landmarks: np.ndarray, count: int, *,
                         grid_step: int = 4, expression_gain: float = EXPRESSION_GAIN, lid_closed: float = LID_CLOSED,
                         irises: np.ndarray | None = None, gaze: np.ndarray | None = None
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``landmarks.warp.tps.warp_references`` over the face mesh: the ``count`` nearest shots (by the 68 points, the same
    choice), each warped piecewise-affine over the mesh inside the face and by the 68-point TPS outside
    (``mesh_warp_map``), both made on the coarse grid of ``grid_step`` pixels as the TPS references are. What depends
    on the target alone is made once: the TPS system (``tps.tps_maps``) and the face's raster and feathering
    (``target_layout``). A shot without a
    mesh (NaN) is warped by the TPS alone. Where the target opens its mouth wider than a shot, that shot's mouth is
    carried up to ``opening_gain`` times as far (``landmarks.parts.mouth.opening_gain``; 1 = exactly onto the target);
    where it closes its eyes further than the shots, its upper lids are lowered so that the warps show its
    aperture (``landmarks.parts.eyes.lids``, for the median lid gaps of the shots warped; ``lid_closed`` = 0: as measured).
    With ``irises`` ((K, 2, 2) each shot's iris centres, NaN where not found), the warps carry every iris to where
    the target looks (``gaze`` (2, 2), ``landmarks.parts.eyes.iris.gaze_offsets``; None or NaN: where the nearest shot's
    lands) by ``landmarks.parts.eyes.iris_shift.align_irises``.

    shots: (K, S, S, 3) uint8; shot_meshes: (K, 468, 3); shot_landmarks: (K, 68, 2); target_mesh: (468, 3);
    target_landmarks: (68, 2), all in the shots' pixels. -> (warped (count, S, S, 3) uint8, masks (count, S, S)
    float32 in {0, 1}, indices (count,) int), as ``landmarks.warp.tps.warp_references``.
    """
    shots = np.asarray(shots)
    if shots.ndim != 4 or shots.shape[-1] != 3 or shots.dtype != np.uint8:
        raise ValueError(f"shots must be (K, S, S, 3) uint8, got {shots.shape} {shots.dtype}")
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    indices = np.resize(measures.nearest_shots(shot_landmarks, target_landmarks, count), count)  # repeat when K < count
    height, width = shots.shape[1:3]
    unique = [int(index) for index in dict.fromkeys(indices.tolist())]  # a repeated shot (K < count) is warped once
    fallbacks = tps.tps_maps([shot_landmarks[index] for index in unique], target_landmarks, height, width,
                             grid_step=grid_step)
    meshed = [shot_meshes[index] for index in unique if np.isfinite(shot_meshes[index]).all()]
    lids_mesh = close_lids(target_mesh, np.median([lid_gaps(mesh) for mesh in meshed], axis=0), lid_closed
                           ) if meshed else target_mesh
    layout = target_layout(lids_mesh, height, width, grid_step=grid_step)
    warps = []
    for index, fallback in zip(unique, fallbacks):
        warp = fallback
        if np.isfinite(shot_meshes[index]).all():
            source = amplify_mouth(shot_meshes[index], target_mesh,
                                   mouth_gain(shot_landmarks[index], target_landmarks, expression_gain))
            warp = mesh_warp_map(source, lids_mesh, height, width, fallback=fallback, layout=layout)
        warps.append(warp)
    if irises is not None:
        from landmarks.parts.eyes.iris_shift import align_irises

        maps = align_irises([(warp.map_x, warp.map_y) for warp in warps], np.asarray(irises)[unique],
                            target_landmarks, gaze)
        warps = [dataclasses.replace(warp, map_x=map_x, map_y=map_y) for warp, (map_x, map_y) in zip(warps, maps)]
    warped_by_shot, mask_by_shot = {}, {}
    for index, warp in zip(unique, warps):
        warped_by_shot[index] = cv2.remap(shots[index], warp.map_x, warp.map_y, tps.INTERPOLATION,
                                          borderMode=cv2.BORDER_REPLICATE)
        mask_by_shot[index] = warp.valid(height, width)
    warped = np.stack([warped_by_shot[int(index)] for index in indices])
    masks = np.stack([mask_by_shot[int(index)] for index in indices]).astype(np.float32)
    return warped, masks, indices
