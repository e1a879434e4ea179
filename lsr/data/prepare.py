"""``lsr prepare``: real videos and images -> the dataset format of ``lsr.data.format``.

Inputs found under the input folder (or one file):

* VoxCeleb2 layout ``<id>/<video>/<clip>.mp4`` -> identity ``<id>``, video ``<video>_<clip>`` (recognised
  by the ``id<digits>`` folder name at any depth, or by depth 3 below the input); ``<person>/<clip>.mp4`` -> identity ``<person>``, video ``<clip>``; a bare ``clip.mp4`` -> identity and
  video ``clip``.
* Folders of images: one clip per folder (identity = parent folder name, video = folder name).
* The LSR release layout ``.../{train,test}/<id>/<video>/combined/NNNNN_rgb.png``: one clip per
  (split, id, video) with video name ``<video>_<split>`` and ``meta["source_split"]``. That layout's
  train/test are the FSTH protocol's 32 K-shot input frames and 32 hold-out frames of the *same*
  identity, so they cannot be a manifest split (manifest splits are by identity): they stay separate
  videos. Only ``*_rgb.png`` are read; an official ``*_segmap_merged.png`` beside a frame is used
  (remapped to ``SEG_CLASSES``) instead of the oracle when the framing is kept.

Per clip: frames are sampled uniformly (``frames_per_clip``, 0 = all). Sampled frames get per-frame
detection, and frames without a face are dropped (counted, logged). With all frames the video is
tracked (``landmarks.detect.dlib_tracker``) and One-Euro smoothed; frames without a face are kept with NaN
landmarks (the format allows it) and cropped like the nearest frame with a face, so the clip stays
aligned with the video. Framing: ``align`` crops and aligns each frame (``landmarks.align.crop``);
``keep`` centre-crops to a square and resizes (the LSR release frames are already aligned 224^2
VoxCeleb2 crops); ``auto`` = keep for the LSR release layout, align otherwise. Segmentation: the
landmark-seeded oracle of ``lsr.data.oracle_seg``.

Robustness: clips run in a process pool; finished clips (folder with meta.json; ``write_clip`` is
atomic) are skipped, so a run can be resumed; a failing clip is logged and skipped; if every clip
fails ``DatasetError`` is raised (the CLI exits 2).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import multiprocessing
import os
import re
import time
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from lsr.data import format as fmt
from lsr.errors import DatasetError

log = logging.getLogger("lsr.prepare")

Framing = Literal["auto", "align", "keep"]
_VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".webm", ".gif", ".mpg", ".mpeg", ".flv", ".wmv")
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
_LSR_SPLITS = ("train", "test")
_VOXCELEB_ID = re.compile(r"id\d+")


@dataclasses.dataclass(frozen=True)
class ClipSource:
    """One input clip. kind: "video" (path = file) | "images" | "lsr_release" (path = folder)."""

    identity: str
    video: str
    path: Path
    kind: Literal["video", "images", "lsr_release"]
    source_split: str | None = None


@dataclasses.dataclass(frozen=True)
class PrepareOptions:
    """Per-clip settings (picklable, sent to the workers)."""

    size: int = 256
    frames_per_clip: int = 10
    framing: Framing = "auto"
    detector: str = "mesh"
    official_segmaps: bool = True
    smooth: bool = True


@dataclasses.dataclass
class ClipOutcome:
    source: ClipSource
    status: Literal["done", "skipped", "failed"]
    frames: int = 0
    missing: int = 0  # frames without a face: dropped (sampled) or kept with NaN landmarks (all frames)
    dropped: int = 0
    message: str = ""
    seconds: float = 0.0


@dataclasses.dataclass
class PrepareSummary:
    outcomes: list[ClipOutcome]
    seconds: float

    def count(self, status: str) -> int:
        return sum(1 for o in self.outcomes if o.status == status)

    @property
    def frames(self) -> int:
        return sum(o.frames for o in self.outcomes)

    def table(self) -> str:
        done, skipped, failed = self.count("done"), self.count("skipped"), self.count("failed")
        missing = sum(o.missing for o in self.outcomes)
        dropped = sum(o.dropped for o in self.outcomes)
        rate = self.frames / self.seconds if self.seconds > 0 else float("nan")
        lines = [
            f"clips       done {done}, skipped (already prepared) {skipped}, failed {failed}",
            f"frames      written {self.frames} ({rate:.2f} frames/s over {self.seconds:.1f} s)",
            f"no face     {missing} frame(s): {dropped} dropped (sampled frames), {missing - dropped} kept with NaN landmarks",
        ]
        lines += [f"failed      {o.source.identity}/{o.source.video}: {o.message}" for o in self.outcomes if o.status == "failed"]
        return "\n".join(lines)


# -- discovery -------------------------------------------------------------------------------------


def _safe(name: str) -> str:
    cleaned = "".join(c if c.isalnum() or c in "-_." else "_" for c in name).strip(".")
    return cleaned or "unnamed"


def discover_sources(input_path: str | os.PathLike[str]) -> list[ClipSource]:
    """All clips under ``input_path`` (see the module docstring for the layouts), sorted."""
    root = Path(input_path)
    if not root.exists():
        raise DatasetError(f"input {root} does not exist; give a video, a folder of videos/images or an LSR release folder")
    if root.is_file():
        if root.suffix.lower() not in _VIDEO_SUFFIXES:
            raise DatasetError(f"{root} is not a video ({', '.join(_VIDEO_SUFFIXES)}); give a video or a folder")
        return [ClipSource(_safe(root.stem), _safe(root.stem), root, "video")]
    sources: list[ClipSource] = []
    for folder, _, names in os.walk(root):
        folder_path = Path(folder)
        names = sorted(n for n in names if not n.startswith("."))
        relative = folder_path.relative_to(root).parts
        rgb = [n for n in names if n.endswith("_rgb.png")]
        if rgb and folder_path.name == "combined" and len(folder_path.parts) >= 4 and folder_path.parts[-4] in _LSR_SPLITS:
            split, identity, video = folder_path.parts[-4], folder_path.parts[-3], folder_path.parts[-2]
            sources.append(ClipSource(_safe(identity), _safe(f"{video}_{split}"), folder_path, "lsr_release", split))
            continue
        for name in names:
            if Path(name).suffix.lower() in _VIDEO_SUFFIXES:
                parts = (*relative, Path(name).stem)
                if _VOXCELEB_ID.fullmatch(folder_path.parent.name):  # id00017/<video>/<clip>.mp4 at any depth
                    identity, video = folder_path.parent.name, f"{folder_path.name}_{Path(name).stem}"
                elif len(parts) >= 3:
                    identity, video = parts[-3], f"{parts[-2]}_{parts[-1]}"
                elif len(parts) == 2:
                    identity, video = parts
                else:
                    identity = video = parts[0]
                sources.append(ClipSource(_safe(identity), _safe(video), folder_path / name, "video"))
        if any(Path(n).suffix.lower() in _IMAGE_SUFFIXES for n in names):
            identity = folder_path.parent.name if relative else folder_path.name
            sources.append(ClipSource(_safe(identity), _safe(folder_path.name), folder_path, "images"))
    keys = [(s.identity, s.video) for s in sources]
    duplicates = sorted({k for k in keys if keys.count(k) > 1})
    if duplicates:
        raise DatasetError(f"several inputs map to the same clip name {duplicates[:3]}; rename them or prepare them separately")
    return sorted(sources, key=lambda s: (s.identity, s.video))


# -- one clip --------------------------------------------------------------------------------------


def sample_indices(total: int, count: int) -> np.ndarray:
    """``count`` indices spread uniformly over ``total`` frames (all when count == 0 or >= total)."""
    if count <= 0 or count >= total:
        return np.arange(total)
    return np.unique(np.round(np.linspace(0, total - 1, count)).astype(np.int64))


def _read_source_frames(source: ClipSource, frames_per_clip: int) -> tuple[list[np.ndarray], list[int], float, list[Path]]:
    """Sampled frames (H, W, 3) uint8 RGB, their source indices, fps, and their files (images only)."""
    from landmarks.io.image_files import read_image
    from landmarks.io.video import iter_frames, probe_video

    if source.kind == "video":
        info = probe_video(source.path)
        wanted = set(sample_indices(info.frames, frames_per_clip).tolist())
        frames, indices = [], []
        for index, frame in enumerate(iter_frames(source.path)):
            if frames_per_clip <= 0 or index in wanted:
                frames.append(frame)
                indices.append(index)
        return frames, indices, info.fps, []
    pattern = "*_rgb.png" if source.kind == "lsr_release" else "*"
    files = sorted(p for p in source.path.glob(pattern) if p.suffix.lower() in _IMAGE_SUFFIXES)
    if source.kind == "images":
        files = [p for p in files if not p.name.endswith(("_contour.png", "_segmap_merged.png"))]
    if not files:
        raise DatasetError(f"{source.path}: no images found")
    chosen = sample_indices(len(files), frames_per_clip)
    return [read_image(files[i]) for i in chosen], chosen.tolist(), 25.0, [files[i] for i in chosen]


def _detect_landmarks(frames: list[np.ndarray], detector_kind: str, track: bool, fps: float, smooth: bool) -> np.ndarray:
    """(N, 68, 2) float32 landmarks, NaN rows where no face was found."""
    from landmarks.detect.registry import make_detector, make_tracker
    from landmarks.motion.smooth import smooth_sequence

    detector = make_detector(detector_kind)
    if track:
        landmarks = make_tracker(detector).track_frames(frames).landmarks
        return smooth_sequence(landmarks, fps) if smooth else landmarks
    rows = []
    for frame in frames:
        faces = detector.detect(frame)
        rows.append(faces[0].landmarks if faces else np.full((68, 2), np.nan, np.float32))
    return np.stack(rows).astype(np.float32)


def _keep_framing(frame: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Centre square crop + resize: (crop (size, size, 3), M (2, 3) source -> crop pixels)."""
    height, width = frame.shape[:2]
    side = min(height, width)
    x0, y0 = (width - side) / 2.0, (height - side) / 2.0
    scale = size / side
    # Pixel centres at integers: x_out + 0.5 = (x_in + 0.5 - x0) * scale.
    matrix = np.array([[scale, 0.0, (0.5 - x0) * scale - 0.5], [0.0, scale, (0.5 - y0) * scale - 0.5]])
    crop = cv2.warpAffine(frame, matrix, (size, size), flags=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
    return crop, matrix


def _apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    return (points @ matrix[:, :2].T + matrix[:, 2]).astype(np.float32)


def prepare_clip(source: ClipSource, out_root: Path, options: PrepareOptions) -> ClipOutcome:
    """Prepare one clip into ``out_root/<identity>/<video>``. Raises on failure (see ``_run_one``)."""
    from landmarks.motion.head_pose import estimate_head_pose

    from lsr.data.oracle_seg import oracle_segmentation, read_official_segmap

    started = time.perf_counter()
    frames, indices, fps, files = _read_source_frames(source, options.frames_per_clip)
    if not frames:
        raise DatasetError(f"{source.path}: no frames decoded")
    track = source.kind == "video" and options.frames_per_clip <= 0
    landmarks = _detect_landmarks(frames, options.detector, track, fps, options.smooth)
    found = np.isfinite(landmarks).all(axis=(1, 2))
    if not found.any():
        raise DatasetError(f"{source.path}: no face found in any of {len(frames)} frame(s); use footage with a visible frontal face")
    missing = int((~found).sum())
    keep = np.arange(len(frames)) if track else np.flatnonzero(found)
    framing = options.framing
    if framing == "auto":
        framing = "keep" if source.kind == "lsr_release" else "align"
    if framing == "align":
        from landmarks.align import crop as align_crop

    nearest_found = np.flatnonzero(found)
    out_frames, out_landmarks, out_segs, out_pose, transforms = [], [], [], [], []
    official_used = 0
    for position in keep:
        frame = frames[position]
        reference = landmarks[position] if found[position] else landmarks[nearest_found[np.argmin(np.abs(nearest_found - position))]]
        if framing == "align":
            cropped, matrix = align_crop(frame, reference, options.size)
            matrix = np.asarray(matrix, np.float64)
        else:
            cropped, matrix = _keep_framing(frame, options.size)
        crop_landmarks = _apply(matrix, landmarks[position]) if found[position] else np.full((68, 2), np.nan, np.float32)
        segmentation = None
        if framing == "keep" and options.official_segmaps and files:
            official = files[position].with_name(files[position].name.replace("_rgb.png", "_segmap_merged.png"))
            if official.is_file() and official != files[position]:
                segmentation = cv2.warpAffine(read_official_segmap(official), matrix, (options.size, options.size),
                                              flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
                official_used += 1
        if segmentation is None:
            segmentation = oracle_segmentation(cropped, crop_landmarks)
        out_frames.append(cropped)
        out_landmarks.append(crop_landmarks)
        out_segs.append(segmentation)
        out_pose.append(estimate_head_pose(crop_landmarks, (options.size, options.size)))
        transforms.append(np.round(matrix, 6).tolist())
    meta = {
        "origin": "video" if source.kind == "video" else "images",
        "identity": source.identity,
        "video": source.video,
        "fps": float(fps),
        "crop_transforms": transforms,
        "source_path": str(source.path),
        "source_split": source.source_split,
        "source_frame_indices": [int(indices[p]) for p in keep],
        "generator": {
            "tool": "lsr prepare",
            **dataclasses.asdict(options),
            "framing_used": framing,
            "segmentation": "official" if official_used == len(keep) else ("mixed" if official_used else "oracle"),
            "landmarks": "tracked+smoothed" if track and options.smooth else ("tracked" if track else "per-frame detection"),
            "frames_without_face": missing,
            "frames_dropped": 0 if track else missing,
        },
    }
    fmt.write_clip(out_root / source.identity / source.video, out_frames, np.stack(out_landmarks), np.stack(out_pose),
                   meta, segmentations=out_segs)
    return ClipOutcome(source, "done", frames=len(keep), missing=missing, dropped=0 if track else missing,
                       seconds=time.perf_counter() - started)


def _run_one(job: tuple[ClipSource, Path, PrepareOptions]) -> ClipOutcome:
    """Worker entry: never raises for a bad clip (the run goes on); the failure is returned."""
    source, out_root, options = job
    started = time.perf_counter()
    try:
        return prepare_clip(source, out_root, options)
    except Exception as exc:  # noqa: BLE001 - one bad clip must not abort a long run; it is reported
        return ClipOutcome(source, "failed", message=f"{type(exc).__name__}: {exc}", seconds=time.perf_counter() - started)


# -- the whole run ---------------------------------------------------------------------------------


def clip_is_finished(out_root: Path, source: ClipSource) -> bool:
    """write_clip moves a complete folder into place, so meta.json present = finished."""
    return (out_root / source.identity / source.video / fmt.META_NAME).is_file()


def _assign_splits(out_root: Path, identities: Sequence[str], test_fraction: float, test_identities: Sequence[str],
                   all_in: str | None) -> dict[str, list[str]]:
    """Identity -> split. Existing manifest assignments are kept (resumed runs stay stable); new
    identities go to ``all_in`` if given, else test if named or by a stable hash of the name."""
    previous: dict[str, str] = {}
    if (out_root / fmt.MANIFEST_NAME).is_file():
        for split, names in fmt.read_manifest(out_root)["splits"].items():
            previous.update({name: split for name in names})
    splits: dict[str, list[str]] = {"train": [], "test": []}
    for identity in sorted(identities):
        if identity in previous:
            split = previous[identity]
        elif all_in is not None:
            split = all_in
        elif identity in test_identities:
            split = "test"
        else:
            split = "test" if (zlib.crc32(identity.encode()) % 10_000) / 10_000 < test_fraction else "train"
        splits.setdefault(split, []).append(identity)
    return splits


def prepare_dataset(
    input_path: str | os.PathLike[str],
    out_root: str | os.PathLike[str],
    options: PrepareOptions = PrepareOptions(),
    workers: int = 1,
    test_fraction: float = 0.1,
    test_identities: Sequence[str] = (),
    split_all: str | None = None,
    progress: bool = True,
) -> PrepareSummary:
    """Prepare every clip under ``input_path`` into ``out_root`` and (re)write its manifest.

    split_all: put every identity into this split ("train"/"test"); default: LSR release inputs go to
    "test" (they are evaluation identities), others by ``test_identities`` / ``test_fraction``.
    Raises DatasetError when nothing is found or every clip fails.
    """
    from tqdm import tqdm

    out_root = Path(out_root)
    sources = discover_sources(input_path)
    if not sources:
        raise DatasetError(f"no videos or images found under {input_path}")
    if split_all is None and all(s.kind == "lsr_release" for s in sources):
        split_all = "test"
    started = time.perf_counter()
    outcomes = [ClipOutcome(s, "skipped") for s in sources if clip_is_finished(out_root, s)]
    todo = [(s, out_root, options) for s in sources if not clip_is_finished(out_root, s)]
    out_root.mkdir(parents=True, exist_ok=True)
    bar = tqdm(total=len(todo), desc="prepare", unit="clip", disable=not progress)
    results: Iterator[ClipOutcome]
    if workers <= 1 or len(todo) <= 1:
        results = map(_run_one, todo)
        pool = None
    else:
        # spawn: dlib/OpenCV state must not be shared through fork; each worker loads its own models.
        pool = multiprocessing.get_context("spawn").Pool(min(workers, len(todo)))
        results = pool.imap_unordered(_run_one, todo)
    try:
        for outcome in results:
            outcomes.append(outcome)
            if outcome.status == "failed":
                log.warning("clip %s/%s failed, skipped: %s", outcome.source.identity, outcome.source.video, outcome.message)
            elif outcome.missing:
                log.info("clip %s/%s: %d frame(s) without a face", outcome.source.identity, outcome.source.video, outcome.missing)
            bar.update(1)
    finally:
        bar.close()
        if pool is not None:
            pool.close()
            pool.join()
    summary = PrepareSummary(outcomes, time.perf_counter() - started)
    if summary.count("done") == 0 and summary.count("skipped") == 0:
        first = next(o for o in outcomes if o.status == "failed")
        raise DatasetError(f"all {len(outcomes)} clip(s) failed, nothing written (first: {first.source.path}: {first.message}); "
                           "check that the inputs are readable videos/images showing a face")
    identities = sorted({p.parent.parent.name for p in out_root.glob(f"*/*/{fmt.META_NAME}")})
    splits = _assign_splits(out_root, identities, test_fraction, test_identities, split_all)
    fmt.write_manifest(out_root, splits, extra={"prepared_from": str(input_path), "options": dataclasses.asdict(options)})
    _write_summary(out_root, summary)
    return summary


def _write_summary(out_root: Path, summary: PrepareSummary) -> None:
    record: dict[str, Any] = {
        "seconds": summary.seconds,
        "clips": {s: summary.count(s) for s in ("done", "skipped", "failed")},
        "frames": summary.frames,
        "frames_without_face": sum(o.missing for o in summary.outcomes),
        "frames_dropped": sum(o.dropped for o in summary.outcomes),
        "failed": [{"clip": f"{o.source.identity}/{o.source.video}", "path": str(o.source.path), "error": o.message}
                   for o in summary.outcomes if o.status == "failed"],
    }
    path = out_root / "prepare_summary.json"
    temp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    temp.write_text(json.dumps(record, indent=1) + "\n")
    os.replace(temp, path)
