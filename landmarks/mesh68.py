"""iBUG-68 points from the 468-point face mesh, by a mapping fitted here (not copied from anywhere).

Each of the 68 points is a fixed convex combination of a few mesh vertices: ``points68 = weights @ mesh``
with ``weights`` (68, 468), at most ``NEIGHBOURS`` non-zero per row, summing to 1. The weights are fitted
by non-negative least squares on frames of the project's *training* people (``real_talking_heads``; never
the evaluation people): for each of the 68 points, the ``NEIGHBOURS`` mesh vertices nearest to it on
average are the candidates, and the weights minimise the squared distance to dlib's point over all frames,
in coordinates centred on the face and scaled by the inter-ocular distance. A row summing to 1 keeps the
mapping equivariant to translation, so it works in any frame's pixels.

How to rebuild it (writes ``landmarks/assets/mesh68.json``, with the frames used and the fit's error, and the
canonical mesh of ``landmarks.mesh_pose``):

    lsr face-models fit ../shared/data/real_talking_heads

The jaw line is where a fixed mapping is weakest: dlib's jaw points follow the face's silhouette, which slides
over the skin as the head turns, while a mesh vertex stays on the skin.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from landmarks.errors import ModelFilesError
from landmarks.parts import NUM_LANDMARKS

MAPPING_FILE = Path(__file__).resolve().parent / "assets" / "mesh68.json"
NEIGHBOURS = 6
VALIDATION_PEOPLE = ("real015", "real033", "real036", "real046")  # the project's held-out training people


@functools.lru_cache(maxsize=1)
def mapping() -> np.ndarray:
    """(68, 468) float32 weights; rows are convex combinations of mesh vertices."""
    if not MAPPING_FILE.is_file():
        raise ModelFilesError(f"{MAPPING_FILE} is missing; reinstall the package (or rebuild it: lsr face-models fit DATA)")
    record = json.loads(MAPPING_FILE.read_text())
    weights = np.zeros((NUM_LANDMARKS, record["mesh_points"]), np.float32)
    for row, terms in enumerate(record["rows"]):
        for vertex, weight in terms:
            weights[row, vertex] = weight
    return weights


def mesh_to_68(mesh: np.ndarray) -> np.ndarray:
    """(..., 468, 2 or 3) mesh -> (..., 68, 2) float32 iBUG-68 points (x, y)."""
    return np.einsum("pv,...vc->...pc", mapping(), mesh[..., :2]).astype(np.float32)


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


def _collect(videos: Sequence[Path], frames_per_clip: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Mesh and dlib points on frames spread through each clip where both find one face."""
    from tqdm import tqdm

    from landmarks import mesh as face_mesh
    from landmarks.detect import DlibDetector
    from landmarks.video import iter_frames, probe_video

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
    canonical mesh (``landmarks.mesh_pose``) on the same frames, write both, print."""
    from landmarks.errors import InputFileError
    from landmarks.imageio import write_json
    from landmarks.mesh_pose import CANONICAL_FILE, build_canonical
    from landmarks.pose import CANONICAL_FACE_3D

    data = Path(cfg.data)
    videos = sorted(path for path in data.glob("real*/**/*.mp4") if path.relative_to(data).parts[0] not in VALIDATION_PEOPLE)
    if not videos:
        raise InputFileError(f"no real*/**/*.mp4 clips under {data}; give the real_talking_heads folder")
    meshes, targets, used = _collect(videos, cfg.frames_per_clip)
    weights, errors = fit_mapping(meshes, targets)
    rows = [[[int(v), round(float(weights[p, v]), 6)] for v in np.flatnonzero(weights[p])] for p in range(NUM_LANDMARKS)]
    record = {
        "about": "iBUG-68 points as convex combinations of MediaPipe face-mesh vertices; fitted by landmarks.mesh68",
        "mesh_points": int(meshes.shape[1]),
        "neighbours": NEIGHBOURS,
        "frames": len(used),
        "clips": len(videos),
        "fit_error_iod": {"mean": round(float(errors.mean()), 5), "per_point": [round(float(e), 5) for e in errors]},
        "rows": rows,
    }
    out = Path(cfg.out) if cfg.out is not None else MAPPING_FILE.parent
    write_json(out / MAPPING_FILE.name, record)
    canonical = build_canonical(meshes, weights, CANONICAL_FACE_3D)
    write_json(out / CANONICAL_FILE.name, {
        "about": "canonical 468-vertex face mesh (landmarks.pose's model units and axes) and its rigid vertices; "
                 "built by landmarks.mesh_pose.build_canonical",
        "frames": len(used),
        "vertices": np.round(canonical["vertices"], 4).tolist(),
        "rigid": canonical["rigid"].astype(int).tolist(),
    })
    print(f"fitted on {len(used)} frames of {len(videos)} clips: mean error {errors.mean():.4f} of the inter-ocular distance")
    print(f"worst points: {', '.join(f'{p}: {errors[p]:.3f}' for p in np.argsort(-errors)[:5])}")
    print(f"wrote {out / MAPPING_FILE.name} and {out / CANONICAL_FILE.name} ({int(canonical['rigid'].sum())} rigid vertices)")
    return record
