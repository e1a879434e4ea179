"""Cross-identity driving of face meshes: the driver's motion moved onto the source's mesh.

Two ways, both relative to a reference frame of the driver (its first face, as ``lsr reenact`` takes it) and both
ending with the mouth as open as the driver's (``open_mouth_as``, what ``landmarks.motion.retarget_points.retarget_driving``
does to 68 points):

* ``retarget_mesh`` (2D): ``landmarks.motion.retarget_points.retarget_relative``'s steps on every vertex, the similarities fitted
  on the meshes' 68 points. Yaw and pitch, which a 2D similarity cannot express, travel as expression deltas: the
  driver's face shape, turned, is added to the source's.
* ``retarget_mesh_3d``: the head pose is a 3D rotation (``landmarks.motion.mesh_rotation``: Kabsch on the rigid vertices of
  the canonical mesh). The driver's expression is its mesh in the canonical head frame minus its reference's
  there; it is added to the source's mesh in that frame, which is then turned by the source's own pose composed
  with the driver's rotation since its reference, scaled and moved as the driver's head was (its translation
  in source face sizes). A head turn turns the source's own face shape.

Meshes: (468, 3) float x, y frame pixels, z depth in the same units (smaller = nearer), as the detector gives.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from landmarks.parts.eyes.lids import LidReference, lid_gaps, lids_as_driver
from landmarks.shape.mesh68 import mesh_to_68
from landmarks.warp.piecewise_affine import MESH_POINTS, check_mesh, frontal_canonical

INTERPOLATION_NEIGHBOURS = 4  # 68 points that spread a correction onto each mesh vertex


@functools.lru_cache(maxsize=1)
def spreading_weights() -> np.ndarray:
    """(468, 68) float64: how a displacement of the 68 points spreads onto the mesh vertices (``retarget_mesh``).

    Inverse-square-distance weights over each vertex's ``INTERPOLATION_NEIGHBOURS`` nearest 68 points on the
    canonical mesh, whose mouth is open (the mean of talking faces), so lower-lip vertices follow the lower lip."""
    canonical = frontal_canonical()
    points = mesh_to_68(canonical).astype(np.float64)
    distances = np.linalg.norm(canonical[:, None] - points[None], axis=-1)  # (468, 68)
    nearest = np.argsort(distances, axis=1)[:, :INTERPOLATION_NEIGHBOURS]
    weights = np.zeros_like(distances)
    rows = np.arange(len(canonical))[:, None]
    weights[rows, nearest] = 1.0 / np.maximum(distances[rows, nearest], 1e-3) ** 2
    return weights / weights.sum(1, keepdims=True)


def retarget_mesh(driver_meshes: np.ndarray, driver_reference: np.ndarray, source_mesh: np.ndarray,
                  corrections: int = 3) -> np.ndarray:
    """What ``landmarks.motion.retarget_points.retarget_driving`` does to 68 points, done to the 468 mesh vertices: the driver's
    motion relative to its reference frame moved onto the source (``retarget_relative``'s steps, with the
    similarities fitted on the meshes' 68 points, ``RIGID_INDEX``), then the mouth as open as the driver's
    (``open_mouth_as``).

    driver_meshes: (T, 468, >=2), NaN frames stay NaN; driver_reference: (468, >=2) the driver frame that maps
    onto the source; source_mesh: (468, >=2) -> (T, 468, 2) float64. Purely 2D: the meshes' 68 points are taken
    without depth (the jaw's yaw-0 weights), so the jaw follows the mesh's skin, not the silhouette.
    """
    from landmarks.motion.retarget_points import RIGID_INDEX, apply_similarity, invert_similarity, similarity_procrustes

    frames = np.asarray(driver_meshes, np.float64)[..., :2]
    if frames.ndim != 3 or frames.shape[1] != MESH_POINTS:
        raise ValueError(f"driver_meshes must be (T, {MESH_POINTS}, 2 or 3), got {np.shape(driver_meshes)}")
    reference, source = check_mesh(driver_reference, "driver_reference"), check_mesh(source_mesh, "source_mesh")
    if not (np.isfinite(reference).all() and np.isfinite(source).all()):
        raise ValueError("driver_reference and source_mesh must be finite")
    rigid = list(RIGID_INDEX)

    def points(mesh: np.ndarray) -> np.ndarray:
        return mesh_to_68(mesh).astype(np.float64)

    def fit(first: np.ndarray, second: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        return similarity_procrustes(points(first)[rigid], points(second)[rigid])

    place = fit(reference, source)  # retarget_relative's steps 1-5, on every vertex
    place_linear = place[0] * place[1]
    output = np.full_like(frames, np.nan)
    found = np.isfinite(frames).all(axis=(1, 2))
    for index in np.flatnonzero(found):
        motion = fit(reference, frames[index])
        delta = apply_similarity(frames[index], *invert_similarity(*motion)) - reference
        expressive = source + delta @ place_linear.T
        in_driver_frame = apply_similarity(expressive, *invert_similarity(*place))
        output[index] = apply_similarity(apply_similarity(in_driver_frame, *motion), *place)
    if found.any():
        output[found] = open_mouth_as(output[found], frames[found], corrections)
    return output


def open_mouth_as(meshes: np.ndarray, drivers: np.ndarray, corrections: int = 3) -> np.ndarray:
    """``retarget_driving``'s mouth on meshes: each mesh's mouth as open as its driver's (``mouth_opening`` of the
    68 points, normalised by the eye distance), made on the 68 points by ``set_mouth_opening`` and spread onto the
    vertices (``spreading_weights``), ``corrections`` times, so that the mesh's inner lips land where it put them.
    meshes: (T, 468, >=2) finite, drivers: (T, 468, >=2) finite -> (T, 468, 2) float64 (x, y; depth is the
    caller's)."""
    from landmarks.shape.expression import mouth_opening, set_mouth_opening

    def points(mesh: np.ndarray) -> np.ndarray:
        return mesh_to_68(np.asarray(mesh)[..., :2]).astype(np.float64)

    moved = np.asarray(meshes, np.float64)[..., :2]
    targets = set_mouth_opening(points(moved), mouth_opening(points(drivers)))
    spread = spreading_weights()
    for _ in range(corrections):
        moved = moved + spread @ (targets - points(moved))  # (468, 68) @ (T, 68, 2)
    return moved


def retarget_mesh_3d(driver_meshes: np.ndarray, driver_reference: np.ndarray, source_mesh: np.ndarray,
                     corrections: int = 3) -> np.ndarray:
    """The driver's motion since ``driver_reference`` moved onto ``source_mesh`` in 3D (module docstring), then the
    mouth as open as the driver's (``open_mouth_as``).

    Per frame t, with head frames (R, s, T) of ``landmarks.motion.mesh_rotation.mesh_rotation`` and c(.) = its
    ``to_head_frame``:
      expression  e_t = c_t(driver_t) - c_ref(driver_ref)            (canonical units: face size cancels)
      rotation    R = R_t R_ref^T R_source                           (the driver's turn since its reference)
      scale       s = s_source * s_t / s_ref
      translation T = T_source + (T_t - T_ref) * s_source / s_ref     (x, y; depth alike)
      output_t = s R (c_source(source) + e_t) + T
    When driver_t == driver_ref the output is the source (up to float rounding).

    driver_meshes: (T, 468, 3), NaN frames stay NaN; driver_reference, source_mesh: (468, 3) finite
    -> (T, 468, 3) float64.
    """
    frames = np.asarray(driver_meshes, np.float64)
    if frames.ndim != 3 or frames.shape[1:] != (MESH_POINTS, 3):
        raise ValueError(f"driver_meshes must be (T, {MESH_POINTS}, 3), got {np.shape(driver_meshes)}")
    reference = check_mesh(driver_reference, "driver_reference", depth=True)
    source = check_mesh(source_mesh, "source_mesh", depth=True)
    if not (np.isfinite(reference).all() and np.isfinite(source).all()):
        raise ValueError("driver_reference and source_mesh must be finite")
    from landmarks.motion.mesh_rotation import mesh_rotation, to_head_frame

    reference_frame, source_frame = mesh_rotation(reference), mesh_rotation(source)
    reference_rotation, reference_scale, reference_translation = reference_frame
    source_rotation, source_scale, source_translation = source_frame
    neutral, own = to_head_frame(reference, reference_frame), to_head_frame(source, source_frame)
    ratio = source_scale / reference_scale
    output = np.full_like(frames, np.nan)
    found = np.isfinite(frames).all(axis=(1, 2))
    for index in np.flatnonzero(found):
        frame = mesh_rotation(frames[index])
        rotation, scale, translation = frame
        expression = to_head_frame(frames[index], frame) - neutral
        turned = rotation @ reference_rotation.T @ source_rotation
        moved = (own + expression) @ turned.T * (source_scale * scale / reference_scale)
        output[index] = moved + source_translation + (translation - reference_translation) * ratio
    if found.any():
        output[found, :, :2] = open_mouth_as(output[found], frames[found], corrections)
    return output


RETARGET_MODES = ("2d", "3d")


@dataclasses.dataclass
class DriverReference:
    """A stream's driver reference, as ``lsr reenact`` and the live tab keep it: its first face (68 points in crop
    pixels, and its mesh or None), which relative motion is measured from, and the reference lid gaps of both
    kinds of face (``landmarks.parts.eyes.lids.LidReference``: the median of the driver's so far and of those seen ahead,
    so a first face that blinks does not make every later eye look wide open). ``lids`` on each driver face as
    detected, then ``start`` on the first one found; ``reset`` for a new driver."""

    landmarks: np.ndarray | None = None
    mesh: np.ndarray | None = None
    lid_reference: LidReference = dataclasses.field(default_factory=LidReference)
    mesh_lid_reference: LidReference = dataclasses.field(default_factory=LidReference)

    def start(self, landmarks: np.ndarray, mesh: np.ndarray | None = None) -> None:
        """The reference face, unless there is one already."""
        if self.landmarks is None:
            self.landmarks, self.mesh = landmarks, mesh

    def reset(self) -> None:
        """No reference face, no lid history: the next face starts both anew."""
        self.landmarks = self.mesh = None
        self.lid_reference.reset()
        self.mesh_lid_reference.reset()

    def look_ahead(self, landmarks: list, meshes: list) -> None:
        """The driver's next faces (None: none found), seen before the first is driven
        (``landmarks.parts.eyes.lids.LidReference.look_ahead``)."""
        self.lid_reference.look_ahead(landmarks)
        self.mesh_lid_reference.look_ahead(meshes)

    def lids(self, landmarks: np.ndarray, mesh: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One driver face in, as detected (68 points, mesh or None): the reference lid gaps of its 68 points and
        of its mesh, (2,) each (NaN: none yet)."""
        nowhere = np.full((468, 3), np.nan)
        return self.lid_reference(landmarks), self.mesh_lid_reference(nowhere if mesh is None else mesh)


def retarget_face(driver_landmarks: np.ndarray, driver_reference_landmarks: np.ndarray, source_landmarks: np.ndarray,
                  driver_meshes: np.ndarray | None = None, driver_reference_mesh: np.ndarray | None = None,
                  source_mesh: np.ndarray | None = None, mode: str = "2d", reference_gaps: np.ndarray | None = None,
                  mesh_reference_gaps: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """What a source is driven with, its 68 points and (where there are meshes) its mesh, as ``lsr reenact`` and
    ``lsr eval`` drive it.

    mode "3d": where the driver's frame, its reference and the source have meshes, ``retarget_mesh_3d`` and the 68
    points mapped from the result (``mesh_to_68``, its jaw following the turned head's silhouette); other frames
    as "2d". mode "2d": ``landmarks.motion.retarget_points.retarget_driving`` of the 68 points, and ``retarget_mesh`` of the
    meshes (with the driver frame's depth, which orders overlapping triangles as its head is turned). Either way
    the lids close as the driver's do, in proportion to the source's own eyes (``landmarks.parts.eyes.lids.lids_as_driver``,
    which ``retarget_driving`` applies to the 68 points), measured against the driver reference's lid gaps:
    ``reference_gaps`` of its 68 points and ``mesh_reference_gaps`` of its mesh, (2,) or (T, 2) each
    (``landmarks.parts.eyes.lids.LidReference``: the median of the driver's so far, robust to a blink), None for those of
    the reference frame.

    driver_landmarks: (T, 68, 2) (NaN frames stay NaN); driver_reference_landmarks, source_landmarks: (68, 2) finite;
    driver_meshes: (T, 468, 3) or None; driver_reference_mesh, source_mesh: (468, 3) or None (NaN = none)
    -> (landmarks (T, 68, 2) float64, meshes (T, 468, 3) float64 or None when no mesh is given).
    """
    from landmarks.motion.retarget_points import retarget_driving

    if mode not in RETARGET_MODES:
        raise ValueError(f"mode must be one of {RETARGET_MODES}, got {mode!r}")
    landmarks = retarget_driving(driver_landmarks, driver_reference_landmarks, source_landmarks, reference_gaps)
    if driver_meshes is None or driver_reference_mesh is None or source_mesh is None:
        return landmarks, None
    frames = np.asarray(driver_meshes, np.float64)
    meshes = np.full(frames.shape, np.nan)
    if not (np.isfinite(driver_reference_mesh).all() and np.isfinite(source_mesh).all()):
        return landmarks, meshes
    lids = lid_gaps(driver_reference_mesh) if mesh_reference_gaps is None else mesh_reference_gaps
    if mode == "3d":
        meshes = lids_as_driver(retarget_mesh_3d(frames, driver_reference_mesh, source_mesh), frames, lids,
                                source_mesh)
        found = np.isfinite(meshes).all(axis=(1, 2))
        landmarks[found] = mesh_to_68(meshes[found])
        return landmarks, meshes
    meshes[..., :2] = retarget_mesh(frames, driver_reference_mesh, source_mesh)
    meshes[..., 2] = np.where(np.isfinite(meshes[..., 0]), frames[..., 2], np.nan)  # the driver's: its turn, its
    # occlusions (which of two overlapping triangles shows)
    return landmarks, lids_as_driver(meshes, frames, lids, source_mesh)
