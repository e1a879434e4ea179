"""Reading images of any common kind as RGB uint8, and atomic output files.

``read_image`` accepts grey, RGB, RGBA (composited on white), 16-bit (scaled to
8-bit) and EXIF-rotated files (OpenCV applies the EXIF orientation on colour
decode). Every failure is an ``InputFileError`` that names the file.

All outputs of the toolkit are written through ``atomic_output``: a temp file in
the destination folder that replaces the target only when writing succeeded, so
an interrupted run never leaves a half-written file under the final name.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from landmarks.exceptions import InputFileError, OutputPathError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm")


def to_rgb_uint8(array: np.ndarray) -> np.ndarray:
    """Any image array -> (H, W, 3) uint8 RGB.

    array: (H, W), (H, W, 1), (H, W, 3) RGB or (H, W, 4) RGBA; uint8, uint16 (scaled
    by 255/65535), bool, or float in [0, 1] (clipped). Alpha is composited on white.
    """
    array = np.asarray(array)
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    if array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[2] not in (3, 4)) or min(array.shape[:2]) < 1:
        raise InputFileError(f"expected an image array (H, W), (H, W, 3) or (H, W, 4), got shape {array.shape}")
    if array.dtype == np.uint8:
        unit = array.astype(np.float32) / 255.0 if array.ndim == 3 and array.shape[2] == 4 else None
    elif array.dtype == np.uint16:
        unit = array.astype(np.float32) / 65535.0
    elif array.dtype == bool:
        unit = array.astype(np.float32)
    elif np.issubdtype(array.dtype, np.floating):
        unit = np.clip(np.nan_to_num(array.astype(np.float32)), 0.0, 1.0)
    elif np.issubdtype(array.dtype, np.integer):
        unit = np.clip(array.astype(np.float32) / 255.0, 0.0, 1.0)
    else:
        raise InputFileError(f"unsupported image dtype {array.dtype}")
    if unit is None:  # uint8 grey or RGB: no arithmetic needed
        rgb = array if array.ndim == 3 else np.repeat(array[:, :, None], 3, axis=2)
        return np.ascontiguousarray(rgb)
    if unit.ndim == 2:
        unit = np.repeat(unit[:, :, None], 3, axis=2)
    elif unit.shape[2] == 4:  # alpha-composite on white: transparent background reads as paper, not black
        alpha = unit[:, :, 3:4]
        unit = unit[:, :, :3] * alpha + (1.0 - alpha)
    return np.ascontiguousarray(np.round(unit * 255.0).astype(np.uint8))


def _check_input_file(path: Path) -> None:
    if not path.exists():
        raise InputFileError(f"input file not found: {path}")
    if not path.is_file():
        raise InputFileError(f"input is not a file: {path}")
    if path.stat().st_size == 0:
        raise InputFileError(f"input file is empty (0 bytes): {path}")


def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an image file -> (H, W, 3) uint8 RGB, upright per its EXIF orientation."""
    path = Path(path)
    _check_input_file(path)
    try:
        buffer = np.fromfile(str(path), dtype=np.uint8)  # np.fromfile + imdecode: works for non-ASCII paths
    except OSError as exc:
        raise InputFileError(f"cannot read {path}: {exc}") from exc
    unchanged = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED)
    if unchanged is None or unchanged.size == 0:
        raise InputFileError(f"cannot decode {path} as an image (corrupt or unsupported format); use a PNG or JPEG")
    if unchanged.ndim == 3 and unchanged.shape[2] == 4:
        # Only IMREAD_UNCHANGED keeps alpha (and it ignores EXIF orientation, rare in files with alpha).
        return to_rgb_uint8(cv2.cvtColor(unchanged, cv2.COLOR_BGRA2RGBA))
    # IMREAD_COLOR applies the EXIF orientation; ANYDEPTH keeps 16-bit so we scale it ourselves.
    oriented = cv2.imdecode(buffer, cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
    if oriented is None:
        raise InputFileError(f"cannot decode {path} as a colour image; use a PNG or JPEG")
    return to_rgb_uint8(cv2.cvtColor(oriented, cv2.COLOR_BGR2RGB))


def check_output_path(path: str | os.PathLike[str], label: str = "--out", *, folder: bool = False) -> None:
    """Raise ``OutputPathError`` unless an output file (``folder``: an output folder) can be created at ``path``.

    Runs before the work, so a typo costs no waiting. Writers create missing folders, so the test is a real temp
    file in the nearest existing folder (permission bits alone do not tell: root, /proc, read-only mounts);
    nothing is left behind. ``label`` names the option in the one-line message.
    """
    path = Path(path)
    if folder and path.exists() and not path.is_dir():
        raise OutputPathError(f"{label} {path} is a file, not a folder; give a folder path")
    if not folder and path.is_dir():
        raise OutputPathError(f"{label} {path} is a folder; give a file path")
    existing = path if folder else path.parent
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise OutputPathError(
            f"{label} {path} cannot be written: {existing} is a file, not a folder; choose another folder or move that file"
        )
    try:
        handle, probe = tempfile.mkstemp(dir=existing, prefix=".lsr-write-check.")
    except OSError as exc:
        raise OutputPathError(
            f"{label} {path} cannot be written: cannot create files in {existing} ({exc.strerror}); "
            "choose a writable folder or fix its permissions"
        ) from None
    os.close(handle)
    os.unlink(probe)


def make_readable(path: Path) -> None:
    """Give a temp file or folder (mkstemp makes 0600, mkdtemp 0700) the mode a plain open()/mkdir() would."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, (0o777 if Path(path).is_dir() else 0o666) & ~umask)


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temp folder beside ``path``; on success it replaces ``path`` (an old one moved aside first, then
    removed), on error it is deleted: a reader sees the old folder or the new one, never half of one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temp = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp"))
    try:
        yield temp
        make_readable(temp)
        old = path.with_name(f".{path.name}.old")
        shutil.rmtree(old, ignore_errors=True)
        if path.exists():
            os.replace(path, old)
        os.replace(temp, path)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(temp, ignore_errors=True)


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temp path beside ``path``; on success it replaces ``path``, on error it is deleted.

    The temp name keeps the suffix so that writers which infer the format from it work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}")
    os.close(handle)
    temp = Path(temp_name)
    try:
        yield temp
        make_readable(temp)
        os.replace(temp, path)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise


def write_image(path: str | os.PathLike[str], rgb: np.ndarray) -> None:
    """Atomically write an (H, W, 3) uint8 RGB (or grey) image; the format follows the suffix."""
    rgb = to_rgb_uint8(rgb)
    with atomic_output(path) as temp:
        if not cv2.imwrite(str(temp), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
            raise InputFileError(f"cannot write image {path}; use a .png or .jpg name in a writable folder")


def write_npy(path: str | os.PathLike[str], array: np.ndarray) -> None:
    """Atomically write a .npy file."""
    with atomic_output(path) as temp, open(temp, "wb") as handle:
        np.save(handle, array)


def write_json(path: str | os.PathLike[str], data: Any) -> None:
    """Atomically write pretty-printed JSON."""
    with atomic_output(path) as temp:
        temp.write_text(json.dumps(data, indent=2) + "\n")
