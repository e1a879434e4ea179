"""``lsr landmarks``: landmarks of an image, a folder of images or a video, written to a folder.

Outputs in ``out`` (all written atomically):
  landmarks.npy      (N, 68, 2) float32 x, y pixels, NaN rows for frames/images without a face
  landmarks_raw.npy  video with smoothing only: the tracked landmarks before One-Euro smoothing
  summary.json       input, kind, frames, missing indices, fps, detector, smoothing, pose per frame, ...
  overlay.png        image input: landmarks drawn over the image
  overlays/*.png     folder input: one overlay per image (same stem)
  overlay.mp4        video input: H.264 overlay video with the source's audio
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from landmarks.detect.face_detector import DEFAULT_DETECTOR, DetectorKind, FaceDetector
from landmarks.detect.registry import make_detector, make_tracker
from landmarks.exceptions import InputFileError, NoFaceError
from landmarks.io.image_files import IMAGE_SUFFIXES, check_output_path, read_image, write_image, write_json, write_npy
from landmarks.shape.ibug68 import NUM_LANDMARKS
from landmarks.motion.head_pose import estimate_head_pose
from landmarks.shape.raster import draw_landmarks
from landmarks.motion.smooth import jitter, smooth_sequence
from landmarks.io.video import VIDEO_SUFFIXES, VideoWriter, iter_frames, probe_video


def draw_overlay(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Landmark drawing over a picture. image: (H, W, 3) uint8 RGB; landmarks: (68, 2), NaN = none drawn."""
    # Thinner than the model's landmark image (2.78 px per 224 px) so the face stays visible.
    drawing = draw_landmarks(landmarks, image.shape[:2], thickness=max(1.5, min(image.shape[:2]) / 256.0))
    # The drawing is anti-aliased colour on black; its strongest channel tells where ink is.
    coverage = np.clip(drawing.max(axis=2, keepdims=True).astype(np.float32) / 128.0, 0.0, 1.0)
    blended = image.astype(np.float32) * (1.0 - coverage) + drawing.astype(np.float32)
    return np.clip(blended, 0, 255).astype(np.uint8)


def input_kind(path: Path) -> str:
    """"folder", "video" or "image" (anything that is not a folder or a known video suffix)."""
    if path.is_dir():
        return "folder"
    if not path.exists():
        raise InputFileError(f"input not found: {path}; give an image, a folder of images or a video")
    return "video" if path.suffix.lower() in VIDEO_SUFFIXES else "image"


def _finite_or_none(value: float) -> float | None:
    """JSON has no NaN: missing numbers become null."""
    return float(value) if np.isfinite(value) else None


def _pose_rows(landmarks: np.ndarray, sizes: list[tuple[int, int]]) -> list[list[float] | None]:
    rows: list[list[float] | None] = []
    for points, size in zip(landmarks, sizes):
        angles = estimate_head_pose(points, size)
        rows.append(None if not np.isfinite(angles).all() else [round(float(a), 2) for a in angles])
    return rows


def _annotate_image(path: Path, out: Path, detector: FaceDetector, face_index: int, overlay: bool) -> dict[str, Any]:
    image = read_image(path)
    face = detector.detect_one(image, face_index, name=path.name)
    landmarks = face.landmarks[None]  # (1, 68, 2)
    write_npy(out / "landmarks.npy", landmarks)
    if overlay:
        write_image(out / "overlay.png", draw_overlay(image, face.landmarks))
    height, width = image.shape[:2]
    return {
        "frames": 1,
        "missing": [],
        "size": [height, width],
        "box": [round(float(v), 1) for v in face.box],
        "score": round(face.score, 3),
        "pose_yaw_pitch_roll_deg": _pose_rows(landmarks, [(height, width)]),
        "outputs": ["landmarks.npy"] + (["overlay.png"] if overlay else []),
    }


def _annotate_folder(path: Path, out: Path, detector: FaceDetector, face_index: int, overlay: bool) -> dict[str, Any]:
    files = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InputFileError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in folder {path}")
    landmarks = np.full((len(files), NUM_LANDMARKS, 2), np.nan, np.float32)
    sizes: list[tuple[int, int]] = []
    problems: dict[str, str] = {}
    for index, file in enumerate(tqdm(files, desc="images", unit="image")):
        try:
            image = read_image(file)
        except InputFileError as exc:  # one bad file does not sink the folder: it is recorded as missing
            problems[file.name] = str(exc)
            sizes.append((0, 0))
            continue
        sizes.append(image.shape[:2])
        faces = detector.detect(image)
        if len(faces) > face_index:
            landmarks[index] = faces[face_index].landmarks
        else:
            problems[file.name] = f"{len(faces)} face(s) found, face index {face_index} asked for"
        if overlay:
            write_image(out / "overlays" / f"{file.stem}.png", draw_overlay(image, landmarks[index]))
    missing = np.flatnonzero(~np.isfinite(landmarks).all(axis=(1, 2)))
    if len(missing) == len(files):
        raise NoFaceError(
            f"no face found in any of the {len(files)} images in {path}; use frontal, well-lit photos "
            "or try --detector cnn"
        )
    write_npy(out / "landmarks.npy", landmarks)
    return {
        "frames": len(files),
        "missing": missing.tolist(),
        "files": [file.name for file in files],
        "sizes": [list(size) for size in sizes],
        "problems": problems,
        "pose_yaw_pitch_roll_deg": _pose_rows(landmarks, sizes),
        "outputs": ["landmarks.npy"] + (["overlays/"] if overlay else []),
    }


def _annotate_video(
    path: Path,
    out: Path,
    detector: FaceDetector,
    face_index: int,
    smooth: bool,
    min_cutoff: float,
    beta: float,
    overlay: bool,
) -> dict[str, Any]:
    info = probe_video(path)
    tracker = make_tracker(detector, face_index=face_index)
    tracked = tracker.track_frames(iter_frames(path), total=info.frames, progress=True)
    if tracked.missing.all():
        raise NoFaceError(
            f"no face found in any of the {len(tracked.missing)} frames of {path.name}; "
            "use a video of a frontal, well-lit face or try --detector cnn"
        )
    outputs = ["landmarks.npy"]
    final = tracked.landmarks
    if smooth:
        final = smooth_sequence(tracked.landmarks, info.fps, min_cutoff=min_cutoff, beta=beta)
        write_npy(out / "landmarks_raw.npy", tracked.landmarks)
        outputs.append("landmarks_raw.npy")
    write_npy(out / "landmarks.npy", final)
    if overlay:
        metadata = {"comment": f"lsr landmarks overlay of {path.name}"}
        with VideoWriter(out / "overlay.mp4", info.fps, audio_from=path if info.has_audio else None,
                         metadata=metadata) as writer:
            frames = zip(iter_frames(path), final)
            for frame, points in tqdm(frames, total=len(final), desc="overlay", unit="frame"):
                writer.write(draw_overlay(frame, points))
        outputs.append("overlay.mp4")
    size = (info.height, info.width)
    return {
        "frames": len(final),
        "missing": np.flatnonzero(tracked.missing).tolist(),
        "fps": info.fps,
        "size": list(size),
        "has_audio": info.has_audio,
        "detections": tracked.detections,
        # Mean frame-to-frame motion / inter-ocular distance (null with < 2 consecutive faces).
        "jitter_raw": _finite_or_none(jitter(tracked.landmarks)),
        "jitter_final": _finite_or_none(jitter(final)),
        "pose_yaw_pitch_roll_deg": _pose_rows(final, [size] * len(final)),
        "outputs": outputs,
    }


def annotate_path(
    input: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    detector: DetectorKind = DEFAULT_DETECTOR,
    face_index: int = 0,
    smooth: bool = True,
    min_cutoff: float = 1.0,
    beta: float = 0.05,
    overlay: bool = True,
) -> dict[str, Any]:
    """Landmarks of an image, a folder of images or a video into ``out``; returns the summary dict.

    Raises InputFileError (missing/corrupt input), OutputPathError (``out`` cannot be written; checked first),
    NoFaceError (no face at all). A failed run leaves no folder or overlay it created.
    """
    input_path, out = Path(input), Path(out)
    kind = input_kind(input_path)
    check_output_path(out, "--out", folder=True)
    face_detector = make_detector(detector)
    created = out  # the topmost folder this call creates: removed again if the work fails
    while not created.parent.exists():
        created = created.parent
    created = None if created.exists() else created
    out.mkdir(parents=True, exist_ok=True)
    overlays_existed = (out / "overlays").exists()
    try:
        if kind == "image":
            details = _annotate_image(input_path, out, face_detector, face_index, overlay)
        elif kind == "folder":
            details = _annotate_folder(input_path, out, face_detector, face_index, overlay)
        else:
            details = _annotate_video(input_path, out, face_detector, face_index, smooth, min_cutoff, beta, overlay)
    except BaseException:  # leave nothing of a failed run: no empty folders, no half a set of overlays
        if created is not None:
            shutil.rmtree(created, ignore_errors=True)
        elif not overlays_existed:
            shutil.rmtree(out / "overlays", ignore_errors=True)
        raise
    summary = {
        "input": str(input_path.resolve()),
        "kind": kind,
        "detector": detector,
        "face_index": face_index,
        "smoothing": {"enabled": smooth and kind == "video", "min_cutoff": min_cutoff, "beta": beta},
        "landmarks_format": "(N, 68, 2) float32 x, y pixels, iBUG-68 order; NaN rows = missing",
        **details,
    }
    summary.setdefault("fps", None)
    write_json(out / "summary.json", summary)
    found = summary["frames"] - len(summary["missing"])
    print(f"landmarks: {kind} {input_path.name}: face in {found}/{summary['frames']} frame(s) -> {out}")
    return summary
