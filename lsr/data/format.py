"""The one on-disk format of every LSR dataset (synthetic or prepared from real video).

Layout (``root/<identity>/<video>/`` is one *clip*)::

    root/
      manifest.json                 {"format_version", "splits": {"train": [...], "test": [...]},
                                     "counts": {split: {"identities", "clips", "frames"}}, "extra"}
      <identity>/<video>/
        frames/00000.png ...        RGB PNG, (S, S, 3) uint8 at crop resolution
        landmarks.npy               (N, 68, 2) float32, x, y in crop pixels (pixel centres at
                                    integers, iBUG-68 order); NaN rows = frames without landmarks
        pose.npy                    (N, 3) float32 yaw, pitch, roll in degrees (conventions of
                                    ``landmarks.motion.head_pose``: yaw > 0 nose towards image right, pitch > 0
                                    nose up, roll > 0 clockwise on screen); NaN rows = missing
        segmentation/00000.png ...  optional; (S, S) uint8 class maps in the 19-class CelebAMask-HQ
                                    order of ``lsr.data.classes.SEG_CLASSES`` (ids < 19)
        meta.json                   see below

``meta.json`` keys (written by ``write_clip``; extra keys are kept):
    format_version  int, must equal ``FORMAT_VERSION``
    origin          "synthetic" | "video" | "images"
    identity, video str names (= the folder names)
    fps             float frames per second of the source
    size            int S (frames are S x S)
    num_frames      int N
    crop_transforms list of N entries, each a 2x3 affine (source pixels -> crop pixels) or null
                    (synthetic frames have no source; null)
    missing_frames  sorted list of frame indices whose landmarks/pose are NaN
    has_segmentation bool
    generator       dict of generator/preparation parameters (free form, JSON)

Every reader validates and raises ``lsr.errors.DatasetError`` with a message that names the
file and says what to do. Writers are atomic: a clip is built in ``<clip>.tmp-<random suffix>`` beside the
final folder and moved into place with ``os.replace``; the manifest goes through a temp file.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from landmarks.io.image_files import atomic_output, make_readable
from landmarks.shape.ibug68 import NUM_LANDMARKS
from lsr.data.classes import NUM_SEG_CLASSES
from lsr.errors import DatasetError

FORMAT_VERSION = 1
MANIFEST_NAME = "manifest.json"
META_NAME = "meta.json"
FRAMES_DIR = "frames"
SEGMENTATION_DIR = "segmentation"
LANDMARKS_NAME = "landmarks.npy"
POSE_NAME = "pose.npy"
ORIGINS = ("synthetic", "video", "images")


def frame_name(index: int) -> str:
    """File name of frame ``index`` in ``frames/`` and ``segmentation/``: 00000.png."""
    return f"{index:05d}.png"


def _write_png(path: Path, image: np.ndarray) -> None:
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    if not cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
        raise DatasetError(f"could not write {path}: check free disk space and permissions")


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _write_json_atomic(path: Path, data: Any) -> None:
    with atomic_output(path) as temp, open(temp, "w") as handle:
        json.dump(data, handle, indent=1, default=_json_default)


def _check_frame(index: int, frame: np.ndarray, size: int | None) -> int:
    if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3 or frame.shape[0] != frame.shape[1]:
        raise DatasetError(f"frame {index}: expected (S, S, 3) uint8 RGB, got {frame.shape} {frame.dtype}")
    if size is not None and frame.shape[0] != size:
        raise DatasetError(f"frame {index}: size {frame.shape[0]} differs from frame 0 ({size}); resize all frames alike")
    return frame.shape[0]


def write_clip(
    clip_dir: str | os.PathLike[str],
    frames: Iterable[np.ndarray],
    landmarks: np.ndarray,
    pose: np.ndarray,
    meta: dict[str, Any],
    segmentations: Iterable[np.ndarray] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write one clip atomically; returns the final clip folder.

    frames: N x (S, S, 3) uint8 RGB; landmarks: (N, 68, 2) float; pose: (N, 3) float (degrees);
    segmentations: None or N x (S, S) uint8 class ids < 19. meta: at least ``origin`` and
    ``fps``; ``identity``/``video`` default to the folder names; ``generator`` and
    ``crop_transforms`` are optional. Missing frames are derived from NaN landmark rows.
    """
    clip_dir = Path(clip_dir)
    if clip_dir.exists() and not overwrite:
        raise DatasetError(f"{clip_dir} already exists: delete it or pass overwrite=True")
    landmarks = np.asarray(landmarks, dtype=np.float32)
    pose = np.asarray(pose, dtype=np.float32)
    if landmarks.ndim != 3 or landmarks.shape[1:] != (NUM_LANDMARKS, 2):
        raise DatasetError(f"landmarks must be (N, 68, 2), got {landmarks.shape}")
    if pose.shape != (landmarks.shape[0], 3):
        raise DatasetError(f"pose must be (N, 3) with N = {landmarks.shape[0]} (landmark rows), got {pose.shape}")
    if meta.get("origin") not in ORIGINS:
        raise DatasetError(f"meta['origin'] must be one of {ORIGINS}, got {meta.get('origin')!r}")
    clip_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=clip_dir.name + ".tmp-", dir=clip_dir.parent))
    try:
        (tmp / FRAMES_DIR).mkdir()
        size = None
        count = 0
        for count, frame in enumerate(frames, start=1):
            size = _check_frame(count - 1, np.asarray(frame), size)
            _write_png(tmp / FRAMES_DIR / frame_name(count - 1), np.ascontiguousarray(frame))
        num_frames = count
        if num_frames == 0:
            raise DatasetError(f"{clip_dir}: a clip needs at least one frame")
        if landmarks.shape[0] != num_frames:
            raise DatasetError(f"{clip_dir}: {num_frames} frames but {landmarks.shape[0]} landmark rows")
        has_segmentation = segmentations is not None
        if segmentations is not None:
            (tmp / SEGMENTATION_DIR).mkdir()
            seg_count = 0
            for seg_count, seg in enumerate(segmentations, start=1):
                seg = np.asarray(seg)
                if seg.dtype != np.uint8 or seg.shape != (size, size):
                    raise DatasetError(f"segmentation {seg_count - 1}: expected ({size}, {size}) uint8, got {seg.shape} {seg.dtype}")
                if seg.max(initial=0) >= NUM_SEG_CLASSES:
                    raise DatasetError(f"segmentation {seg_count - 1}: class id {seg.max()} >= {NUM_SEG_CLASSES}")
                _write_png(tmp / SEGMENTATION_DIR / frame_name(seg_count - 1), seg)
            if seg_count != num_frames:
                raise DatasetError(f"{clip_dir}: {num_frames} frames but {seg_count} segmentation maps")
        np.save(tmp / LANDMARKS_NAME, landmarks)
        np.save(tmp / POSE_NAME, pose)
        missing = np.flatnonzero(np.isnan(landmarks).any(axis=(1, 2))).tolist()
        full_meta = {
            "identity": clip_dir.parent.name,
            "video": clip_dir.name,
            "crop_transforms": [None] * num_frames,
            "generator": {},
            **meta,
            "format_version": FORMAT_VERSION,
            "size": int(size),
            "num_frames": num_frames,
            "missing_frames": missing,
            "has_segmentation": has_segmentation,
        }
        if len(full_meta["crop_transforms"]) != num_frames:
            raise DatasetError(f"{clip_dir}: meta crop_transforms needs {num_frames} entries (2x3 lists or None)")
        _write_json_atomic(tmp / META_NAME, full_meta)
        make_readable(tmp)  # mkdtemp makes 0700
        if clip_dir.exists():
            shutil.rmtree(clip_dir)
        os.replace(tmp, clip_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return clip_dir


class ClipReader:
    """Validated read access to one clip folder (see the module docstring for the layout).

    Opening checks meta.json, array shapes/dtypes and file counts; frames and maps are read
    lazily: ``frame(i)`` -> (S, S, 3) uint8 RGB, ``segmentation(i)`` -> (S, S) uint8.
    ``landmarks`` (N, 68, 2) float32 and ``pose`` (N, 3) float32 are loaded at open.
    """

    def __init__(self, clip_dir: str | os.PathLike[str]) -> None:
        self.clip_dir = Path(clip_dir)
        if not self.clip_dir.is_dir():
            raise DatasetError(f"clip folder {self.clip_dir} does not exist: check the dataset root and manifest")
        self.meta = self._read_meta()
        self.num_frames = int(self.meta["num_frames"])
        self.size = int(self.meta["size"])
        self.landmarks = self._read_array(LANDMARKS_NAME, (self.num_frames, NUM_LANDMARKS, 2))
        self.pose = self._read_array(POSE_NAME, (self.num_frames, 3))
        self._check_files(FRAMES_DIR)
        self.has_segmentation = bool(self.meta.get("has_segmentation")) and (self.clip_dir / SEGMENTATION_DIR).is_dir()
        if self.meta.get("has_segmentation") and not self.has_segmentation:
            raise DatasetError(f"{self.clip_dir}: meta.json says has_segmentation but segmentation/ is missing; re-generate the clip")
        if self.has_segmentation:
            self._check_files(SEGMENTATION_DIR)

    @property
    def identity(self) -> str:
        return str(self.meta["identity"])

    @property
    def video(self) -> str:
        return str(self.meta["video"])

    @property
    def missing_frames(self) -> list[int]:
        return list(self.meta["missing_frames"])

    def _read_meta(self) -> dict[str, Any]:
        path = self.clip_dir / META_NAME
        meta = _read_json(path, missing="the clip is incomplete, re-generate or re-prepare it", fix="re-generate the clip")
        version = meta.get("format_version")
        if version != FORMAT_VERSION:
            raise DatasetError(f"{path}: format_version {version!r}, this code reads version {FORMAT_VERSION}; re-generate the dataset")
        for key in ("num_frames", "size", "origin", "fps", "missing_frames"):
            if key not in meta:
                raise DatasetError(f"{path}: key {key!r} is missing; re-generate the clip")
        return meta

    def _read_array(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        path = self.clip_dir / name
        if not path.is_file():
            raise DatasetError(f"{path} is missing: the clip is incomplete, re-generate or re-prepare it")
        try:
            array = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise DatasetError(f"{path} cannot be read as a .npy array ({exc}); re-generate the clip") from exc
        if array.dtype != np.float32:
            raise DatasetError(f"{path}: dtype {array.dtype}, expected float32")
        if array.shape != shape:
            raise DatasetError(f"{path}: shape {array.shape}, expected {shape} (num_frames = {self.num_frames} from meta.json)")
        return array

    def _check_files(self, sub: str) -> None:
        folder = self.clip_dir / sub
        if not folder.is_dir():
            raise DatasetError(f"{folder} is missing: the clip is incomplete, re-generate or re-prepare it")
        count = sum(1 for p in folder.iterdir() if p.suffix == ".png")
        if count != self.num_frames:
            raise DatasetError(f"{folder}: {count} PNG files but meta.json says num_frames = {self.num_frames}")

    def _read_png(self, path: Path, flags: int) -> np.ndarray:
        image = cv2.imread(str(path), flags)
        if image is None:
            raise DatasetError(f"{path} is missing or not a readable PNG; re-generate the clip")
        return image

    def _index(self, index: int) -> int:
        if not -self.num_frames <= index < self.num_frames:
            raise IndexError(f"frame index {index} out of range for {self.num_frames} frames")
        return index % self.num_frames

    def frame(self, index: int) -> np.ndarray:
        """Frame ``index``: (S, S, 3) uint8 RGB."""
        path = self.clip_dir / FRAMES_DIR / frame_name(self._index(index))
        image = self._read_png(path, cv2.IMREAD_COLOR)
        if image.shape != (self.size, self.size, 3):
            raise DatasetError(f"{path}: shape {image.shape}, expected ({self.size}, {self.size}, 3) from meta.json")
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)

    def segmentation(self, index: int) -> np.ndarray:
        """Class map ``index``: (S, S) uint8, ids in [0, 19). Raises DatasetError if the clip has none."""
        if not self.has_segmentation:
            raise DatasetError(f"{self.clip_dir} has no segmentation maps (has_segmentation is false)")
        path = self.clip_dir / SEGMENTATION_DIR / frame_name(self._index(index))
        seg = self._read_png(path, cv2.IMREAD_UNCHANGED)
        if seg.dtype != np.uint8 or seg.shape != (self.size, self.size):
            raise DatasetError(f"{path}: expected ({self.size}, {self.size}) uint8, got {seg.shape} {seg.dtype}")
        if seg.max(initial=0) >= NUM_SEG_CLASSES:
            raise DatasetError(f"{path}: class id {int(seg.max())} >= {NUM_SEG_CLASSES}; ids follow lsr.data.classes.SEG_CLASSES")
        return seg

    def frames(self) -> Iterator[np.ndarray]:
        for index in range(self.num_frames):
            yield self.frame(index)

    def __len__(self) -> int:
        return self.num_frames


def read_clip(clip_dir: str | os.PathLike[str], with_segmentation: bool = True) -> dict[str, Any]:
    """Load a whole clip into memory: {"frames": (N, S, S, 3) uint8, "landmarks": (N, 68, 2),
    "pose": (N, 3), "segmentation": (N, S, S) uint8 or None, "meta": dict}."""
    reader = ClipReader(clip_dir)
    segmentation = None
    if with_segmentation and reader.has_segmentation:
        segmentation = np.stack([reader.segmentation(i) for i in range(reader.num_frames)])
    return {
        "frames": np.stack(list(reader.frames())),
        "landmarks": reader.landmarks,
        "pose": reader.pose,
        "segmentation": segmentation,
        "meta": reader.meta,
    }


def _clip_frames(clip_dir: Path) -> int:
    meta_path = clip_dir / META_NAME
    try:
        return int(json.loads(meta_path.read_text())["num_frames"])
    except (OSError, ValueError, KeyError) as exc:
        raise DatasetError(f"{meta_path} is missing or unreadable ({exc}); re-generate the clip") from exc


def identity_clips(root: str | os.PathLike[str], identity: str) -> list[Path]:
    """Clip folders of one identity, sorted by name (folders holding a meta.json)."""
    folder = Path(root) / identity
    if not folder.is_dir():
        raise DatasetError(f"identity folder {folder} does not exist; the manifest and the folders disagree")
    return sorted(p for p in folder.iterdir() if p.is_dir() and (p / META_NAME).is_file())


def write_manifest(root: str | os.PathLike[str], split: dict[str, list[str]], extra: dict[str, Any] | None = None) -> Path:
    """Write ``root/manifest.json`` atomically. split: split name -> identity folder names.

    An identity may appear in one split only. Counts of identities, clips and frames per split
    are computed from the folders (each must exist).
    """
    root = Path(root)
    seen: dict[str, str] = {}
    counts: dict[str, dict[str, int]] = {}
    for name, identities in split.items():
        clips = frames = 0
        for identity in identities:
            if identity in seen:
                raise DatasetError(f"identity {identity!r} is in splits {seen[identity]!r} and {name!r}; splits are by identity")
            seen[identity] = name
            for clip in identity_clips(root, identity):
                clips += 1
                frames += _clip_frames(clip)
        counts[name] = {"identities": len(identities), "clips": clips, "frames": frames}
    manifest = {
        "format_version": FORMAT_VERSION,
        "splits": {name: sorted(ids) for name, ids in split.items()},
        "counts": counts,
        "extra": extra or {},
    }
    path = root / MANIFEST_NAME
    _write_json_atomic(path, manifest)
    return path


def _read_json(path: Path, *, missing: str, fix: str) -> Any:
    """Parse a JSON file of the format, or raise a DatasetError that says what to do."""
    if not path.is_file():
        raise DatasetError(f"{path} is missing: {missing}")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path} is not valid JSON ({exc}); {fix}") from exc


def read_manifest(root: str | os.PathLike[str]) -> dict[str, Any]:
    """Read and validate ``root/manifest.json`` -> {"format_version", "splits", "counts", "extra"}."""
    path = Path(root) / MANIFEST_NAME
    missing = f"generate the dataset with `lsr synth --out {root}` or prepare it first"
    manifest = _read_json(path, missing=missing, fix="re-generate the manifest")
    if manifest.get("format_version") != FORMAT_VERSION:
        raise DatasetError(f"{path}: format_version {manifest.get('format_version')!r}, expected {FORMAT_VERSION}; re-generate the dataset")
    splits = manifest.get("splits")
    if not isinstance(splits, dict) or not all(isinstance(v, list) for v in splits.values()):
        raise DatasetError(f"{path}: 'splits' must map split names to lists of identities")
    return manifest


def list_clips(root: str | os.PathLike[str], split: str | None = None) -> list[Path]:
    """Clip folders of ``split`` (or of all splits when None), sorted, from the manifest."""
    manifest = read_manifest(root)
    splits = manifest["splits"]
    if split is not None and split not in splits:
        raise DatasetError(f"split {split!r} not in {Path(root) / MANIFEST_NAME} (has {sorted(splits)})")
    names = [split] if split is not None else sorted(splits)
    clips: list[Path] = []
    for name in names:
        for identity in splits[name]:
            clips.extend(identity_clips(root, identity))
    return sorted(clips)
