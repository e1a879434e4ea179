"""``lsr bench landmarks``: ms/frame of each landmarks stage on a real clip, as a markdown table.

Stages, each timed per frame on frames resized to size x size (median and 90th percentile):
  detect        full HOG detection + shape predictor on every frame
  track         ``LandmarkTracker``: shape predictor from the previous frame, detection on loss only
  predictor     the 68-point shape predictor alone, in the tracked box
  rasterise     ``landmarks.raster.draw_landmarks`` at raster_size
  smooth        One-Euro filter step
  pose          head pose (solvePnP)
Then the jitter of a static sequence (one frame repeated with fresh pixel noise each time, so
the true landmarks do not move) before and after One-Euro smoothing.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lsr.config import BenchLandmarksConfig
from lsr.errors import ConfigError

DEFAULT_CLIP = "clips/tpsmm_driving.mp4"


def shared_data_dir() -> Path:
    """Real data beside the project: $LSR_SHARED_DATA, default ../shared/data from the repo root."""
    repo_root = Path(__file__).resolve().parents[2]
    return Path(os.environ.get("LSR_SHARED_DATA", repo_root.parent / "shared" / "data"))


def default_video() -> Path:
    path = shared_data_dir() / DEFAULT_CLIP
    if not path.is_file():
        raise ConfigError(
            f"no video given and the shared clip {path} is absent; pass --video PATH (any talking-head video) "
            "or set LSR_SHARED_DATA"
        )
    return path


def static_jitter(
    frame: np.ndarray,
    *,
    repeats: int = 50,
    noise_sigma: float = 4.0,
    fps: float = 25.0,
    min_cutoff: float = 1.0,
    beta: float = 0.05,
    seed: int = 0,
) -> tuple[float, float, int]:
    """Jitter (inter-ocular units per frame) of a static face before and after One-Euro smoothing.

    frame: (H, W, 3) uint8 RGB with a face. It is repeated ``repeats`` times with fresh Gaussian
    pixel noise (sigma in grey levels), so any landmark motion is jitter. Returns
    (raw jitter, smoothed jitter, missing frames).
    """
    from landmarks.smooth import jitter, smooth_sequence
    from landmarks.track import LandmarkTracker

    rng = np.random.default_rng(seed)

    def noisy_frames():
        for _ in range(repeats):
            noise = rng.normal(0.0, noise_sigma, frame.shape)
            yield np.clip(frame.astype(np.float32) + noise, 0, 255).astype(np.uint8)

    tracked = LandmarkTracker().track_frames(noisy_frames())
    smoothed = smooth_sequence(tracked.landmarks, fps, min_cutoff=min_cutoff, beta=beta)
    return jitter(tracked.landmarks), jitter(smoothed), int(tracked.missing.sum())


def _time_per_frame(step: Callable[[int], object], count: int) -> np.ndarray:
    """Milliseconds of ``step(i)`` for i in range(count)."""
    times = np.empty(count)
    for index in range(count):
        start = time.perf_counter()
        step(index)
        times[index] = (time.perf_counter() - start) * 1000.0
    return times


def _load_frames(video: Path, count: int, size: int) -> tuple[list[np.ndarray], float]:
    import cv2

    from landmarks.video import iter_frames, probe_video

    fps = probe_video(video).fps
    frames = []
    for frame in iter_frames(video):
        frames.append(np.ascontiguousarray(cv2.resize(frame, (size, size), interpolation=cv2.INTER_AREA)))
        if len(frames) == count:
            break
    return frames, fps


def run_bench_landmarks(cfg: BenchLandmarksConfig) -> str:
    """Time the landmark stages and print (and return) the markdown tables."""
    from landmarks.detect import FaceDetector, predict_landmarks
    from landmarks.pose import estimate_head_pose
    from landmarks.smooth import OneEuroFilter
    from landmarks.track import LandmarkTracker
    from lsr.machine import machine_markdown

    video = cfg.video if cfg.video is not None else default_video()
    frames, fps = _load_frames(video, cfg.frames, cfg.size)
    count = len(frames)
    detector = FaceDetector("hog")
    detector.detect(frames[0])  # load the models outside the timings

    rows: list[tuple[str, np.ndarray, str]] = []
    detect_ms = _time_per_frame(lambda i: detector.detect(frames[i]), count)
    rows.append(("detect (HOG + predictor, every frame)", detect_ms, ""))

    tracker = LandmarkTracker(detector)
    tracked: list[np.ndarray | None] = [None] * count

    def track_step(index: int) -> None:
        tracked[index] = tracker.update(frames[index])

    track_ms = _time_per_frame(track_step, count)
    missing = sum(points is None for points in tracked)
    rows.append(("track (detect on loss only)", track_ms, f"{tracker.detections} detections, {missing} missing"))

    valid = [i for i, points in enumerate(tracked) if points is not None]
    boxes = {i: tracker.box_from_landmarks(tracked[i]) for i in valid}
    predictor_ms = _time_per_frame(lambda k: predict_landmarks(frames[valid[k]], boxes[valid[k]]), len(valid))
    rows.append(("shape predictor only", predictor_ms, ""))

    try:
        from landmarks.raster import draw_landmarks
    except ImportError:
        draw_landmarks = None
    if draw_landmarks is not None and valid:
        factor = cfg.raster_size / cfg.size
        raster_ms = _time_per_frame(
            lambda k: draw_landmarks(tracked[valid[k]] * factor, cfg.raster_size), len(valid)
        )
        rows.append((f"rasterise at {cfg.raster_size}x{cfg.raster_size}", raster_ms, ""))

    one_euro = OneEuroFilter(fps)
    smooth_ms = _time_per_frame(lambda k: one_euro(tracked[valid[k]]), len(valid))
    rows.append(("One-Euro smoothing", smooth_ms, ""))
    pose_ms = _time_per_frame(lambda k: estimate_head_pose(tracked[valid[k]], (cfg.size, cfg.size)), len(valid))
    rows.append(("head pose (solvePnP)", pose_ms, ""))

    lines = [
        machine_markdown(),
        "",
        f"Landmarks on {video.name}: {count} frames resized to {cfg.size}x{cfg.size}",
        "",
        "| stage | median ms/frame | p90 ms/frame | notes |",
        "|---|---:|---:|---|",
    ]
    for name, times, note in rows:
        lines.append(f"| {name} | {np.median(times):.2f} | {np.percentile(times, 90):.2f} | {note} |")

    raw, smoothed, static_missing = static_jitter(frames[valid[0]] if valid else frames[0], fps=fps)
    lines += [
        "",
        "Static-face jitter (first tracked frame repeated 50x with pixel noise sigma 4; "
        "mean frame-to-frame motion / inter-ocular distance)",
        "",
        "| landmarks | jitter |",
        "|---|---:|",
        f"| tracked (raw) | {raw:.4f} |",
        f"| One-Euro (min_cutoff 1.0, beta 0.05, {fps:g} fps) | {smoothed:.4f} |",
    ]
    if static_missing:
        lines.append(f"\n({static_missing} of the static frames had no face)")
    table = "\n".join(lines)
    print(table)
    return table
