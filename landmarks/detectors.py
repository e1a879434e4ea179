"""Build a face detector and its tracker by name: ``make_detector("mesh" | "hog" | "cnn")``, ``make_tracker``.

"mesh" (the default) is MediaPipe's detector and face mesh on onnxruntime (Apache-2.0 models); "hog" and "cnn"
are dlib's, with its 68-point shape predictor (a non-commercial model). dlib is imported only when asked for,
so the default path runs without it.
"""

from __future__ import annotations

from typing import Any

from landmarks.detect import DEFAULT_DETECTOR, DetectorKind, FaceDetector
from landmarks.track import FrameTracker

DETECTOR_KINDS: tuple[str, ...] = ("mesh", "hog", "cnn")


def make_detector(kind: DetectorKind | str = DEFAULT_DETECTOR, **options: Any) -> FaceDetector:
    """A detector by name; ``options`` go to its constructor (dlib: max_side, upsample, min_score;
    mesh: min_score, min_presence)."""
    if kind == "mesh":
        from landmarks.mesh_track import MeshDetector

        return MeshDetector(**options)
    if kind in ("hog", "cnn"):
        from landmarks.detect import DlibDetector

        return DlibDetector(kind=kind, **options)  # type: ignore[arg-type]
    raise ValueError(f"detector must be one of {', '.join(DETECTOR_KINDS)}, got {kind!r}")


def make_tracker(detector: FaceDetector | str | None = None, **options: Any) -> FrameTracker:
    """The tracker that goes with ``detector`` (a detector, a kind, or None for the default); ``options`` go to
    the tracker (face_index, ...)."""
    if detector is None or isinstance(detector, str):
        detector = make_detector(detector or DEFAULT_DETECTOR)
    if detector.kind == "mesh":
        from landmarks.mesh_track import MeshTracker

        return MeshTracker(detector, **options)  # type: ignore[arg-type]
    from landmarks.track import LandmarkTracker

    return LandmarkTracker(detector, **options)  # type: ignore[arg-type]
