"""Typed configs. Each dataclass is one ``lsr`` sub-command; tyro turns it into a CLI.

Configs hold values only; the work lives in the modules that ``lsr.cli`` dispatches to.
Validation happens up front in ``validate()`` so a bad flag fails before any work starts.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import tyro

from lsr.errors import ConfigError


@dataclasses.dataclass
class LandmarksConfig:
    """Detect and track 68-point landmarks in an image, a folder of images or a video."""

    input: tyro.conf.Positional[Path]
    """Image file, folder of images, or video file."""
    out: Path = Path("out/landmarks")
    """Output folder: landmarks.npy (N x 68 x 2, NaN rows = missing), summary.json, overlay."""
    detector: Literal["hog", "cnn"] = "hog"
    """dlib face detector: HOG (fast, default) or CNN/mmod (slower, more robust to pose)."""
    face_index: int = 0
    """Which face to use when several are found, ordered largest first."""
    smooth: bool = True
    """One-Euro temporal smoothing of tracked landmarks (videos only)."""
    min_cutoff: float = 1.0
    """One-Euro minimum cutoff frequency in Hz: lower = smoother at rest, more lag."""
    beta: float = 0.05
    """One-Euro speed coefficient: higher = less lag on fast motion."""
    overlay: bool = True
    """Also write an overlay image (or an H.264 overlay video for video input)."""

    def validate(self) -> None:
        if self.face_index < 0:
            raise ConfigError(f"--face-index must be >= 0, got {self.face_index}")
        if self.min_cutoff <= 0:
            raise ConfigError(f"--min-cutoff must be > 0, got {self.min_cutoff}")
        if self.beta < 0:
            raise ConfigError(f"--beta must be >= 0, got {self.beta}")


@dataclasses.dataclass
class DemoConfig:
    """The README's main job on a fresh machine: make a bundled input and run the pipeline on it."""

    out: Path = Path("out")
    """Output folder."""

    def validate(self) -> None:
        pass


@dataclasses.dataclass
class BenchLandmarksConfig:
    """Print ms/frame of detection, tracking and rasterisation on a clip (a table, with machine info)."""

    video: Path | None = None
    """Video to time on; default: the shared real clip if present, else a synthetic one."""
    size: int = 512
    """Frames are resized to size x size before timing (the tracking goal is stated at 512)."""
    frames: int = 100
    """Number of frames to time."""
    raster_size: int = 256
    """Resolution of the rasterised landmark image."""

    def validate(self) -> None:
        if self.size < 64 or self.frames < 1 or self.raster_size < 16:
            raise ConfigError("--size >= 64, --frames >= 1 and --raster-size >= 16 are required")
