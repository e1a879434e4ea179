"""The default face detector and tracker: MediaPipe's BlazeFace and face mesh (``landmarks.detect.mediapipe_mesh``), giving the
468-point mesh and the iBUG-68 points mapped from it (``landmarks.shape.mesh68``). Apache-2.0 models, onnxruntime only.

Tracking (per frame; (H, W, 3) uint8 RGB in, (68, 2) float32 out, the full mesh kept in ``tracker.mesh`` and the
iris net's irises in ``tracker.irises``):

1. While tracking, the mesh net runs in the region predicted from the previous frame's mesh (MediaPipe's
   landmarks-to-region: the square 1.5x the mesh's extent, levelled on the eye corners). 3-5 ms.
2. The result is kept when the net's face-presence probability is at least ``min_presence`` and the face did not
   jump: size change within ``max_scale_change`` and centre shift below ``max_shift`` of the face size.
3. Otherwise (and on the first frame) a full detection runs on that frame (whole frame, then tiles for small
   faces); after a loss, the face overlapping the last one is preferred. Nothing found: the frame is missing and
   detection runs again on the next one. No frame is dropped.
4. With ``iris_gate`` (live tracking), the iris net reruns on an eye only where it changed
   (``landmarks.detect.mediapipe_mesh.IrisGate``); after a detection every eye runs.
"""

from __future__ import annotations

import os
import numpy as np

from landmarks.detect import mediapipe_mesh as face_mesh
from landmarks.detect.face_detector import Face, FaceDetector, as_image
from landmarks.shape.mesh68 import mesh_to_68
from landmarks.detect.dlib_tracker import FrameTracker, pick_face


def _refined(image: np.ndarray, detection: face_mesh.Detection) -> face_mesh.MeshResult:
    """Mesh from a detection's region, then once more from the mesh's own region (tighter and levelled, as
    the tracker's next frame would see it): the first pass alone sits a few pixels off on turned heads."""
    first = face_mesh.predict_mesh(image, face_mesh.region_from_detection(detection))
    second = face_mesh.predict_mesh(image, face_mesh.region_from_mesh(first.mesh))
    return second if second.presence >= first.presence * 0.5 else first


def mesh_box(mesh: np.ndarray) -> np.ndarray:
    """(468, >=2) -> (4,) float32 bounding box of the mesh's x, y."""
    low, high = mesh[:, :2].min(0), mesh[:, :2].max(0)
    return np.concatenate([low, high]).astype(np.float32)


def box_area(box: np.ndarray) -> float:
    return float(np.prod(np.maximum(box[2:] - box[:2], 0.0)))


class MeshDetector(FaceDetector):
    """BlazeFace (short range, tiled for small faces) + the 468-point mesh, its eye contours refined by the iris net
    (``landmarks.detect.mediapipe_mesh.refine_eyes``), 68 points mapped from it.

    min_score: detection probability threshold (MediaPipe's 0.5); min_presence: the mesh net's face
    probability below which a detection is dropped (a detector false positive).
    """

    kind = "mesh"

    def __init__(self, min_score: float = 0.5, min_presence: float = 0.5) -> None:
        self.min_score = min_score
        self.min_presence = min_presence

    @property
    def settings(self) -> str:
        return f"mesh/{self.min_score}/{self.min_presence}/iris-eyes"

    def min_face_size(self, shape: tuple[int, ...]) -> int:
        # The short-range net finds faces down to about 1/8 of its 128-px view; tiles halve the view.
        return int(np.ceil(min(shape[:2]) / 2 / 8))

    def meshes(self, image: np.ndarray | str | os.PathLike[str]) -> list[tuple[face_mesh.Detection, face_mesh.MeshResult]]:
        """Every face's detection and mesh, largest first."""
        image = as_image(image)
        found = []
        for detection in face_mesh.detect_tiled(image, self.min_score):
            result = _refined(image, detection)
            if result.presence >= self.min_presence:
                found.append((detection, result))
        found.sort(key=lambda pair: -box_area(mesh_box(pair[1].mesh)))
        return found

    def detect(self, image: np.ndarray | str | os.PathLike[str]) -> list[Face]:
        return [
            Face(box=detection.box, landmarks=mesh_to_68(result.mesh), score=detection.score, mesh=result.mesh)
            for detection, result in self.meshes(image)
        ]


class MeshTracker(FrameTracker):
    """Tracks one face's mesh and its 68 points through frames (policy in the module docstring).

    The same interface as ``landmarks.detect.dlib_tracker.LandmarkTracker``: ``update``, ``track_frames``, ``reset``,
    ``detections``; ``mesh`` holds the last frame's (468, 3) mesh (None when missing). iris_gate: rerun the iris net
    on an eye only where it changed (``landmarks.detect.mediapipe_mesh.IrisGate``: a camera stream's frame budget;
    off for videos, where every frame is refined).
    """

    def __init__(
        self,
        detector: MeshDetector | None = None,
        *,
        face_index: int = 0,
        max_scale_change: float = 0.3,
        max_shift: float = 0.4,
        iris_gate: bool = False,
    ) -> None:
        self.detector = detector if detector is not None else MeshDetector()
        self.gate = face_mesh.IrisGate() if iris_gate else None
        self.face_index = face_index
        self.max_scale_change = max_scale_change
        self.max_shift = max_shift
        self.reset()

    def reset(self) -> None:
        self.mesh: np.ndarray | None = None
        self.irises: np.ndarray | None = None  # the last frame's (2, 4) ``landmarks.detect.mediapipe_mesh.eye_iris`` rows
        self.last_box: np.ndarray | None = None  # kept across losses: prefer the same face afterwards
        self.detections = 0
        if self.gate is not None:
            self.gate.reset()

    def _plausible(self, mesh: np.ndarray, previous: np.ndarray) -> bool:
        if not np.isfinite(mesh).all():
            return False
        box, old = mesh_box(mesh), mesh_box(previous)
        size, old_size = np.sqrt(np.prod(box[2:] - box[:2])), np.sqrt(np.prod(old[2:] - old[:2]))
        if not 1.0 / (1.0 + self.max_scale_change) <= size / max(old_size, 1e-6) <= 1.0 + self.max_scale_change:
            return False
        shift = np.linalg.norm((box[:2] + box[2:]) / 2.0 - (old[:2] + old[2:]) / 2.0)
        return bool(shift <= self.max_shift * old_size)

    def _detect(self, frame: np.ndarray) -> face_mesh.MeshResult | None:
        self.detections += 1
        found = self.detector.meshes(frame)
        if not found:
            return None
        choice = pick_face([mesh_box(result.mesh) for _, result in found], self.last_box, self.face_index)
        return None if choice is None else found[choice][1]

    def update(self, frame: np.ndarray) -> np.ndarray | None:
        """Track one frame. frame: (H, W, 3) uint8 RGB. Returns (68, 2) float32 or None (missing)."""
        frame = self.checked_frame(frame)
        kept = None
        if self.mesh is not None:
            result = face_mesh.predict_mesh(frame, face_mesh.region_from_mesh(self.mesh), gate=self.gate)
            if result.presence >= self.detector.min_presence and self._plausible(result.mesh, self.mesh):
                kept = result
        if kept is None:
            if self.gate is not None:
                self.gate.reset()
            kept = self._detect(frame)
        mesh = self.mesh = None if kept is None else kept.mesh
        self.irises = None if kept is None else kept.irises
        if mesh is None:
            return None
        self.last_box = mesh_box(mesh)
        return mesh_to_68(mesh)
