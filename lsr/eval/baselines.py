"""No-learning baselines, evaluated in the same run and through the same ``Method`` protocol
(``lsr.eval.protocol.Method``) as a trained model.

nearest_shot  copies the source shot whose landmarks are closest to the target's. Distance:
              ``landmarks.shape.measures.landmark_distance``, the NMKE of the raw landmarks (no alignment; mean
              point distance over the target's eye distance); the choice is ``landmarks.shape.measures.nearest_shots``,
              the one the warp-guided generator's references use. Raw, because the copied pixels keep
              their position: a shot whose head sits elsewhere in the frame is a worse copy even if the
              pose matches.
tps           warps that nearest shot onto the target landmarks with a regularised thin-plate
              spline (``landmarks.warp.tps``), frame corners and edge midpoints fixed. Counts how often
              each warp method (tps / tps_stronger / similarity / identity) was used.
tps_mean3     the per-pixel mean of the 3 nearest shots (fewer when K < 3; no shot twice), each warped
              as by ``tps``, rounded to uint8. Averaging buys PSNR/SSIM at the cost of blur (the
              ``sharpness`` metric shows it): the bar a warp-guided model must clear without blurring.
mesh          warps the same nearest shot from its 468-point face mesh onto the target's, piecewise affine over
              the mesh triangles inside the face and the ``tps`` warp (the same map) outside, feathered across the
              outline and around folded triangles (``landmarks.warp.piecewise_affine``). Needs meshes (``needs_meshes``: the
              runner passes ``shot_meshes`` and ``target_meshes``); a frame whose shot or target has no mesh is
              warped by ``tps`` alone (counted as ``without_mesh``). ``warp_counts`` counts the method of the TPS
              used outside the face.
mesh_mean3    the per-pixel mean of the 3 nearest shots, each warped as by ``mesh``.
"""

from __future__ import annotations

import collections

import numpy as np

from landmarks.warp import piecewise_affine as mesh_warp
from landmarks.shape import measures
from landmarks.warp import tps


def check_method_inputs(shots: list[np.ndarray], shot_landmarks: np.ndarray, target_landmarks: np.ndarray) -> None:
    """Shape contract of ``Method.reenact``: K shots (S, S, 3) uint8, (K, 68, 2), (T, 68, 2)."""
    if not shots:
        raise ValueError("reenact needs at least one shot")
    size = shots[0].shape
    for shot in shots:
        if shot.dtype != np.uint8 or shot.ndim != 3 or shot.shape[2] != 3 or shot.shape != size:
            raise ValueError(f"shots must all be (S, S, 3) uint8 of one size, got {shot.shape} {shot.dtype}")
    if shot_landmarks.shape != (len(shots), 68, 2):
        raise ValueError(f"shot_landmarks must be ({len(shots)}, 68, 2), got {shot_landmarks.shape}")
    if target_landmarks.ndim != 3 or target_landmarks.shape[1:] != (68, 2):
        raise ValueError(f"target_landmarks must be (T, 68, 2), got {target_landmarks.shape}")


def check_mesh_inputs(shot_meshes: np.ndarray, target_meshes: np.ndarray, shots: int, targets: int) -> None:
    """Shape contract of a mesh method's extra inputs: (K, 468, 3) and (T, 468, 3) float (NaN rows: no mesh)."""
    points = mesh_warp.MESH_POINTS
    if np.shape(shot_meshes) != (shots, points, 3):
        raise ValueError(f"shot_meshes must be ({shots}, {points}, 3), got {np.shape(shot_meshes)}")
    if np.shape(target_meshes) != (targets, points, 3):
        raise ValueError(f"target_meshes must be ({targets}, {points}, 3), got {np.shape(target_meshes)}")


def nearest_shot_indices(shot_landmarks: np.ndarray, target_landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per target, the shot ``landmarks.shape.measures.nearest_shots`` picks first, and its raw-landmark NMKE.

    shot_landmarks: (K, 68, 2) (NaN rows = shot without a face; never chosen unless all are);
    target_landmarks: (T, 68, 2). Returns (T,) int indices, (T,) float distances (NaN when the
    target or every shot lacks landmarks; index 0 then).
    """
    distances = measures.landmark_distance(shot_landmarks[None, :], target_landmarks[:, None])  # (T, K)
    # one choice of "nearest" for the baselines, the pose buckets and the warp-guided references
    indices = np.array([measures.nearest_shots(shot_landmarks, target, 1)[0] for target in target_landmarks], dtype=np.int64)
    return indices, distances[np.arange(len(indices)), indices]


class NearestShot:
    """Copy the nearest source shot (see the module docstring)."""

    name = "nearest_shot"

    def reenact(self, shots: list[np.ndarray], shot_landmarks: np.ndarray, target_landmarks: np.ndarray) -> np.ndarray:
        """shots: K x (S, S, 3) uint8; shot_landmarks: (K, 68, 2); target_landmarks: (T, 68, 2)
        -> (T, S, S, 3) uint8."""
        check_method_inputs(shots, shot_landmarks, target_landmarks)
        indices, _ = nearest_shot_indices(shot_landmarks, target_landmarks)
        return np.stack([shots[i] for i in indices])


class TpsWarp:
    """Warp the nearest shot onto the target landmarks with a regularised TPS (see the module docstring).

    ``warp_counts`` counts the warp method used per output frame over the object's lifetime.
    """

    name = "tps"

    def __init__(
        self,
        regularization: float = tps.DEFAULT_REGULARIZATION,
        merge_distance: float = tps.DEFAULT_MERGE_DISTANCE,
        max_folded_fraction: float = tps.DEFAULT_MAX_FOLDED_FRACTION,
        fix_border: bool = True,
    ) -> None:
        self.regularization = regularization
        self.fix_border = fix_border
        self.merge_distance = merge_distance
        self.max_folded_fraction = max_folded_fraction
        self.warp_counts: collections.Counter[str] = collections.Counter({m: 0 for m in tps.WARP_METHODS})

    def reenact(self, shots: list[np.ndarray], shot_landmarks: np.ndarray, target_landmarks: np.ndarray) -> np.ndarray:
        """shots: K x (S, S, 3) uint8; shot_landmarks: (K, 68, 2); target_landmarks: (T, 68, 2)
        -> (T, S, S, 3) uint8."""
        check_method_inputs(shots, shot_landmarks, target_landmarks)
        indices, _ = nearest_shot_indices(shot_landmarks, target_landmarks)
        return np.stack([self.warp(shots[i], shot_landmarks[i], target) for i, target in zip(indices, target_landmarks)])

    def warp(self, shot: np.ndarray, shot_points: np.ndarray, target_points: np.ndarray) -> np.ndarray:
        """One shot (S, S, 3) uint8 warped from shot_points (68, 2) onto target_points (68, 2) -> (S, S, 3) uint8.

        Exact map (grid_step 1): the baselines stay the exact TPS, not the coarse-grid one of the references."""
        result = tps.warp_tps(shot, shot_points, target_points, regularization=self.regularization,
                              merge_distance=self.merge_distance, max_folded_fraction=self.max_folded_fraction,
                              fix_border=self.fix_border, grid_step=1)
        self.warp_counts[result.method] += 1
        return result.image


class TpsMean3(TpsWarp):
    """Per-pixel mean of the ``SHOTS`` nearest shots, each warped as by ``TpsWarp`` (see the module docstring).

    ``warp_counts`` counts every warp, so a frame adds min(3, K) to it.
    """

    name = "tps_mean3"
    SHOTS = 3

    def reenact(self, shots: list[np.ndarray], shot_landmarks: np.ndarray, target_landmarks: np.ndarray) -> np.ndarray:
        """shots: K x (S, S, 3) uint8; shot_landmarks: (K, 68, 2); target_landmarks: (T, 68, 2)
        -> (T, S, S, 3) uint8."""
        check_method_inputs(shots, shot_landmarks, target_landmarks)
        outputs = []
        for target in target_landmarks:
            nearest = measures.nearest_shots(shot_landmarks, target, self.SHOTS)  # min(3, K) distinct shots, nearest first
            warped = np.stack([self.warp(shots[i], shot_landmarks[i], target) for i in nearest])  # (n, S, S, 3)
            outputs.append(np.rint(warped.mean(axis=0, dtype=np.float64)).astype(np.uint8))
        return np.stack(outputs)


class MeshWarp(TpsWarp):
    """Warp the nearest shot onto the target over the face mesh (see the module docstring).

    ``warp_counts``: per warp, the method of the TPS outside the face (tps / tps_stronger / similarity / identity),
    and ``without_mesh`` for frames warped by the TPS alone."""

    name = "mesh"
    needs_meshes = True

    def __init__(self, feather: float | None = None, **tps_settings: float | bool) -> None:
        super().__init__(**tps_settings)  # type: ignore[arg-type]
        self.feather = feather
        self.warp_counts["without_mesh"] = 0

    def reenact(self, shots: list[np.ndarray], shot_landmarks: np.ndarray, target_landmarks: np.ndarray, *,
                shot_meshes: np.ndarray, target_meshes: np.ndarray) -> np.ndarray:
        """shots: K x (S, S, 3) uint8; shot_landmarks: (K, 68, 2); target_landmarks: (T, 68, 2); shot_meshes:
        (K, 468, 3); target_meshes: (T, 468, 3) (NaN rows: no mesh) -> (T, S, S, 3) uint8."""
        check_method_inputs(shots, shot_landmarks, target_landmarks)
        check_mesh_inputs(shot_meshes, target_meshes, len(shots), len(target_landmarks))
        indices, _ = nearest_shot_indices(shot_landmarks, target_landmarks)
        return np.stack([self.warp_mesh(shots[i], shot_landmarks[i], target, shot_meshes[i], target_mesh)
                         for i, target, target_mesh in zip(indices, target_landmarks, target_meshes)])

    def warp_mesh(self, shot: np.ndarray, shot_points: np.ndarray, target_points: np.ndarray,
                  shot_mesh: np.ndarray, target_mesh: np.ndarray) -> np.ndarray:
        """One shot (S, S, 3) uint8 warped from shot_mesh (468, 3) onto target_mesh (468, 3) -> (S, S, 3) uint8; by
        ``TpsWarp.warp`` of the 68 points when either mesh is missing (NaN)."""
        if not (np.isfinite(shot_mesh).all() and np.isfinite(target_mesh).all()):
            self.warp_counts["without_mesh"] += 1
            return self.warp(shot, shot_points, target_points)
        height, width = shot.shape[:2]
        # outside the face: exactly the tps baseline's map (with the mesh detector the 68 points are the meshes')
        fallback = tps.tps_map(shot_points, target_points, height, width, regularization=self.regularization,
                               merge_distance=self.merge_distance, max_folded_fraction=self.max_folded_fraction,
                               fix_border=self.fix_border, grid_step=1)
        moved, _ = mesh_warp.warp_mesh(shot, shot_mesh, target_mesh, fallback=fallback, feather=self.feather)
        self.warp_counts[fallback.method] += 1
        return moved


class MeshMean3(MeshWarp):
    """Per-pixel mean of the ``SHOTS`` nearest shots, each warped as by ``MeshWarp`` (see the module docstring)."""

    name = "mesh_mean3"
    SHOTS = 3

    def reenact(self, shots: list[np.ndarray], shot_landmarks: np.ndarray, target_landmarks: np.ndarray, *,
                shot_meshes: np.ndarray, target_meshes: np.ndarray) -> np.ndarray:
        """Shapes as ``MeshWarp.reenact``."""
        check_method_inputs(shots, shot_landmarks, target_landmarks)
        check_mesh_inputs(shot_meshes, target_meshes, len(shots), len(target_landmarks))
        outputs = []
        for target, target_mesh in zip(target_landmarks, target_meshes):
            nearest = measures.nearest_shots(shot_landmarks, target, self.SHOTS)
            warped = np.stack([self.warp_mesh(shots[i], shot_landmarks[i], target, shot_meshes[i], target_mesh)
                               for i in nearest])  # (n, S, S, 3)
            outputs.append(np.rint(warped.mean(axis=0, dtype=np.float64)).astype(np.uint8))
        return np.stack(outputs)
