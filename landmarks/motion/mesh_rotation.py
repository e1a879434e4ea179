"""Head pose in 3D from the 468-point mesh: a rotation fitted against a canonical face mesh made here.

The face-mesh net gives every vertex an x, y in frame pixels and a depth z at the same scale (smaller = nearer),
so a mesh is a 3D shape up to perspective. The pose is the rotation that best maps the canonical mesh onto it:
weighted orthogonal Procrustes (Kabsch, with scale) over the *rigid* vertices (forehead, nose, cheekbones, eye
corners: the ones that move least against the skull when people talk), so an open mouth or a blink does not read as
a head turn. Angles follow ``landmarks.motion.head_pose`` (yaw > 0: the face turns to the image right; pitch > 0: up; roll > 0:
clockwise on screen; R = Rz(roll) Rx(-pitch) Ry(-yaw)).

The canonical mesh (``landmarks/assets/mesh_canonical.json``) is made by ``build_canonical`` from meshes of the
training people (``lsr face-models fit`` writes it beside the 68-point mapping): generalised Procrustes
(centre, scale to unit size, rotate onto the running mean, repeat), then turned so that its 68 mapped points face the
camera as ``landmarks.motion.head_pose``'s canonical 68-point face does. The rigid vertices are the half whose aligned positions
vary least over those frames.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np

from landmarks.exceptions import ModelFilesError

CANONICAL_FILE = Path(__file__).resolve().parents[1] / "assets" / "mesh_canonical.json"
RIGID_FRACTION = 0.5


def kabsch(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, float, np.ndarray]:
    """Similarity (rotation R (3, 3), scale s, translation t (3,)) minimising sum w |s R source + t - target|^2.

    source, target: (N, 3). A proper rotation (det +1), never a reflection.
    """
    weights = np.ones(len(source)) if weights is None else np.asarray(weights, np.float64)
    weights = weights / weights.sum()
    source_mean, target_mean = weights @ source, weights @ target
    centred_source, centred_target = source - source_mean, target - target_mean
    covariance = (centred_target * weights[:, None]).T @ centred_source  # (3, 3)
    u, singular, vt = np.linalg.svd(covariance)
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    rotation = u @ flip @ vt
    variance = float(weights @ (centred_source**2).sum(1))
    scale = float((singular * np.diag(flip)).sum() / max(variance, 1e-12))
    return rotation, scale, target_mean - scale * rotation @ source_mean


def _normalised(mesh: np.ndarray) -> np.ndarray:
    centred = mesh - mesh.mean(0)
    return centred / np.sqrt((centred**2).sum(1).mean())


def build_canonical(meshes: np.ndarray, mapping68: np.ndarray, face68: np.ndarray, iterations: int = 5) -> dict:
    """Canonical mesh and rigid vertices from many meshes.

    meshes: (N, 468, 3) in frame pixels; mapping68: (68, 468) weights (``landmarks.shape.mesh68.mapping``);
    face68: (68, 3) the canonical 68-point face of ``landmarks.motion.head_pose`` (OpenCV camera axes, model units).
    Returns {"vertices": (468, 3) float, "rigid": (468,) bool} in ``face68``'s units and orientation.
    """
    shapes = np.stack([_normalised(np.asarray(m, np.float64)) for m in meshes])
    mean = shapes[0]
    for _ in range(iterations):
        aligned = []
        for shape in shapes:
            rotation, _, _ = kabsch(shape, mean)
            aligned.append(shape @ rotation.T)
        aligned = np.stack(aligned)
        mean = _normalised(aligned.mean(0))
    spread = np.linalg.norm(aligned - aligned.mean(0), axis=2).mean(0)  # (468,) how much each vertex moves
    rigid = spread <= np.quantile(spread, RIGID_FRACTION)
    # Orientation and units: the mean's 68 mapped points onto landmarks.motion.head_pose's canonical face.
    rotation, scale, translation = kabsch(mapping68 @ mean, face68)
    vertices = scale * mean @ rotation.T + translation
    return {"vertices": vertices, "rigid": rigid}


@functools.lru_cache(maxsize=1)
def canonical() -> tuple[np.ndarray, np.ndarray]:
    """(468, 3) canonical vertices and (468,) bool rigid mask."""
    if not CANONICAL_FILE.is_file():
        raise ModelFilesError(f"{CANONICAL_FILE} is missing; reinstall the package (or: lsr face-models fit DATA)")
    record = json.loads(CANONICAL_FILE.read_text())
    return np.asarray(record["vertices"], np.float64), np.asarray(record["rigid"], bool)


def mesh_rotation(mesh: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Similarity from the canonical mesh to ``mesh`` ((468, 3) frame pixels) over the rigid vertices:
    rotation (3, 3) model-to-camera, scale (pixels per model unit), translation (3,)."""
    vertices, rigid = canonical()
    return kabsch(vertices[rigid], np.asarray(mesh, np.float64)[rigid])


def to_head_frame(mesh: np.ndarray, frame: tuple[np.ndarray, float, np.ndarray]) -> np.ndarray:
    """(468, 3) frame pixels -> (468, 3) canonical head coordinates under ``frame``, the similarity
    (rotation, scale, translation) of ``mesh_rotation`` that places the canonical head there."""
    rotation, scale, translation = frame
    return (np.asarray(mesh, np.float64) - translation) @ rotation / scale


def yaw_of(mesh: np.ndarray, canonical_record: dict) -> float:
    """Yaw in degrees of one (468, 3) mesh against a canonical record of ``build_canonical`` (before it is saved)."""
    from landmarks.motion.head_pose import angles_from_rotation

    rigid = canonical_record["rigid"]
    rotation, _, _ = kabsch(canonical_record["vertices"][rigid], np.asarray(mesh, np.float64)[rigid])
    return float(angles_from_rotation(rotation)[0])


def mesh_head_pose(mesh: np.ndarray) -> np.ndarray:
    """(468, 3) mesh -> (3,) float32 yaw, pitch, roll in degrees (``landmarks.motion.head_pose`` conventions); NaN when the
    mesh has NaN."""
    from landmarks.motion.head_pose import angles_from_rotation

    mesh = np.asarray(mesh, np.float64)
    if mesh.shape != (468, 3):
        raise ValueError(f"mesh must be (468, 3), got {mesh.shape}")
    if not np.isfinite(mesh).all():
        return np.full(3, np.nan, np.float32)
    rotation, _, _ = mesh_rotation(mesh)
    return angles_from_rotation(rotation).astype(np.float32)
