"""Rebuild the shipped face models (``landmarks/assets/mediapipe``) from the MediaPipe 0.10.21 wheel.

    python -m landmarks.detect.rebuild_mediapipe [--wheel PATH] [--frames VIDEO ...] [--out DIR]

Steps: fetch the wheel with pip (or take ``--wheel``) and refuse it unless its sha256 is the pinned one; take
the short-range face detector and the face-mesh ``.tflite`` out of it; convert both with
``landmarks.detect.tflite_onnx``; run the original (TFLite, ai-edge-litert) and the conversion (onnxruntime) on the
same real inputs and refuse when they disagree; only then write into ``--out`` (each file atomically):

  face_detection_short_range.onnx, face_landmark.onnx   the converted nets
  SOURCES.json   wheel, checksums of every file, converter commit and tool versions, the check's numbers
  LICENSE        the wheel's own Apache-2.0 licence text
  NOTICE         what these files are and what was changed

Inputs of the check, as the runtime (``landmarks.detect.mediapipe_mesh``) makes them: the detector sees the frame letterboxed
to 128x128 in [-1, 1]; the mesh sees the 192x192 crop of the region from the best detection in [0, 1]
(a centred square when nothing is detected). Needs ``pip install .[convert]`` (tflite, ai-edge-litert).
"""

from __future__ import annotations

import glob
import hashlib
import importlib.metadata
import os
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from landmarks.detect import mediapipe_mesh as mesh
from landmarks.scene import person_matte as segment
from landmarks.exceptions import InputFileError, LandmarksError
from landmarks.io.image_files import atomic_output, write_json

PACKAGE = "mediapipe"
VERSION = "0.10.21"
WHEEL_NAME = "mediapipe-0.10.21-cp311-cp311-manylinux_2_28_x86_64.whl"
WHEEL_SHA256 = "05dc4a9e593655a79558d05d6227d31018c2537a4bd3362b51e230cf22aecfe3"
PIP_ARGS = ("download", f"{PACKAGE}=={VERSION}", "--no-deps", "--only-binary", ":all:",
            "--python-version", "3.11", "--platform", "manylinux_2_28_x86_64")
LICENSE_MEMBER = f"{PACKAGE}-{VERSION}.dist-info/LICENSE"
# (path inside the wheel, shipped ONNX name)
MODELS = (
    ("mediapipe/modules/face_detection/face_detection_short_range.tflite", mesh.DETECTOR_FILE),
    ("mediapipe/modules/face_landmark/face_landmark.tflite", mesh.MESH_FILE),
    ("mediapipe/modules/iris_landmark/iris_landmark.tflite", mesh.IRIS_FILE),
    ("mediapipe/modules/selfie_segmentation/selfie_segmentation.tflite", segment.SEGMENTER_FILE),
)
FRAMES_PER_VIDEO = 10
POINT_TOLERANCE = 0.05  # crop pixels (of 192 for the mesh, 64 for the eyes): far below what anything downstream sees
SCORE_TOLERANCE = 1e-3  # sigmoid scores: detection and face presence, and the segmenter's matte
REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_CLIPS = ("../shared/data/clips/tpsmm_driving.mp4",)
DEFAULT_REAL_GLOB = "../shared/data/real_talking_heads/real0*/**/*.mp4"
DEFAULT_REAL_COUNT = 2
RANDOM_SIDE = 256

NOTICE = f"""\
face_detection_short_range.onnx, face_landmark.onnx, iris_landmark.onnx and selfie_segmentation.onnx in this folder
are converted from the TensorFlow Lite models mediapipe/modules/face_detection/face_detection_short_range.tflite,
mediapipe/modules/face_landmark/face_landmark.tflite, mediapipe/modules/iris_landmark/iris_landmark.tflite and
mediapipe/modules/selfie_segmentation/selfie_segmentation.tflite of MediaPipe {VERSION}
(Copyright Google LLC; Apache License, Version 2.0: see LICENSE in this folder).

Changes made: the file format was converted from TensorFlow Lite to ONNX (landmarks/detect/tflite_onnx.py), and the
float16 weights were widened to float32. Weights and architecture are otherwise unchanged; the outputs of the
converted nets were checked against the originals' (inputs and numbers in SOURCES.json).

These files are redistributed under the Apache License, Version 2.0.
"""


class MediapipeWheelError(LandmarksError):
    """The MediaPipe wheel cannot be fetched, is not the pinned file, or lacks a member we need."""


class ParityError(LandmarksError):
    """The converted ONNX nets disagree with the original TFLite nets beyond the tolerances."""


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


# -- the wheel ---------------------------------------------------------------------------------------
def download_wheel(folder: Path) -> Path:
    """``pip download`` the pinned wheel into ``folder`` (pip's own index and cache settings apply)."""
    command = [sys.executable, "-m", "pip", *PIP_ARGS, "-d", str(folder)]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        last = (result.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise MediapipeWheelError(f"pip could not download {PACKAGE}=={VERSION}: {last}; "
                                  "check the network, or pass a downloaded wheel with --wheel")
    wheels = sorted(folder.glob(f"{PACKAGE}-{VERSION}-*.whl"))
    if not wheels:
        raise MediapipeWheelError(f"pip download left no {PACKAGE}-{VERSION} wheel in {folder}")
    return wheels[0]


def verify_wheel(path: Path) -> str:
    """The wheel's sha256, or MediapipeWheelError unless it is the pinned file."""
    if not path.is_file():
        raise MediapipeWheelError(f"wheel {path} not found; pass the {WHEEL_NAME} file with --wheel, or omit "
                                  "--wheel to download it")
    digest = sha256_file(path)
    if digest != WHEEL_SHA256:
        raise MediapipeWheelError(f"{path.name} has sha256 {digest}, expected {WHEEL_SHA256} ({WHEEL_NAME}); "
                                  "refusing to convert an unpinned wheel")
    return digest


def read_member(wheel: Path, member: str) -> bytes:
    with zipfile.ZipFile(wheel) as archive:
        try:
            return archive.read(member)
        except KeyError:
            raise MediapipeWheelError(f"{wheel.name} has no {member}") from None


# -- the check ---------------------------------------------------------------------------------------
def _onnx_session(model_bytes: bytes) -> Any:
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1  # as the runtime (landmarks.detect.mediapipe_mesh) runs it
    options.inter_op_num_threads = 1
    return ort.InferenceSession(model_bytes, options, providers=["CPUExecutionProvider"])


class _TfliteNet:
    """The original net on ai-edge-litert (XNNPACK, one thread: what MediaPipe itself runs on CPU)."""

    def __init__(self, model_bytes: bytes) -> None:
        try:
            from ai_edge_litert.interpreter import Interpreter
        except ImportError as exc:
            raise MediapipeWheelError("the check needs the TFLite runtime: pip install '.[convert]' "
                                      "(ai-edge-litert)") from exc
        self.interpreter = Interpreter(model_content=model_bytes, num_threads=1)
        self.interpreter.allocate_tensors()

    def run(self, tensor: np.ndarray) -> dict[str, np.ndarray]:
        self.interpreter.set_tensor(self.interpreter.get_input_details()[0]["index"], tensor)
        self.interpreter.invoke()
        return {out["name"]: self.interpreter.get_tensor(out["index"]).copy()
                for out in self.interpreter.get_output_details()}


def _run_onnx(session: Any, tensor: np.ndarray) -> dict[str, np.ndarray]:
    names = [out.name for out in session.get_outputs()]
    return dict(zip(names, session.run(None, {session.get_inputs()[0].name: tensor})))


def _max_abs(first: dict[str, np.ndarray], second: dict[str, np.ndarray]) -> dict[str, float]:
    if first.keys() != second.keys():
        raise ParityError(f"output names differ: TFLite {sorted(first)} vs ONNX {sorted(second)}")
    return {name: float(np.abs(first[name].astype(np.float64) - second[name]).max()) for name in first}


def compare_frame(image: np.ndarray, nets: dict[str, tuple[Any, Any]]) -> dict[str, Any]:
    """Both versions of both nets on one (H, W, 3) uint8 RGB frame: the largest differences."""
    detector_in, scale, offset = mesh.detector_input(image)  # as detect_faces
    tflite_detector, onnx_detector = nets[mesh.DETECTOR_FILE]
    reference, converted = tflite_detector.run(detector_in), _run_onnx(onnx_detector, detector_in)
    detector_diff = _max_abs(reference, converted)
    score_diff = float(np.abs(mesh.sigmoid(reference["classificators"]) - mesh.sigmoid(converted["classificators"])).max())
    # The reference's detection picks the crop, so both mesh nets see the same pixels.
    found = mesh.decode_detections(reference["regressors"], reference["classificators"], scale, offset)
    region = mesh.region_from_detection(found[0]) if found else None
    detected = region is not None
    if region is None:
        height, width = image.shape[:2]
        region = mesh.Region((width / 2.0, height / 2.0), float(min(height, width)), 0.0)
    crop = cv2.warpAffine(image, region.to_crop(mesh.MESH_SIZE), (mesh.MESH_SIZE, mesh.MESH_SIZE),
                          flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)  # as predict_mesh
    mesh_in = (crop.astype(np.float32) / 255.0)[None]  # (1, 192, 192, 3) in [0, 1]
    tflite_mesh, onnx_mesh = nets[mesh.MESH_FILE]
    reference, converted = tflite_mesh.run(mesh_in), _run_onnx(onnx_mesh, mesh_in)
    mesh_diff = _max_abs(reference, converted)
    points = [out[name].reshape(mesh.MESH_POINTS, 3) for out in (reference, converted)
              for name in out if out[name].size == 3 * mesh.MESH_POINTS]
    flags = [out[name] for out in (reference, converted) for name in out if out[name].size == 1]
    if len(points) != 2 or len(flags) != 2:
        raise ParityError("the mesh net should give 468 x 3 points and one presence logit")
    # The eyes' squares come from the reference's mesh (in frame pixels), as refine_eye_contours makes them.
    frame_points = mesh.to_frame(points[0][:, :2].astype(np.float64), region.to_crop(mesh.MESH_SIZE))
    tflite_iris, onnx_iris = nets[mesh.IRIS_FILE]
    iris_diff: dict[str, float] = {}
    iris_px = 0.0
    for corners, _, mirrored in mesh.EYE_CONTOURS:
        eye_in = mesh.eye_input(image, mesh.eye_region(frame_points, corners), mirrored)
        reference, converted = tflite_iris.run(eye_in), _run_onnx(onnx_iris, eye_in)
        iris_diff = _merge_max([iris_diff, _max_abs(reference, converted)])
        eyes = [out[name].reshape(-1, 3) for out in (reference, converted) for name in out if out[name].size == 71 * 3]
        if len(eyes) != 2:
            raise ParityError("the iris net should give 71 x 3 eye points")
        iris_px = max(iris_px, float(np.linalg.norm(eyes[0][:, :2].astype(np.float64) - eyes[1][:, :2], axis=1).max()))
    # the segmenter on the whole frame, as landmarks.scene.person_matte.person_matte gives it
    small = cv2.resize(image, (segment.SEGMENTER_SIZE, segment.SEGMENTER_SIZE), interpolation=cv2.INTER_AREA)
    segmenter_in = (small.astype(np.float32) / 255.0)[None]
    tflite_segmenter, onnx_segmenter = nets[segment.SEGMENTER_FILE]
    segmenter_diff = _max_abs(tflite_segmenter.run(segmenter_in), _run_onnx(onnx_segmenter, segmenter_in))
    return {
        "detected": detected,
        "matte": max(segmenter_diff.values()),
        "detector_max_abs": detector_diff,
        "detection_score": score_diff,
        "mesh_max_abs": mesh_diff,
        "mesh_point_px": float(np.linalg.norm(points[0][:, :2].astype(np.float64) - points[1][:, :2], axis=1).max()),
        "presence_score": float(np.abs(mesh.sigmoid(flags[0]) - mesh.sigmoid(flags[1])).max()),
        "iris_max_abs": iris_diff,
        "iris_point_px": iris_px,
    }


def display_path(path: Path) -> str:
    """A repo-relative (or ../shared-relative) path for the record; never an absolute machine path."""
    resolved = path.resolve()
    for base in (REPO_ROOT, REPO_ROOT.parent / "shared"):
        if resolved.is_relative_to(base):
            return os.path.relpath(resolved, REPO_ROOT)
    return path.name


def default_frames() -> list[Path]:
    """The shared clips that exist here: tpsmm_driving and the first real talking heads (sorted)."""
    clips = [REPO_ROOT / clip for clip in DEFAULT_CLIPS]
    real = sorted(glob.glob(str(REPO_ROOT / DEFAULT_REAL_GLOB), recursive=True))[:DEFAULT_REAL_COUNT]
    return [path for path in clips + [Path(p) for p in real] if path.is_file()]


def sample_frames(video: Path, count: int) -> Iterator[tuple[int, np.ndarray]]:
    """About ``count`` frames spread evenly through the clip: (index, (H, W, 3) uint8 RGB)."""
    from landmarks.io.video import iter_frames, probe_video

    total = probe_video(video).frames
    wanted = set(np.linspace(0, total - 1, min(count, total)).round().astype(int).tolist())
    for index, frame in enumerate(iter_frames(video)):
        if index in wanted:
            yield index, frame
        if index >= max(wanted):
            break


def check_conversion(tflite_models: dict[str, bytes], onnx_models: dict[str, bytes], videos: Sequence[Path],
                     frames_per_video: int = FRAMES_PER_VIDEO) -> dict[str, Any]:
    """Run TFLite and ONNX side by side on frames of ``videos`` (a seeded random image when there are none).

    Returns the record for SOURCES.json; raises ParityError past the tolerances."""
    from tqdm import tqdm

    nets = {name: (_TfliteNet(tflite_models[name]), _onnx_session(onnx_models[name])) for name in onnx_models}
    rows: list[dict[str, Any]] = []
    if videos:
        progress = tqdm(total=len(videos) * frames_per_video, desc="tflite vs onnx", unit="frame")
        for video in videos:
            results, indices = [], []
            for index, frame in sample_frames(video, frames_per_video):
                results.append(compare_frame(frame, nets))
                indices.append(index)
                progress.update()
            rows.append(_summarise(display_path(video), indices, results))
        progress.close()
        inputs = "video frames, evenly spread through each clip"
    else:
        image = np.random.default_rng(0).integers(0, 256, (RANDOM_SIDE, RANDOM_SIDE, 3), dtype=np.uint8)
        rows.append(_summarise("random", [0], [compare_frame(image, nets)]))
        inputs = (f"no video given or found: one seeded random image (numpy default_rng(0), {RANDOM_SIDE}x{RANDOM_SIDE} uint8); "
                  "no face in it, so the mesh saw a centred square crop")
    keys = ("detection_score", "mesh_point_px", "presence_score", "iris_point_px", "matte")
    worst = {key: max(row[key] for row in rows) for key in keys}
    for key in ("detector_max_abs", "mesh_max_abs", "iris_max_abs"):
        worst[key] = _merge_max(row[key] for row in rows)
    record = {
        "inputs": inputs,
        "tflite_runtime": "ai-edge-litert Interpreter, default (XNNPACK) kernels, 1 thread",
        "onnx_runtime": "onnxruntime CPUExecutionProvider, 1 thread",
        "tolerances": {"mesh_point_px": POINT_TOLERANCE, "iris_point_px": POINT_TOLERANCE, "score": SCORE_TOLERANCE},
        "max": worst,
        "per_input": rows,
    }
    # `not <=` so that a NaN fails too
    failed = [f"{key.split('_')[0]} points differ by {worst[key]:.4g} crop px (> {POINT_TOLERANCE})"
              for key in ("mesh_point_px", "iris_point_px") if not worst[key] <= POINT_TOLERANCE]
    failed += [f"{key.replace('_', ' ')}s differ by {worst[key]:.4g} (> {SCORE_TOLERANCE})"
               for key in ("detection_score", "presence_score", "matte") if not worst[key] <= SCORE_TOLERANCE]
    if failed:
        raise ParityError(f"converted nets disagree with the TFLite originals: {'; '.join(failed)}; nothing written")
    return record


def _merge_max(dicts: Iterator[dict[str, float]]) -> dict[str, float]:
    merged: dict[str, float] = {}
    for values in dicts:
        for name, value in values.items():
            merged[name] = max(merged.get(name, 0.0), value)
    return merged


def _summarise(source: str, indices: list[int], results: list[dict[str, Any]]) -> dict[str, Any]:
    if not results:
        raise InputFileError(f"--frames {source}: no frame could be decoded")
    return {
        "source": source,
        "frames": indices,
        "faces_detected": sum(result["detected"] for result in results),
        "detector_max_abs": _merge_max(result["detector_max_abs"] for result in results),
        "detection_score": max(result["detection_score"] for result in results),
        "mesh_max_abs": _merge_max(result["mesh_max_abs"] for result in results),
        "mesh_point_px": max(result["mesh_point_px"] for result in results),
        "presence_score": max(result["presence_score"] for result in results),
        "iris_max_abs": _merge_max(result["iris_max_abs"] for result in results),
        "iris_point_px": max(result["iris_point_px"] for result in results),
        "matte": max(result["matte"] for result in results),
    }


# -- the record --------------------------------------------------------------------------------------
def _converter_version() -> dict[str, Any]:
    """The repo commit (``unknown`` outside a git checkout) and whether the converter had uncommitted edits."""
    def git(*args: str) -> str | None:
        try:
            result = subprocess.run(["git", "-C", str(REPO_ROOT), *args], capture_output=True, text=True, check=False)
        except OSError:
            return None
        return result.stdout.strip() if result.returncode == 0 else None

    commit = git("rev-parse", "HEAD") if (REPO_ROOT / ".git").exists() else None
    files = ("landmarks/detect/tflite_onnx.py", "landmarks/detect/rebuild_mediapipe.py")
    status = git("status", "--porcelain", "--", *files) if commit else None
    tools = {}
    for dist in ("tflite", "onnx", "onnxruntime", "ai-edge-litert", "numpy"):
        try:
            tools[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            tools[dist] = "unknown"
    return {"module": "landmarks.detect.tflite_onnx", "commit": commit or "unknown",
            "uncommitted_changes": bool(status) if commit else None, "tools": tools}


def build_sources(downloaded: bool, tflite_models: dict[str, bytes], onnx_models: dict[str, bytes],
                  license_text: bytes, check: dict[str, Any]) -> dict[str, Any]:
    how = "pip " + " ".join(PIP_ARGS) + " (from the public package index; the sha256 above is pinned and checked)"
    return {
        "source": {
            "package": PACKAGE,
            "version": VERSION,
            "wheel": WHEEL_NAME,
            "sha256": WHEEL_SHA256,
            "fetched_with": how,
            "fetched_by_this_run": downloaded,  # False: a local copy given with --wheel (same checksum)
            "license": {"file": "LICENSE", "copied_from": LICENSE_MEMBER, "sha256": sha256_bytes(license_text),
                        "spdx": "Apache-2.0"},
        },
        "models": [
            {
                "onnx": onnx_name,
                "onnx_sha256": sha256_bytes(onnx_models[onnx_name]),
                "onnx_bytes": len(onnx_models[onnx_name]),
                "tflite": member,
                "tflite_sha256": sha256_bytes(tflite_models[onnx_name]),
                "tflite_bytes": len(tflite_models[onnx_name]),
            }
            for member, onnx_name in MODELS
        ],
        "converter": {**_converter_version(),
                      "changes": "TFLite -> ONNX (opset 17, NCHW inside, NHWC inputs/outputs as the TFLite models); "
                                 "float16 weights widened to float32"},
        "check": check,
    }


def convert_wheel(wheel: Path | None, out: Path, videos: Sequence[Path],
                  frames_per_video: int = FRAMES_PER_VIDEO) -> dict[str, Any]:
    """Fetch/verify, convert, check, write. Returns the SOURCES.json record."""
    from landmarks.detect.tflite_onnx import convert

    missing = [str(video) for video in videos if not Path(video).is_file()]
    if missing:  # before the download and conversion, not after
        raise InputFileError(f"--frames: no such video file: {', '.join(missing)}")
    with tempfile.TemporaryDirectory(prefix="mediapipe-wheel-") as scratch_name:
        scratch = Path(scratch_name)
        downloaded = wheel is None
        wheel = download_wheel(scratch) if wheel is None else wheel
        verify_wheel(wheel)
        tflite_models, onnx_models = {}, {}
        for member, onnx_name in MODELS:
            tflite_models[onnx_name] = read_member(wheel, member)
            source = scratch / Path(member).name
            source.write_bytes(tflite_models[onnx_name])
            onnx_models[onnx_name] = convert(source).SerializeToString()
        license_text = read_member(wheel, LICENSE_MEMBER)
    # Check before writing anything, so a failed check leaves the shipped files as they were.
    check = check_conversion(tflite_models, onnx_models, videos, frames_per_video)
    record = build_sources(downloaded, tflite_models, onnx_models, license_text, check)
    for name, data in [*onnx_models.items(), ("LICENSE", license_text), ("NOTICE", NOTICE.encode())]:
        with atomic_output(out / name) as temp:
            temp.write_bytes(data)
    write_json(out / "SOURCES.json", record)
    return record


def summary_table(record: dict[str, Any]) -> str:
    header = ("input", "frames", "faces", "det |d|max", "det score d", "mesh |d|max", "point d px", "presence d",
              "eye point d px", "matte d")
    lines = []
    check = record["check"]
    for row in [*check["per_input"], {"source": "all", "frames": sum((r["frames"] for r in check["per_input"]), []),
                                      "faces_detected": sum(r["faces_detected"] for r in check["per_input"]),
                                      **check["max"]}]:
        lines.append((row["source"], str(len(row["frames"])), str(row["faces_detected"]),
                      f"{max(row['detector_max_abs'].values()):.2e}", f"{row['detection_score']:.2e}",
                      f"{max(row['mesh_max_abs'].values()):.2e}", f"{row['mesh_point_px']:.2e}",
                      f"{row['presence_score']:.2e}", f"{row['iris_point_px']:.2e}", f"{row['matte']:.2e}"))
    widths = [max(len(cells[i]) for cells in [header, *lines]) for i in range(len(header))]
    text = [" | ".join(cell.ljust(width) for cell, width in zip(cells, widths)) for cells in [header, *lines]]
    text.insert(1, "-+-".join("-" * width for width in widths))
    files = [f"  {m['onnx']}: {m['onnx_bytes']} bytes, sha256 {m['onnx_sha256']}" for m in record["models"]]
    return "\n".join(text + ["", *files])


def run_convert(cfg: Any) -> dict[str, Any]:
    """Entry point of ``lsr face-models convert`` (``lsr.config.FaceModelsConvertConfig``): convert, check, print."""
    videos = list(cfg.frames) or default_frames()
    out = Path(cfg.out) if cfg.out is not None else mesh.ASSETS
    record = convert_wheel(cfg.wheel, out, videos, max(1, cfg.frames_per_video))
    print(summary_table(record))
    print(f"wrote {', '.join(name for _, name in MODELS)}, SOURCES.json, LICENSE, NOTICE to {out}")
    return record
