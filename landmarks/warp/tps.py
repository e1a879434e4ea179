"""Regularised thin-plate-spline image warping (numpy + OpenCV): the one warp of the project.

Used by the ``tps`` / ``tps_mean3`` baselines of ``lsr eval``, by the warp-guided generator's references
(``warp_references``: training episodes, fine-tuning and the per-frame runtime) and, through the dense
maps it returns, by the training episodes (``lsr.data.episodes``).

Backward mapping: a TPS f is solved from *target* points to *source* points, evaluated on
every output pixel, and the source image is sampled there with ``cv2.remap`` (bicubic: ``INTERPOLATION``).

Dense 68-point sets from a real detector contain near-coincident points (closed lips, eye
corners), for which the plain interpolating TPS system is singular or produces huge weights
that tear the image. So:
  1. control points closer than ``merge_distance`` pixels are merged (their values averaged);
  2. the solve is regularised, K + lambda*I on the kernel block, with coordinates normalised to
     unit RMS spread so lambda is dimensionless ("scaled to the point spread");
  3. a system whose condition number exceeds ``max_condition`` is not solved, and a dense map
     that folds (Jacobian determinant <= 0 on more than ``max_folded_fraction`` of the pixels)
     is rejected; both retry with 10x and 100x lambda, then fall back to a least-squares
     similarity warp, then to the identity. ``WarpResult.method`` says which one was used so
     callers can count fallbacks.
The frame corners and edge midpoints are added as fixed control points so the background
stays put.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect

import cv2
import numpy as np

from landmarks.shape.measures import nearest_shots

DEFAULT_REGULARIZATION = 1e-3
DEFAULT_MERGE_DISTANCE = 1.0  # pixels
DEFAULT_MAX_CONDITION = 1e10
DEFAULT_MAX_FOLDED_FRACTION = 0.0
RETRY_FACTORS = (1.0, 10.0, 100.0)
WARP_METHODS = ("tps", "tps_stronger", "similarity", "identity")
# Bilinear sampling at sub-pixel positions low-passes every warp: on the validation people (real, centre-cropped)
# one TPS-warped shot kept 0.78 of the real frame's Laplacian variance with bilinear and 0.96 with bicubic, and
# the warp-guided default's detail comes from these warps. uint8 in, so OpenCV saturates the cubic overshoot.
INTERPOLATION = cv2.INTER_CUBIC


class DegenerateTpsError(ValueError):
    """The TPS system for these control points cannot be solved reliably (internal; triggers fallback)."""


def _kernel(squared_distance: np.ndarray) -> np.ndarray:
    """TPS radial basis U(r) = r^2 log r^2, written on r^2 (0 at r = 0: the log of a tiny floor times 0)."""
    values = np.log(np.maximum(squared_distance, 1e-300))
    values *= squared_distance
    return values


def _squared_distances(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """(M, 2), (N, 2) -> (M, N) squared Euclidean distances (exact differences: used for the solve)."""
    difference = first[:, None, :] - second[None, :, :]  # (M, N, 2)
    return np.einsum("mnc,mnc->mn", difference, difference)


def _squared_distances_fast(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Same as ``_squared_distances`` via |a|^2 + |b|^2 - 2ab (one matrix product; for dense grids)."""
    squared = np.sum(first**2, axis=1)[:, None] + np.sum(second**2, axis=1)[None, :] - 2.0 * first @ second.T
    return np.maximum(squared, 0.0, out=squared)


@dataclasses.dataclass
class ThinPlateSpline:
    """A fitted 2-D TPS f: R^2 -> R^2. Call it on (M, 2) points -> (M, 2)."""

    control: np.ndarray  # (N, 2) normalised control points
    centre: np.ndarray  # (2,)
    scale: float
    weights: np.ndarray  # (N, 2) kernel weights
    affine: np.ndarray  # (3, 2) rows: constant, x, y
    condition: float

    def __call__(self, points: np.ndarray) -> np.ndarray:
        normalised = (np.asarray(points, np.float64) - self.centre) / self.scale
        kernel = _kernel(_squared_distances_fast(normalised, self.control))  # (M, N)
        linear = self.affine[0] + normalised @ self.affine[1:]
        return kernel @ self.weights + linear

    def dense(self, points: np.ndarray) -> np.ndarray:
        """``self(points)`` for many points (a pixel grid): the kernel block in float32, the affine part in float64.

        About 5x faster; on face warps it differs from the float64 evaluation by under 0.01 px
        (tests/landmarks/warp/test_tps.py), far below the bilinear sampling it feeds."""
        return self.apply(self.basis(points))

    def basis(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What ``dense`` evaluates at ``points`` that depends on the control points alone: (the kernel block
        (M, N) float32, the normalised points (M, 2) float64). Every spline fitted on the same control points
        (another lambda, other values) shares it: ``apply`` then costs one small product."""
        normalised = (np.asarray(points, np.float64) - self.centre) / self.scale
        small, control = normalised.astype(np.float32), self.control.astype(np.float32)
        squared = np.sum(small**2, axis=1)[:, None] + np.sum(control**2, axis=1)[None, :] - 2.0 * small @ control.T
        kernel = np.log(np.maximum(squared, np.float32(1e-30)))
        kernel *= np.maximum(squared, 0.0)
        return kernel, normalised

    def apply(self, basis: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """``dense`` at the points of ``basis`` (``self.basis``, or that of a spline on the same control points)."""
        kernel, normalised = basis
        return kernel @ self.weights.astype(np.float32) + (self.affine[0] + normalised @ self.affine[1:])


def fit_tps(
    control_points: np.ndarray,
    values: np.ndarray,
    regularization: float = DEFAULT_REGULARIZATION,
    max_condition: float = DEFAULT_MAX_CONDITION,
) -> ThinPlateSpline:
    """Solve the (regularised) TPS with f(control_points[i]) ~= values[i].

    control_points: (N, 2) float, N >= 3; values: (N, D) float (D = 2 for one map; several maps onto the same
    control points solve together, two columns each, with one system). regularization: lambda >= 0 on the kernel
    block in unit-RMS-spread coordinates (0 = exact interpolation). Raises DegenerateTpsError when
    the points have no spread or the system's condition number exceeds ``max_condition``.
    """
    control_points = np.asarray(control_points, np.float64)
    values = np.asarray(values, np.float64)
    if control_points.ndim != 2 or control_points.shape[1] != 2 or values.ndim != 2 or len(values) != len(control_points):
        raise ValueError(f"control points must be (N, 2) and values (N, D), got {control_points.shape}, {values.shape}")
    if regularization < 0:
        raise ValueError(f"regularization must be >= 0, got {regularization}")
    count = len(control_points)
    if count < 3:
        raise DegenerateTpsError(f"a TPS needs >= 3 control points, got {count}")
    centre = control_points.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((control_points - centre) ** 2, axis=1))))
    if not scale > 1e-9:
        raise DegenerateTpsError("control points have no spread")
    normalised = (control_points - centre) / scale
    system = np.zeros((count + 3, count + 3))
    system[:count, :count] = _kernel(_squared_distances(normalised, normalised)) + regularization * np.eye(count)
    system[:count, count] = 1.0
    system[:count, count + 1 :] = normalised
    system[count:, :count] = system[:count, count:].T
    condition = float(np.linalg.cond(system))
    if not np.isfinite(condition) or condition > max_condition:
        raise DegenerateTpsError(f"TPS system ill-conditioned (condition number {condition:.3g})")
    right_side = np.zeros((count + 3, values.shape[1]))
    right_side[:count] = values
    solution = np.linalg.solve(system, right_side)
    return ThinPlateSpline(normalised, centre, scale, solution[:count], solution[count:], condition)


def merge_close_points(
    control_points: np.ndarray, values: np.ndarray, min_distance: float
) -> tuple[np.ndarray, np.ndarray]:
    """Greedily merge control points closer than ``min_distance`` (their values averaged).

    (N, 2), (N, D) -> (M, 2), (M, D) with M <= N; order of first occurrence is kept.
    """
    close = _squared_distances(control_points, control_points) < min_distance**2  # (N, N)
    if np.count_nonzero(close) == len(control_points):  # only the diagonal: nothing to merge (the usual case)
        return np.array(control_points, np.float64), np.array(values, np.float64)
    clusters: list[list[int]] = []
    owner = np.full(len(control_points), -1)
    for index in range(len(control_points)):
        if owner[index] >= 0:
            continue
        members = np.flatnonzero(close[index] & (owner < 0))  # unassigned points near this representative
        owner[members] = len(clusters)
        clusters.append(members.tolist() or [index])
    merged_control = np.array([control_points[c].mean(axis=0) for c in clusters])
    merged_values = np.array([values[c].mean(axis=0) for c in clusters])
    return merged_control, merged_values


def border_points(height: int, width: int) -> np.ndarray:
    """The 4 frame corners and 4 edge midpoints, (8, 2) x, y pixel centres."""
    right, bottom = width - 1.0, height - 1.0
    return np.array([[0, 0], [right / 2, 0], [right, 0], [right, bottom / 2],
                     [right, bottom], [right / 2, bottom], [0, bottom], [0, bottom / 2]], np.float64)


def folded_fraction(map_x: np.ndarray, map_y: np.ndarray) -> float:
    """Share of pixels where the dense map (H, W) x 2 folds: Jacobian determinant <= 0 (``np.gradient``'s
    differences: central inside, one-sided at the edges)."""
    dx_du, dx_dv = _gradient(map_x, 1), _gradient(map_x, 0)
    dy_du, dy_dv = _gradient(map_y, 1), _gradient(map_y, 0)
    determinant = dx_du * dy_dv - dx_dv * dy_du
    return float(np.mean(~(determinant > 0)))


def _gradient(values: np.ndarray, axis: int) -> np.ndarray:
    """``np.gradient(values, axis=axis)`` of a 2-D array with at least 2 samples along ``axis``, the same numbers
    (its unit spacing: central differences halved inside, one-sided at the ends) without its general set-up."""
    values = np.asarray(values)
    if values.shape[axis] < 3:
        return np.gradient(values, axis=axis)
    moved = np.moveaxis(values, axis, 0)
    kind = np.result_type(values.dtype, np.float64) if values.dtype.kind in "iub" else values.dtype  # as np.gradient
    out = np.empty(moved.shape, kind)
    np.subtract(moved[2:], moved[:-2], out=out[1:-1])
    out[1:-1] /= 2.0
    out[0] = moved[1] - moved[0]
    out[-1] = moved[-1] - moved[-2]
    return np.moveaxis(out, 0, axis)


def fit_similarity(control_points: np.ndarray, values: np.ndarray) -> np.ndarray | None:
    """Least-squares similarity (Umeyama, no reflection) control -> values: (2, 3) matrix, or None
    when the control points have no spread."""
    source_centre, value_centre = control_points.mean(axis=0), values.mean(axis=0)
    centred_source, centred_values = control_points - source_centre, values - value_centre
    variance = float(np.mean(np.sum(centred_source**2, axis=1)))
    if not variance > 1e-9:
        return None
    covariance = centred_values.T @ centred_source / len(control_points)
    u, singular, vt = np.linalg.svd(covariance)
    sign = np.diag([1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    rotation = u @ sign @ vt
    scale = float(np.trace(np.diag(singular) @ sign)) / variance
    if not scale > 1e-6:
        return None
    matrix = np.zeros((2, 3))
    matrix[:, :2] = scale * rotation
    matrix[:, 2] = value_centre - scale * rotation @ source_centre
    return matrix


@dataclasses.dataclass
class WarpMap:
    """A dense backward map: output pixel (y, x) samples the source at (map_x[y, x], map_y[y, x]).

    map_x, map_y: (H, W) float32 source pixel coordinates; method: one of WARP_METHODS; regularization:
    lambda used (TPS only); folded_fraction of the accepted map; reason: why earlier options were
    rejected ('' if none)."""

    map_x: np.ndarray
    map_y: np.ndarray
    method: str
    regularization: float
    folded_fraction: float
    reason: str

    def valid(self, source_height: int, source_width: int) -> np.ndarray:
        """(H, W) bool: the map samples inside the source image (elsewhere the warp only repeats its border)."""
        slack = 1e-3  # border pixels of an exact identity map come out at -1e-15: still inside
        return ((self.map_x >= -slack) & (self.map_x <= source_width - 1 + slack)
                & (self.map_y >= -slack) & (self.map_y <= source_height - 1 + slack))


@dataclasses.dataclass
class WarpResult:
    """image: (H, W, 3) uint8; method: one of WARP_METHODS; regularization: lambda used (TPS only);
    folded_fraction of the accepted map; reason: why earlier options were rejected ('' if none)."""

    image: np.ndarray
    method: str
    regularization: float
    folded_fraction: float
    reason: str


def _pixel_grid(height: int, width: int) -> np.ndarray:
    grid_y, grid_x = np.mgrid[0:height, 0:width]
    return np.stack([grid_x.ravel(), grid_y.ravel()], axis=1).astype(np.float64)  # (H*W, 2) x, y


def _interpolation_matrix(size: int, coarse: np.ndarray) -> np.ndarray:
    """(size, len(coarse)) linear interpolation weights from samples at ``coarse`` (increasing, ends 0 and size-1)."""
    positions = np.arange(size, dtype=np.float64)
    upper = np.clip(np.searchsorted(coarse, positions, side="right"), 1, len(coarse) - 1)
    lower = upper - 1
    fraction = (positions - coarse[lower]) / (coarse[upper] - coarse[lower])
    matrix = np.zeros((size, len(coarse)))
    matrix[np.arange(size), lower] = 1.0 - fraction
    matrix[np.arange(size), upper] += fraction
    return matrix


class _Grid:
    """Where a smooth R^2 -> R^2 map is evaluated: every pixel (step 1), or every ``step`` pixels with the last
    row and column included, then interpolated bilinearly (``densify``). A TPS is smooth, so at step 4 the maps
    differ from the exact ones by a fraction of a pixel (tests/landmarks/warp/test_tps_references.py) at ~1/16 of the cost."""

    def __init__(self, height: int, width: int, step: int) -> None:
        self.height, self.width, self.step = height, width, max(1, int(step))
        if self.step == 1:
            self.points = _pixel_grid(height, width)
            self.shape = (height, width)
            self.ys, self.xs = np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64)
            return
        self.ys = np.unique(np.append(np.arange(0, height, self.step, dtype=np.float64), height - 1.0))
        self.xs = np.unique(np.append(np.arange(0, width, self.step, dtype=np.float64), width - 1.0))
        grid_y, grid_x = np.meshgrid(self.ys, self.xs, indexing="ij")
        self.points = np.stack([grid_x.ravel(), grid_y.ravel()], axis=1)  # (h*w, 2) x, y
        self.shape = (len(self.ys), len(self.xs))
        # float32: coordinates up to a few thousand pixels keep ~1e-3 px, and the two products are 3x faster
        self._rows = _interpolation_matrix(height, self.ys).astype(np.float32)
        self._cols = _interpolation_matrix(width, self.xs).astype(np.float32)

    def evaluate(self, function) -> tuple[np.ndarray, np.ndarray]:
        """function on the grid points -> (map_x, map_y) on the grid, each ``self.shape``."""
        mapped = function(self.points)
        return mapped[:, 0].reshape(self.shape), mapped[:, 1].reshape(self.shape)

    def densify(self, values: np.ndarray) -> np.ndarray:
        """Grid values -> (H, W) float32 at every pixel."""
        if self.step == 1:
            return values.astype(np.float32)
        return self._rows @ values.astype(np.float32) @ self._cols.T


@functools.lru_cache(maxsize=8)
def _grid(height: int, width: int, step: int) -> _Grid:
    """The ``_Grid`` of an (H, W) frame at ``step``, made once (its arrays read-only): a video's frames share it."""
    grid = _Grid(height, width, step)
    for values in vars(grid).values():
        if isinstance(values, np.ndarray):
            values.setflags(write=False)
    return grid


def _remap(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    return cv2.remap(image, map_x.astype(np.float32), map_y.astype(np.float32), INTERPOLATION,
                     borderMode=cv2.BORDER_REPLICATE)


@dataclasses.dataclass
class GridMap(WarpMap):
    """``tps_map``'s backward map on its evaluation grid, before it is made dense: for callers that do more smooth
    per-pixel work on it (``landmarks.scene.compositing``'s head layer) at the grid's cost, then densify once.

    A ``WarpMap`` whose map_x, map_y are ``grid.shape`` source pixel coordinates at the grid's points (``grid.ys``,
    ``grid.xs``: pixel rows and columns, ends included); ``dense`` makes it the per-pixel one."""

    grid: _Grid

    def densify(self, values: np.ndarray) -> np.ndarray:
        """Values on the grid (``grid.shape``) -> (H, W) float32 at every pixel, interpolated bilinearly."""
        return self.grid.densify(values)

    def dense(self) -> WarpMap:
        return WarpMap(self.densify(self.map_x), self.densify(self.map_y), self.method, self.regularization,
                       self.folded_fraction, self.reason)


def tps_map(source_points: np.ndarray, target_points: np.ndarray, height: int, width: int, *,
            regularization: float = DEFAULT_REGULARIZATION, merge_distance: float = DEFAULT_MERGE_DISTANCE,
            max_condition: float = DEFAULT_MAX_CONDITION, max_folded_fraction: float = DEFAULT_MAX_FOLDED_FRACTION,
            fix_border: bool = True, grid_step: int = 1) -> WarpMap:
    """The backward map of the warp that moves ``source_points`` onto ``target_points`` in an (H, W) frame.

    source_points, target_points: (N, 2) x, y pixels (rows with NaN in either are ignored). grid_step: see
    ``_Grid`` (1 = exact; > 1 evaluates and checks folds on a coarse grid). Never raises for degenerate point
    sets (falls back, see the module docstring).
    """
    return tps_grid_map(source_points, target_points, height, width, regularization=regularization,
                        merge_distance=merge_distance, max_condition=max_condition,
                        max_folded_fraction=max_folded_fraction, fix_border=fix_border, grid_step=grid_step).dense()


def tps_grid_map(source_points: np.ndarray, target_points: np.ndarray, height: int, width: int, *,
                 regularization: float = DEFAULT_REGULARIZATION, merge_distance: float = DEFAULT_MERGE_DISTANCE,
                 max_condition: float = DEFAULT_MAX_CONDITION,
                 max_folded_fraction: float = DEFAULT_MAX_FOLDED_FRACTION, fix_border: bool = True,
                 grid_step: int = 1) -> GridMap:
    """``tps_map`` on its grid, not yet dense (``GridMap``); the same arguments, the same fallbacks."""
    source_points = np.asarray(source_points, np.float64)
    target_points = np.asarray(target_points, np.float64)
    if source_points.shape != target_points.shape or source_points.ndim != 2 or source_points.shape[1] != 2:
        raise ValueError(f"point sets must both be (N, 2), got {source_points.shape}, {target_points.shape}")
    valid = np.all(np.isfinite(source_points), axis=1) & np.all(np.isfinite(target_points), axis=1)
    landmark_targets, landmark_sources = target_points[valid], source_points[valid]
    control, values = landmark_targets, landmark_sources
    if fix_border:
        fixed = border_points(height, width)
        control, values = np.concatenate([control, fixed]), np.concatenate([values, fixed])
    control, values = merge_close_points(control, values, merge_distance)
    return _grid_maps(control, values, landmark_targets, [landmark_sources], _grid(height, width, grid_step),
                      regularization, max_condition, max_folded_fraction)[0]


def _grid_maps(control: np.ndarray, values: np.ndarray, landmark_targets: np.ndarray,
               landmark_sources: list[np.ndarray], grid: _Grid, regularization: float, max_condition: float,
               max_folded_fraction: float) -> list[GridMap]:
    """``tps_grid_map``'s tries for one or more sets of values on the same merged control points (N, 2): values
    (N, 2 * sets). The TPS with lambda ``regularization`` times each of ``RETRY_FACTORS`` until one neither fails nor
    folds, each try one solve for every set still without a map, all on one kernel (``ThinPlateSpline.basis``);
    a set whose tries all fail or fold takes the similarity of its landmarks (``landmark_targets``, its
    ``landmark_sources``), else the identity (``_rigid_map``)."""
    count = values.shape[1] // 2
    maps: list[GridMap | None] = [None] * count
    reasons: list[list[str]] = [[] for _ in range(count)]
    pending, basis = list(range(count)), None
    for attempt, factor in enumerate(RETRY_FACTORS):
        columns = values[:, [column for slot in pending for column in (2 * slot, 2 * slot + 1)]]
        try:
            spline = fit_tps(control, columns, regularization * factor, max_condition)
        except DegenerateTpsError as exc:
            for slot in pending:
                reasons[slot].append(str(exc))
            break  # more regularisation does not help a system without spread / affine rank
        basis = spline.basis(grid.points) if basis is None else basis
        mapped = spline.apply(basis)  # source x, y per output pixel (on the grid), two columns per set left
        left = []
        for column, slot in enumerate(pending):
            map_x, map_y = mapped[:, 2 * column].reshape(grid.shape), mapped[:, 2 * column + 1].reshape(grid.shape)
            folds = folded_fraction(map_x, map_y)  # judged on the grid
            if np.all(np.isfinite(map_x)) and np.all(np.isfinite(map_y)) and folds <= max_folded_fraction:
                maps[slot] = GridMap(map_x, map_y, "tps" if attempt == 0 else "tps_stronger",
                                     regularization * factor, folds, "; ".join(reasons[slot]), grid)
            else:
                reasons[slot].append(_folded_reason(regularization * factor, folds))
                left.append(slot)
        pending = left
        if not pending:
            break
    for slot in pending:
        maps[slot] = _rigid_map(landmark_targets, landmark_sources[slot], grid, reasons[slot])
    return maps  # type: ignore[return-value]


def _rigid_map(landmark_targets: np.ndarray, landmark_sources: np.ndarray, grid: _Grid, reasons: list[str]) -> GridMap:
    """Where every TPS try failed: the least-squares similarity of the landmarks, else the identity."""
    matrix = fit_similarity(landmark_targets, landmark_sources) if len(landmark_targets) >= 2 else None
    if matrix is not None:  # affine: bilinear densifying is exact
        map_x, map_y = grid.evaluate(lambda p: p @ matrix[:, :2].T + matrix[:, 2])
        return GridMap(map_x, map_y, "similarity", 0.0, 0.0, "; ".join(reasons), grid)
    reasons = [*reasons, "no similarity: landmarks have no spread"]
    map_x, map_y = grid.evaluate(lambda p: p)
    return GridMap(map_x, map_y, "identity", 0.0, 0.0, "; ".join(reasons), grid)


def _folded_reason(regularization: float, folds: float) -> str:
    return f"lambda {regularization:.3g}: {folds:.2%} of pixels folded"


# tps_map's keyword options and their defaults: the settings every warp of this module forwards
_TPS_MAP_DEFAULTS = {name: parameter.default for name, parameter in inspect.signature(tps_map).parameters.items()
                     if parameter.kind is inspect.Parameter.KEYWORD_ONLY}


def tps_maps(source_sets: list[np.ndarray], target_points: np.ndarray, height: int, width: int, **settings) -> list[WarpMap]:
    """``tps_map`` of several source point sets onto one target, sharing what depends on the target alone.

    The control points of a backward TPS are the *target* points, so the references of a frame (all warped onto
    its landmarks) share the merge, the TPS system (one solve, two right-hand columns per set) and the kernel on
    the grid; only the fold check and the dense maps are per set. Same maps as ``tps_map`` per set up to float
    rounding: the same tries and fallbacks (``_grid_maps``), those that fold going on together, one solve per try.
    A set whose missing points differ from the target's goes through ``tps_map`` alone.
    """
    # settings: the keyword options of ``tps_map`` (its defaults where not given)
    unknown = set(settings) - set(_TPS_MAP_DEFAULTS)
    if unknown:
        raise TypeError(f"tps_maps got unknown settings {sorted(unknown)}; see tps_map")
    options = {**_TPS_MAP_DEFAULTS, **settings}
    regularization, merge_distance, max_condition = options["regularization"], options["merge_distance"], options["max_condition"]
    max_folded_fraction, fix_border, grid_step = options["max_folded_fraction"], options["fix_border"], options["grid_step"]
    target = np.asarray(target_points, np.float64)
    sources = [np.asarray(points, np.float64) for points in source_sets]
    found = np.all(np.isfinite(target), axis=1) if target.ndim == 2 else None
    shared = [index for index, points in enumerate(sources) if found is not None and points.shape == target.shape
              and np.array_equal(np.all(np.isfinite(points), axis=1) & found, found)]
    maps: list[WarpMap | None] = [None] * len(sources)
    if shared and target.shape[1:] == (2,):
        control = target[found]
        values = np.concatenate([sources[index][found] for index in shared], axis=1)  # (N, 2 * sets)
        if fix_border:
            fixed = border_points(height, width)
            control, values = np.concatenate([control, fixed]), np.concatenate([values, np.tile(fixed, len(shared))])
        control, values = merge_close_points(control, values, merge_distance)
        shared_maps = _grid_maps(control, values, target[found], [sources[index][found] for index in shared],
                                 _grid(height, width, grid_step), regularization, max_condition, max_folded_fraction)
        for index, grid_map in zip(shared, shared_maps):
            maps[index] = grid_map.dense()
    return [found_map if found_map is not None else tps_map(sources[index], target, height, width, **options)
            for index, found_map in enumerate(maps)]


def warp_tps(image: np.ndarray, source_points: np.ndarray, target_points: np.ndarray, **settings) -> WarpResult:
    """Warp ``image`` so that ``source_points`` land on ``target_points`` (``tps_map``, then ``cv2.remap``).

    image: (H, W, 3) uint8; source_points, target_points: (N, 2) x, y pixels (rows with NaN in
    either are ignored); settings: the keyword options of ``tps_map`` (regularization, merge_distance,
    max_condition, max_folded_fraction, fix_border, grid_step). Returns a WarpResult; never raises for
    degenerate point sets (falls back).
    """
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
    height, width = image.shape[:2]
    warp = tps_map(source_points, target_points, height, width, **settings)
    image = image.copy() if warp.method == "identity" else _remap(image, warp.map_x, warp.map_y)
    return WarpResult(image, warp.method, warp.regularization, warp.folded_fraction, warp.reason)


# ---- references for the warp-guided generator and the tps_mean3 baseline ------------------------------------


def warp_references(
    shots: np.ndarray,
    shot_landmarks: np.ndarray,
    target_landmarks: np.ndarray,
    count: int,
    *,
    grid_step: int = 4,
    irises: np.ndarray | None = None,
    gaze: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``count`` nearest shots, each TPS-warped onto the target landmarks, with validity masks.

    shots: (K, S, S, 3) uint8; shot_landmarks: (K, 68, 2); target_landmarks: (68, 2), all in the shots' pixels.
    -> (warped (count, S, S, 3) uint8, masks (count, S, S) float32 in {0, 1}, indices (count,) int). With
    fewer than ``count`` shots the nearest ones repeat (the network always sees ``count`` references). With
    ``irises`` ((K, 2, 2) each shot's iris centres, NaN where not found), the warps carry every iris to where the
    target looks (``gaze`` (2, 2), ``landmarks.parts.eyes.iris.gaze_offsets``; None or NaN: where the nearest shot's lands) by
    ``landmarks.parts.eyes.iris_shift.align_irises``.
    """
    shots = np.asarray(shots)
    if shots.ndim != 4 or shots.shape[-1] != 3 or shots.dtype != np.uint8:
        raise ValueError(f"shots must be (K, S, S, 3) uint8, got {shots.shape} {shots.dtype}")
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    indices = nearest_shots(shot_landmarks, target_landmarks, count)
    indices = np.resize(indices, count)  # repeat the nearest when K < count
    height, width = shots.shape[1:3]
    unique = [int(index) for index in dict.fromkeys(indices.tolist())]  # nearest first; a repeated shot is warped once
    warps = tps_maps([shot_landmarks[index] for index in unique], target_landmarks, height, width, grid_step=grid_step)
    maps = [None if warp.method == "identity" else (warp.map_x, warp.map_y) for warp in warps]
    if irises is not None:
        from landmarks.parts.eyes.iris_shift import align_irises

        grid = np.mgrid[0:height, 0:width].astype(np.float32)
        maps = align_irises([(grid[1], grid[0]) if pair is None else pair for pair in maps], np.asarray(irises)[unique],
                            target_landmarks, gaze)
    by_shot = {}
    for index, pair in zip(unique, maps):
        if pair is None:
            by_shot[index] = (shots[index], np.ones((height, width), bool))
        else:
            map_x, map_y = pair
            warp = dataclasses.replace(warps[unique.index(index)], map_x=map_x, map_y=map_y)
            by_shot[index] = (_remap(shots[index], map_x, map_y), warp.valid(height, width))
    warped = np.stack([by_shot[int(index)][0] for index in indices])
    masks = np.stack([by_shot[int(index)][1] for index in indices]).astype(np.float32)
    return warped, masks, indices


def jittered_copy(image: np.ndarray, points: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A small random similarity of an image and its landmarks (rotation <= 5 deg, scale +-5 %, shift <= 4 %).

    The stand-in reference of a single shot (K = 1): warping it back onto the shot's landmarks is imperfect
    the way a real other shot is, instead of an identity copy the network would learn to trust blindly.
    image: (S, S, 3) uint8; points: (68, 2) -> (image, points) of the same shapes.
    """
    size = image.shape[0]
    angle, scale = rng.uniform(-5.0, 5.0), rng.uniform(0.95, 1.05)
    shift = rng.uniform(-0.04, 0.04, size=2) * size
    matrix = cv2.getRotationMatrix2D(((size - 1) / 2, (size - 1) / 2), angle, scale)
    matrix[:, 2] += shift
    moved = cv2.warpAffine(image, matrix, (size, size), flags=INTERPOLATION, borderMode=cv2.BORDER_REPLICATE)
    return moved, np.asarray(points, np.float64) @ matrix[:, :2].T + matrix[:, 2]


def leave_one_out_references(
    shots: np.ndarray, shot_landmarks: np.ndarray, count: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """For each shot as a target, the ``count`` nearest *other* shots warped onto it (subject fine-tuning).

    shots: (K, S, S, 3) uint8; shot_landmarks: (K, 68, 2) -> (warped (K, count, S, S, 3) uint8, masks
    (K, count, S, S) float32). With K = 1 the other shot is a jittered copy of the shot (``jittered_copy``).
    """
    shots = np.asarray(shots)
    rng = np.random.default_rng(seed)
    warped, masks = [], []
    for index in range(len(shots)):
        others = [i for i in range(len(shots)) if i != index]
        if others:
            pool, pool_points = shots[others], np.asarray(shot_landmarks)[others]
        else:
            moved, moved_points = jittered_copy(shots[index], shot_landmarks[index], rng)
            pool, pool_points = moved[None], moved_points[None]
        images, valid, _ = warp_references(pool, pool_points, shot_landmarks[index], count)
        warped.append(images)
        masks.append(valid)
    return np.stack(warped), np.stack(masks)
