"""Build a face detector and its tracker by name: ``make_detector("mesh" | "hog" | "cnn")``, ``make_tracker``.

"mesh" (the default) is MediaPipe's detector and face mesh on onnxruntime (Apache-2.0 models); "hog" and "cnn"
are dlib's, with its 68-point shape predictor (a non-commercial model). dlib is imported only when asked for,
so the default path runs without it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from landmarks.detect.face_detector import DEFAULT_DETECTOR, DetectorKind, FaceDetector
from landmarks.detect.dlib_tracker import FrameTracker

DETECTOR_KINDS: tuple[str, ...] = ("mesh", "hog", "cnn")


def make_detector(kind: DetectorKind | str = DEFAULT_DETECTOR, **options: Any) -> FaceDetector:
    """A detector by name; ``options`` go to its constructor (dlib: max_side, upsample, min_score;
    mesh: min_score, min_presence)."""
    if kind == "mesh":
        from landmarks.detect.mediapipe_tracker import MeshDetector

        return MeshDetector(**options)
    if kind in ("hog", "cnn"):
        from landmarks.detect.face_detector import DlibDetector

        return DlibDetector(kind=kind, **options)  # type: ignore[arg-type]
    raise ValueError(f"detector must be one of {', '.join(DETECTOR_KINDS)}, got {kind!r}")


def make_tracker(detector: FaceDetector | str | None = None, *, live: bool = False, **options: Any) -> FrameTracker:
    """The tracker that goes with ``detector`` (a detector, a kind, or None for the default); ``options`` go to
    the tracker (face_index, ...). live: a camera stream, where the mesh tracker reruns the iris net only on an eye
    that changed (its ``iris_gate``)."""
    if detector is None or isinstance(detector, str):
        detector = make_detector(detector or DEFAULT_DETECTOR)
    if detector.kind == "mesh":
        from landmarks.detect.mediapipe_tracker import MeshTracker

        return MeshTracker(detector, iris_gate=live, **options)  # type: ignore[arg-type]
    from landmarks.detect.dlib_tracker import LandmarkTracker

    return LandmarkTracker(detector, **options)  # type: ignore[arg-type]


def gives_meshes(detector: Any) -> bool:
    """Whether ``detector`` finds face meshes (``landmarks.detect.mediapipe_tracker.MeshDetector`` has ``meshes``)."""
    return callable(getattr(detector, "meshes", None))


def detect_faces(frames: Sequence[np.ndarray], detector: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """Largest face's 68 landmarks per frame, and its mesh when the detector gives meshes (``gives_meshes``).

    frames: N x (H, W, 3) uint8 -> ((N, 68, 2) float32, (N, 468, 3) float32 or None), NaN rows = no face. A mesh
    detector's 68 points are ``mesh_to_68`` of the mesh, as its ``detect`` gives them."""
    from landmarks.shape.mesh68 import mesh_to_68
    from landmarks.warp.piecewise_affine import MESH_POINTS

    with_meshes = gives_meshes(detector)
    landmarks = np.full((len(frames), 68, 2), np.nan, np.float32)
    meshes = np.full((len(frames), MESH_POINTS, 3), np.nan, np.float32) if with_meshes else None
    retry = None
    for index, frame in enumerate(frames):
        faces = detector.meshes(frame) if with_meshes else detector.detect(frame)
        if not faces:  # ground truth should not lose a face to a cheap detection setting: retry a finer one
            if retry is None:
                retry = detector.more_sensitive() or detector
            if retry is not detector:
                faces = retry.meshes(frame) if with_meshes else retry.detect(frame)
        if faces and meshes is not None:
            meshes[index] = faces[0][1].mesh
            landmarks[index] = mesh_to_68(faces[0][1].mesh)
        elif faces:
            landmarks[index] = faces[0].landmarks
    return landmarks, meshes
