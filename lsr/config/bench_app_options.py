"""Configs of the ``lsr bench`` sub-commands that run the app in a browser (``live``, ``web``, ``soak``; re-exported by
``lsr.config``, beside ``lsr.config.bench_options``'s).

Each benchmark is a command that prints a markdown table with machine info; never a timed test.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from lsr.config.shared import OptionalPath
from lsr.errors import ConfigError


@dataclasses.dataclass
class BenchLiveConfig:
    """The app's live tab in Chromium with a fake camera: frame rate and camera-to-screen latency (a table with
    machine info; needs /usr/bin/chromium and playwright)."""

    weights: OptionalPath = None
    """Model folder; default: the shipped default model."""
    camera_video: OptionalPath = None
    """A clip to play as the camera (its first frames, letterboxed to 640x480); default a synthetic talking person."""
    seconds: float = 30.0
    """Measured stream time, after the warm-up."""
    warmup: float = 5.0
    """Seconds of stream after the first result that are not measured."""
    port: int = 0
    """Port to serve the app on (127.0.0.1); 0 = a free one."""
    screenshot: OptionalPath = None
    """Also save a screenshot of the live tab here (PNG)."""
    out_md: OptionalPath = None
    """Also write the table as the 'live' section of this markdown file (e.g. BENCHMARKS.md)."""

    def validate(self) -> None:
        if self.seconds <= 0 or self.warmup < 0 or not 0 <= self.port < 65536:
            raise ConfigError("--seconds must be > 0, --warmup >= 0 and --port in 0..65535")
        if self.camera_video is not None and not Path(self.camera_video).is_file():
            raise ConfigError(f"--camera-video {self.camera_video} is not a file")


@dataclasses.dataclass
class BenchWebConfig:
    """The static web site (`lsr export --web`) in Chromium with a fake camera against the app's live tab, same run:
    frame rate, camera-to-screen latency and their ratios (a table with machine info; needs /usr/bin/chromium,
    playwright, Node.js and npm)."""

    weights: OptionalPath = None
    """Model folder; default: the shipped default model."""
    camera_video: OptionalPath = None
    """A clip to play as the camera (its first frames, letterboxed to 640x480); default a synthetic talking person."""
    camera_fps: int = 25
    """The camera's frame rate (webcams send 25-30): the most frames a second either can show."""
    seconds: float = 30.0
    """Measured stream time of each, after the warm-up."""
    warmup: float = 5.0
    """Seconds of stream after the first result that are not measured."""
    screenshot: OptionalPath = None
    """Also save a screenshot of the web page here (PNG)."""
    out_md: OptionalPath = None
    """Also write the table as the 'web' section of this markdown file (e.g. BENCHMARKS.md)."""

    def validate(self) -> None:
        if self.seconds <= 0 or self.warmup < 0 or not 1 <= self.camera_fps <= 120:
            raise ConfigError("--seconds must be > 0, --warmup >= 0 and --camera-fps in 1..120")
        if self.camera_video is not None and not Path(self.camera_video).is_file():
            raise ConfigError(f"--camera-video {self.camera_video} is not a file")


@dataclasses.dataclass
class BenchSoakConfig:
    """The app under a long live stream and batch re-enactments at once, on 127.0.0.1: does its resident memory
    hold after the warm-up (a table with machine info; needs /usr/bin/chromium and playwright)?"""

    weights: OptionalPath = None
    """Model folder; default: the shipped default model."""
    minutes: float = 10.0
    """How long the live stream runs (the batch runs go on beside it until they are done or time is up)."""
    batch_runs: int = 50
    """Re-enactments sent through the /reenact API during the stream."""
    warmup_minutes: float = 2.0
    """Minutes not held to the +-10 % bound (the model, the ONNX export, the first runs' caches load)."""
    out_md: OptionalPath = None
    """Also write the table as the 'soak' section of this markdown file (e.g. BENCHMARKS.md)."""

    def validate(self) -> None:
        if self.minutes <= 0 or self.batch_runs < 0 or not 0 <= self.warmup_minutes < self.minutes:
            raise ConfigError("--minutes must be > 0, --batch-runs >= 0 and --warmup-minutes in [0, --minutes)")
