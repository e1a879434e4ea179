"""iBUG-68 points from the 468-point face mesh, by a mapping fitted here (not copied from anywhere).

Each of the 68 points is a fixed convex combination of a few mesh vertices: ``points68 = weights @ mesh``
with ``weights`` (68, 468), at most ``NEIGHBOURS`` non-zero per row, summing to 1. The weights are fitted
by non-negative least squares on frames of the project's *training* people (``real_talking_heads``; never
the evaluation people): for each of the 68 points, the ``NEIGHBOURS`` mesh vertices nearest to it on
average are the candidates, and the weights minimise the squared distance to dlib's point over all frames,
in coordinates centred on the face and scaled by the inter-ocular distance. A row summing to 1 keeps the
mapping equivariant to translation, so it works in any frame's pixels.

How to rebuild it (writes ``landmarks/assets/mesh68.json``, with the frames used and the fit's error, and the
canonical mesh of ``landmarks.motion.mesh_rotation``):

    lsr face-models fit ../shared/data/real_talking_heads

The jaw line is where a fixed mapping is weakest: dlib's jaw points follow the face's silhouette, which slides
over the skin as the head turns, while a mesh vertex stays on the skin. So the 17 jaw points get a second set of
weights scaled by the head's yaw (``landmarks.motion.mesh_rotation``, clipped to +-45 degrees): ``jaw = a @ mesh + (yaw / 30)
b @ mesh``, sum(a) = 1, sum(b) = 0 (still translation-equivariant), fitted by ridge least squares over the
``JAW_NEIGHBOURS`` nearest vertices, on the same frames, once the canonical mesh is built. On the 4 validation
people's frames this took the jaw's error from 0.102 to 0.085 of the eye distance (all 68 points: 0.055 -> 0.051).
"""

from __future__ import annotations

import functools
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from landmarks.exceptions import ModelFilesError
from landmarks.shape.ibug68 import NUM_LANDMARKS

MAPPING_FILE = Path(__file__).resolve().parents[1] / "assets" / "mesh68.json"
NEIGHBOURS = 6
JAW = range(17)
JAW_NEIGHBOURS = 12
YAW_SCALE = 30.0  # degrees: the yaw weights are per 30 degrees of turn
MAX_YAW = 45.0  # beyond the training frames' turns (5-95 %: -26 .. 13 degrees) the linear term is not trusted
VALIDATION_PEOPLE = ("real015", "real033", "real036", "real046")  # the project's held-out training people


def _dense(rows: list, points: int) -> np.ndarray:
    weights = np.zeros((NUM_LANDMARKS, points), np.float32)
    for row, terms in enumerate(rows):
        for vertex, weight in terms:
            weights[row, vertex] = weight
    return weights


@functools.lru_cache(maxsize=1)
def _load() -> tuple[np.ndarray, np.ndarray]:
    if not MAPPING_FILE.is_file():
        raise ModelFilesError(f"{MAPPING_FILE} is missing; reinstall the package (or rebuild it: lsr face-models fit DATA)")
    record = json.loads(MAPPING_FILE.read_text())
    return _dense(record["rows"], record["mesh_points"]), _dense(record["yaw_rows"], record["mesh_points"])


def mapping() -> np.ndarray:
    """(68, 468) float32 weights at yaw 0: rows sum to 1 (convex combinations of vertices, the jaw's aside)."""
    return _load()[0]


def yaw_mapping() -> np.ndarray:
    """(68, 468) float32 weights per ``YAW_SCALE`` degrees of yaw (non-zero on the jaw rows only; rows sum to 0)."""
    return _load()[1]


def mesh_to_68(mesh: np.ndarray) -> np.ndarray:
    """(..., 468, 3) mesh -> (..., 68, 2) float32 iBUG-68 points (x, y); the jaw follows the silhouette with the
    head's yaw (module docstring). A (..., 468, 2) mesh has no depth, hence no yaw: its jaw takes the yaw-0 weights."""
    from landmarks.motion.mesh_rotation import mesh_head_pose

    mesh = np.asarray(mesh, np.float32)
    if mesh.ndim < 2 or mesh.shape[-2] != 468 or mesh.shape[-1] not in (2, 3):
        raise ValueError(f"mesh must be (..., 468, 3) (or (..., 468, 2) without depth), got {mesh.shape}")
    flat = mesh.reshape(-1, 468, mesh.shape[-1])
    points = mapping() @ flat[..., :2]  # (68, 468) @ (M, 468, 2): a matmul, ~10x faster than the einsum
    if mesh.shape[-1] == 3:
        yaw = np.array([mesh_head_pose(m)[0] for m in flat], np.float32)  # (M,) degrees, NaN for NaN meshes
        turn = np.clip(yaw, -MAX_YAW, MAX_YAW) / YAW_SCALE
        points += turn[:, None, None] * (yaw_mapping() @ flat[..., :2])
    return points.reshape(*mesh.shape[:-2], NUM_LANDMARKS, 2).astype(np.float32)


def _normalise(points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Centre on the reference's eye midpoint, scale by its inter-ocular distance (dlib eyes 36-41, 42-47)."""
    left, right = reference[36:42].mean(0), reference[42:48].mean(0)
    return (points - (left + right) / 2.0) / np.linalg.norm(right - left)


def fit_mapping(meshes: np.ndarray, targets: np.ndarray, neighbours: int = NEIGHBOURS) -> tuple[np.ndarray, np.ndarray]:
    """Fit the mapping. meshes: (N, 468, >=2); targets: (N, 68, 2) dlib points of the same frames.

    Returns (weights (68, 468) float32, per-point error (68,) as mean distance / inter-ocular distance).
    """
    from scipy.optimize import nnls

    if meshes.shape[0] != targets.shape[0] or meshes.shape[0] == 0:
        raise ValueError(f"need one target per mesh (and at least one), got {meshes.shape[0]} and {targets.shape[0]}")
    mesh_n = np.stack([_normalise(m[:, :2], t) for m, t in zip(meshes, targets)])  # (N, 468, 2)
    target_n = np.stack([_normalise(t, t) for t in targets])  # (N, 68, 2)
    weights = np.zeros((NUM_LANDMARKS, mesh_n.shape[1]), np.float32)
    errors = np.zeros(NUM_LANDMARKS, np.float32)
    for point in range(NUM_LANDMARKS):
        mean_distance = np.linalg.norm(mesh_n - target_n[:, point : point + 1], axis=-1).mean(0)  # (468,)
        candidates = np.argsort(mean_distance)[:neighbours]
        # x and y stacked: one weight per vertex for both coordinates; a heavy extra row holds sum(w) = 1.
        design = np.concatenate([mesh_n[:, candidates, 0], mesh_n[:, candidates, 1]])  # (2N, k)
        goal = np.concatenate([target_n[:, point, 0], target_n[:, point, 1]])
        design = np.vstack([design, 100.0 * np.ones((1, neighbours))])
        goal = np.append(goal, 100.0)
        solution, _ = nnls(design, goal)
        solution /= max(solution.sum(), 1e-9)
        weights[point, candidates] = solution
        fitted = np.einsum("k,nkc->nc", solution, mesh_n[:, candidates])
        errors[point] = float(np.linalg.norm(fitted - target_n[:, point], axis=-1).mean())
    return weights, errors


def fit_jaw_with_yaw(meshes: np.ndarray, targets: np.ndarray, yaws: np.ndarray, weights: np.ndarray,
                     neighbours: int = JAW_NEIGHBOURS, ridge: float = 1e-2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Refit the jaw rows with a yaw term (module docstring). meshes: (N, 468, >=2); targets: (N, 68, 2);
    yaws: (N,) degrees; weights: (68, 468) the static mapping. Returns (weights, yaw_weights, jaw error (17,))."""
    mesh_n = np.stack([_normalise(m[:, :2], t) for m, t in zip(meshes, targets)])  # (N, 468, 2)
    target_n = np.stack([_normalise(t, t) for t in targets])  # (N, 68, 2)
    turn = (np.clip(yaws, -MAX_YAW, MAX_YAW) / YAW_SCALE)[:, None, None]
    weights, yaw_weights = weights.copy(), np.zeros_like(weights)
    errors = np.zeros(len(JAW), np.float32)
    for point in JAW:
        mean_distance = np.linalg.norm(mesh_n - target_n[:, point : point + 1], axis=-1).mean(0)
        candidates = np.argsort(mean_distance)[:neighbours]
        features = np.concatenate([mesh_n[:, candidates], mesh_n[:, candidates] * turn], axis=1)  # (N, 2k, 2)
        design = np.concatenate([features[:, :, 0], features[:, :, 1]])  # (2N, 2k)
        goal = np.concatenate([target_n[:, point, 0], target_n[:, point, 1]])
        sums = np.zeros((2, 2 * neighbours))
        sums[0, :neighbours] = sums[1, neighbours:] = 100.0  # heavy rows: sum(a) = 1, sum(b) = 0
        design, goal = np.vstack([design, sums]), np.append(goal, [100.0, 0.0])
        solution = np.linalg.solve(design.T @ design + ridge * np.eye(2 * neighbours), design.T @ goal)
        solution[:neighbours] += (1.0 - solution[:neighbours].sum()) / neighbours  # the ridge bends the sums a little:
        solution[neighbours:] -= solution[neighbours:].sum() / neighbours  # make them exact (translation-equivariance)
        weights[point] = 0.0
        weights[point, candidates], yaw_weights[point, candidates] = solution[:neighbours], solution[neighbours:]
        fitted = np.einsum("nkc,k->nc", features, solution)
        errors[point] = float(np.linalg.norm(fitted - target_n[:, point], axis=-1).mean())
    return weights, yaw_weights, errors


def _collect(videos: Sequence[Path], frames_per_clip: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Mesh and dlib points on frames spread through each clip where both find one face."""
    from tqdm import tqdm

    from landmarks.detect import mediapipe_mesh as face_mesh
    from landmarks.detect.face_detector import DlibDetector
    from landmarks.io.video import iter_frames, probe_video

    detector = DlibDetector("hog")
    meshes, targets, used = [], [], []
    for video in tqdm(videos, desc="fit frames", unit="clip"):
        count = probe_video(video).frames
        picks = set(np.linspace(0, max(count - 1, 0), frames_per_clip).round().astype(int).tolist())
        for index, frame in enumerate(iter_frames(video)):
            if index not in picks:
                continue
            faces = detector.detect(frame)
            found = face_mesh.detect_faces(frame)
            if len(faces) != 1 or len(found) != 1:
                continue
            result = face_mesh.predict_mesh(frame, face_mesh.region_from_detection(found[0]))
            result = face_mesh.predict_mesh(frame, face_mesh.region_from_mesh(result.mesh))  # MediaPipe's 2nd pass
            if result.presence < 0.5:
                continue
            meshes.append(result.mesh)
            targets.append(faces[0].landmarks)
            used.append(f"{video.parent.parent.name}/{video.parent.name}/{video.name}#{index}")
    return np.stack(meshes), np.stack(targets), used


def run_fit(cfg: Any) -> dict[str, Any]:
    """Entry point of ``lsr face-models fit`` (``lsr.config.FaceModelsFitConfig``): fit the 68-point mapping and the
    canonical mesh (``landmarks.motion.mesh_rotation``) on the same frames, write both, print."""
    from landmarks.exceptions import InputFileError
    from landmarks.io.image_files import write_json
    from landmarks.motion.mesh_rotation import CANONICAL_FILE, build_canonical, yaw_of
    from landmarks.motion.head_pose import CANONICAL_FACE_3D

    data = Path(cfg.data)
    videos = sorted(path for path in data.glob("real*/**/*.mp4") if path.relative_to(data).parts[0] not in VALIDATION_PEOPLE)
    if not videos:
        raise InputFileError(f"no real*/**/*.mp4 clips under {data}; give the real_talking_heads folder")
    meshes, targets, used = _collect(videos, cfg.frames_per_clip)
    weights, errors = fit_mapping(meshes, targets)
    # The canonical mesh is oriented with the static mapping; the yaw it then gives each frame drives the jaw's refit.
    canonical = build_canonical(meshes, weights, CANONICAL_FACE_3D)
    yaws = np.array([yaw_of(mesh, canonical) for mesh in meshes])
    weights, yaw_weights, jaw_errors = fit_jaw_with_yaw(meshes, targets, yaws, weights)
    errors[list(JAW)] = jaw_errors

    def rows_of(matrix: np.ndarray) -> list:
        return [[[int(v), round(float(matrix[p, v]), 6)] for v in np.flatnonzero(matrix[p])] for p in range(NUM_LANDMARKS)]

    record = {
        "about": "iBUG-68 points as convex combinations of MediaPipe face-mesh vertices; fitted by landmarks.shape.mesh68",
        "mesh_points": int(meshes.shape[1]),
        "neighbours": NEIGHBOURS,
        "frames": len(used),
        "clips": len(videos),
        "fit_error_iod": {"mean": round(float(errors.mean()), 5), "per_point": [round(float(e), 5) for e in errors]},
        "yaw_scale_degrees": YAW_SCALE,
        "rows": rows_of(weights),
        "yaw_rows": rows_of(yaw_weights),
    }
    out = Path(cfg.out) if cfg.out is not None else MAPPING_FILE.parent
    write_json(out / MAPPING_FILE.name, record)
    write_json(out / CANONICAL_FILE.name, {
        "about": "canonical 468-vertex face mesh (landmarks.motion.head_pose's model units and axes) and its rigid vertices; "
                 "built by landmarks.motion.mesh_rotation.build_canonical",
        "frames": len(used),
        "vertices": np.round(canonical["vertices"], 4).tolist(),
        "rigid": canonical["rigid"].astype(int).tolist(),
    })
    print(f"fitted on {len(used)} frames of {len(videos)} clips: mean error {errors.mean():.4f} of the inter-ocular distance")
    print(f"worst points: {', '.join(f'{p}: {errors[p]:.3f}' for p in np.argsort(-errors)[:5])}")
    print(f"wrote {out / MAPPING_FILE.name} and {out / CANONICAL_FILE.name} ({int(canonical['rigid'].sum())} rigid vertices)")
    return record
