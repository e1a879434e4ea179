"""The app's example person and driver, made on first use from the bundled real example (``lsr.examples``: two
GRID corpus speakers, CC BY 4.0, attribution in ``lsr/examples/NOTICE.md``).

Person A's shots are frames spread over its clip; person B's clip is its first ``DRIVER_FRAMES`` frames with a
sine tone added (so that "the output keeps the audio" can be seen and tested) and its landmarks found by the
default detector. They are written once into a cache folder and reused. The folder appears complete or not at all
(built in a temp folder beside it, then renamed), so an interrupted first run leaves nothing half-made.

    examples = ensure_examples()            # ~/.cache/lsr/app_examples by default
    examples.source_images                  # 4 PNG shots of real person A
    examples.driver_video                  # H.264 clip of person B with a sine-tone audio track
    examples.driver_landmarks              # the same clip's (N, 68, 2) landmarks (.npy, frame pixels)
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from lsr.examples import EXAMPLE_SHOTS

EXAMPLES_VERSION = 3  # bump when the recipe changes: a new folder name, old caches are left alone
SOURCE_SHOTS = EXAMPLE_SHOTS
DRIVER_FRAMES = 32
EXAMPLE_FPS = 25
TONE_HZ = 440.0  # the driver clip carries audio so "the output keeps the audio" can be seen and tested

# Names shown in the driver-example dropdown.
DRIVER_EXAMPLE_NONE = "none (use my upload)"
DRIVER_EXAMPLE_VIDEO = f"real person B (GRID corpus, CC BY 4.0): video, {DRIVER_FRAMES} frames with audio"
DRIVER_EXAMPLE_LANDMARKS = f"real person B: landmarks only (.npy, {DRIVER_FRAMES} x 68 x 2)"
DRIVER_EXAMPLES = (DRIVER_EXAMPLE_NONE, DRIVER_EXAMPLE_VIDEO, DRIVER_EXAMPLE_LANDMARKS)


@dataclasses.dataclass(frozen=True)
class Examples:
    """Paths of the generated examples."""

    folder: Path
    source_images: list[Path]
    driver_video: Path
    driver_landmarks: Path

    def driver(self, name: str) -> Path | None:
        """The file behind a dropdown entry of ``DRIVER_EXAMPLES`` (None for 'none')."""
        return {DRIVER_EXAMPLE_VIDEO: self.driver_video, DRIVER_EXAMPLE_LANDMARKS: self.driver_landmarks}.get(name)


def default_examples_dir() -> Path:
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache) / "lsr" / "app_examples"


def _layout(folder: Path) -> Examples:
    return Examples(
        folder,
        [folder / f"source_person_a_{i}.png" for i in range(SOURCE_SHOTS)],
        folder / "driver_person_b.mp4",
        folder / "driver_person_b_landmarks.npy",
    )


def write_clip_with_tone(path: Path, frames: np.ndarray, fps: int = EXAMPLE_FPS, tone_hz: float = TONE_HZ) -> Path:
    """Frames (N, H, W, 3) uint8 RGB -> H.264 MP4 with a mono AAC sine tone as long as the video (PyAV)."""
    import av

    rate = 44100
    with av.open(str(path), mode="w") as container:
        video = container.add_stream("libx264", rate=fps)
        video.width, video.height, video.pix_fmt = frames.shape[2], frames.shape[1], "yuv420p"
        audio = container.add_stream("aac", rate=rate)
        for frame in frames:
            for packet in video.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")):
                container.mux(packet)
        for packet in video.encode(None):
            container.mux(packet)
        samples = int(rate * len(frames) / fps)
        wave = (0.2 * np.sin(2 * np.pi * tone_hz * np.arange(samples) / rate)).astype(np.float32)
        for start in range(0, samples, 1024):
            chunk = av.AudioFrame.from_ndarray(wave[None, start : start + 1024], format="fltp", layout="mono")
            chunk.sample_rate = rate
            for packet in audio.encode(chunk):
                container.mux(packet)
        for packet in audio.encode(None):
            container.mux(packet)
    return path


def _generate(folder: Path) -> None:
    from landmarks.detect.registry import make_detector
    from landmarks.io.image_files import write_image
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_DRIVER, REAL_SOURCE, example_shots

    layout = _layout(folder)
    # Person A: shots spread over its clip, so head pose and expression differ between the K shots.
    for path, shot in zip(layout.source_images, example_shots(SOURCE_SHOTS)):
        write_image(path, shot)
    driver = np.stack([frame for _, frame in zip(range(DRIVER_FRAMES), iter_frames(REAL_DRIVER))])
    write_clip_with_tone(layout.driver_video, driver)
    detector = make_detector()
    landmarks = np.full((len(driver), 68, 2), np.nan, np.float32)
    for index, frame in enumerate(driver):
        faces = detector.detect(frame)
        if faces:
            landmarks[index] = faces[0].landmarks
    np.save(layout.driver_landmarks, landmarks)
    manifest = {"version": EXAMPLES_VERSION, "source": REAL_SOURCE.name, "driver": REAL_DRIVER.name,
                "fps": EXAMPLE_FPS, "landmark_space": "frame", "licence": "CC BY 4.0 (lsr/examples/NOTICE.md)"}
    (folder / "examples.json").write_text(json.dumps(manifest, indent=2))


def ensure_examples(root: str | os.PathLike | None = None) -> Examples:
    """Generate the examples into ``root`` (default ``default_examples_dir()``) unless already there; return them."""
    root = Path(root) if root is not None else default_examples_dir()
    folder = root / f"v{EXAMPLES_VERSION}"
    if (folder / "examples.json").is_file():
        return _layout(folder)
    root.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=root, prefix=".staging-"))
    try:
        _generate(staging)
        try:
            os.replace(staging, folder)
        except OSError:  # another process finished first: keep its folder
            if not (folder / "examples.json").is_file():
                raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return _layout(folder)
