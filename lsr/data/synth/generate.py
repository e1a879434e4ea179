"""Render synthetic talking-head videos and write them as a dataset (``lsr.data.format``).

Seeds. ``identity_seed`` fixes a person (``SeedSequence(identity_seed, spawn_key=(0,))``); video
``v`` of that person draws its scene and motion from ``spawn_key=(1, v)``. A dataset of seed
``s`` gives identity ``i`` the seed ``SeedSequence(s, spawn_key=(i,))``, so adding identities
or videos never changes existing ones, and the same seed gives byte-identical arrays.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from lsr.data.synth import effects
from lsr.data.synth.geometry import HeadPose, head_landmarks, head_parts, make_camera
from lsr.data.synth.persons import Identity, sample_identity, sample_scene
from lsr.data.synth.motion import Motion, sample_motion
from lsr.data.synth.distributions import Preset, get_preset
from lsr.data.synth.render import background_image, render_head
from lsr.errors import ConfigError

DEFAULT_FPS = 25.0
Framing = Literal["aligned", "camera"]
FRAMINGS: tuple[str, ...] = ("aligned", "camera")
ALIGN_OVERSAMPLE = 2  # 'aligned' renders at 2x and crops down (the crop zooms in ~1.3x on the camera framing)
VISIBILITY_TOLERANCE = 0.03  # head units a landmark may lie behind the z-buffer and still count as visible


@dataclasses.dataclass
class SynthClip:
    """One rendered video with exact ground truth.

    frames: (N, S, S, 3) uint8 RGB; landmarks: (N, 68, 2) float32 pixel x, y (iBUG-68);
    segmentation: (N, S, S) uint8 (19 classes, unoccluded truth); pose: (N, 3) float32 yaw,
    pitch, roll degrees; visible: (N, 68) bool (landmark not hidden by the head itself);
    occluded: (N,) bool (a transient occluder is drawn); motion: per-frame state; params: JSON-able
    generator parameters (identity, scene, preset, seeds, occluders).
    """

    frames: np.ndarray
    landmarks: np.ndarray
    segmentation: np.ndarray
    pose: np.ndarray
    visible: np.ndarray
    occluded: np.ndarray
    motion: Motion
    params: dict[str, Any]


def identity_from_seed(identity_seed: int) -> Identity:
    return sample_identity(np.random.default_rng(np.random.SeedSequence(identity_seed, spawn_key=(0,))))


def render_video(
    identity_seed: int,
    num_frames: int,
    size: int = 128,
    preset: str | Preset = "default",
    video_index: int = 0,
    fps: float = DEFAULT_FPS,
) -> SynthClip:
    """Render video ``video_index`` of the person ``identity_seed`` (see ``SynthClip``)."""
    if num_frames < 1 or size < 32:
        raise ConfigError(f"num_frames must be >= 1 and size >= 32, got {num_frames} and {size}")
    preset = get_preset(preset) if isinstance(preset, str) else preset
    identity = identity_from_seed(identity_seed)
    rng = np.random.default_rng(np.random.SeedSequence(identity_seed, spawn_key=(1, video_index)))
    scene = sample_scene(rng)
    face_scale = float(rng.uniform(*preset.face_scale) * (1.0 + scene.scale_jitter))
    gain = float(rng.uniform(*preset.exposure))
    blur_angle = float(rng.uniform(0, np.pi))
    motion = sample_motion(rng, num_frames, fps, preset)
    plan = effects.plan_occluders(rng, num_frames, fps, preset.occluder_fraction, preset.occluder_size)
    noise_rng = np.random.default_rng(rng.integers(2**63))

    camera = make_camera(size, face_scale, scene.offset_x, scene.offset_y)
    background = background_image(scene, size)
    frames = np.empty((num_frames, size, size, 3), np.uint8)
    segmentation = np.empty((num_frames, size, size), np.uint8)
    landmarks = np.empty((num_frames, 68, 2), np.float32)
    visible = np.empty((num_frames, 68), bool)
    run_start: dict[int, int] = {}
    yaw_speed = np.gradient(motion.yaw) if num_frames > 1 else np.zeros(1)  # degrees per frame
    for index in range(num_frames):
        state = motion.frame(index)
        pose = HeadPose.from_angles(state["yaw"], state["pitch"], state["roll"], state["shift_x"], state["shift_y"])
        parts = head_parts(identity, float(state["mouth_open"]))
        local, layout = head_landmarks(identity, parts, state, pose)
        points = pose.apply(local)
        pixels = camera.to_pixels(points)
        image, classes, depth = render_head(
            identity, parts, layout, pose, camera, background, state["light_dir"], float(state["light"]), float(state["ambient"])
        )
        landmarks[index] = pixels
        visible[index] = _visible(pixels, points[:, 2], depth)
        occluder = plan[index]
        if occluder is not None:
            start = run_start.setdefault(id(occluder), index)
            effects.draw_occluder(image, occluder, index - start)
        image = effects.expose(image, gain, preset.gamma)
        if preset.motion_blur_px > 0:
            speed = 0.5 + abs(float(yaw_speed[index])) / 2.0  # faster turns blur more
            image = effects.motion_blur(image, preset.motion_blur_px * size / 128 * min(speed, 2.0), blur_angle)
        frames[index] = effects.to_uint8(image, noise_rng, preset.noise_sd)
        segmentation[index] = classes
    occluders = [None if o is None else dataclasses.asdict(o) for o in plan]
    params = {
        "generator": "lsr.data.synth",
        "identity_seed": int(identity_seed),
        "video_index": int(video_index),
        "preset": preset.name,
        "size": size,
        "fps": fps,
        "face_scale": face_scale,
        "exposure_gain": gain,
        "identity": identity.to_dict(),
        "scene": scene.to_dict(),
        "occluders": occluders,
        "segmentation_under_occluders": "unoccluded truth",
    }
    return SynthClip(frames, landmarks, segmentation, motion.pose(), visible, np.array([o is not None for o in plan]), motion, params)


def align_clip(clip: SynthClip, size: int) -> SynthClip:
    """Crop every frame the way inference crops faces (``landmarks.align.crop_transform`` on the exact landmarks).

    Real data (``lsr prepare``) and every driver at inference are framed by that crop, so training on aligned
    synthetic frames removes a framing gap between the synthetic training set and what the model sees later.
    Frames are warped with cubic interpolation (edges replicated), classes with nearest, landmarks exactly.
    """
    from landmarks.align import crop_transform, transform_landmarks, warp_to_crop

    count = len(clip.frames)
    frames = np.empty((count, size, size, 3), np.uint8)
    segmentation = np.empty((count, size, size), np.uint8)
    landmarks = np.empty((count, 68, 2), np.float32)
    for index in range(count):
        matrix = crop_transform(clip.landmarks[index], size)
        frames[index] = warp_to_crop(clip.frames[index], matrix, size)
        segmentation[index] = cv2.warpAffine(clip.segmentation[index], matrix, (size, size), flags=cv2.INTER_NEAREST,
                                             borderMode=cv2.BORDER_REPLICATE)
        landmarks[index] = transform_landmarks(clip.landmarks[index], matrix)
    params = {**clip.params, "framing": "aligned", "size": size, "render_size": int(clip.frames.shape[1])}
    return dataclasses.replace(clip, frames=frames, landmarks=landmarks, segmentation=segmentation, params=params)


def render_framed(identity_seed: int, num_frames: int, size: int = 128, preset: str | Preset = "default",
                  video_index: int = 0, fps: float = DEFAULT_FPS, framing: Framing = "aligned") -> SynthClip:
    """``render_video`` with a framing: 'camera' (the scene's camera, the head moves in the frame) or 'aligned'
    (rendered at ``ALIGN_OVERSAMPLE`` x size, then cropped per frame like inference; see ``align_clip``)."""
    if framing not in FRAMINGS:
        raise ConfigError(f"framing must be one of {', '.join(FRAMINGS)}, got {framing!r}")
    if framing == "camera":
        return render_video(identity_seed, num_frames, size, preset, video_index=video_index, fps=fps)
    clip = render_video(identity_seed, num_frames, size * ALIGN_OVERSAMPLE, preset, video_index=video_index, fps=fps)
    return align_clip(clip, size)


def _visible(pixels: np.ndarray, point_depth: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(68,) bool: the landmark is not behind the rendered surface at its pixel."""
    size = depth.shape[0]
    ix = np.clip(np.round(pixels[:, 0]).astype(int), 0, size - 1)
    iy = np.clip(np.round(pixels[:, 1]).astype(int), 0, size - 1)
    inside = (pixels >= -0.5).all(axis=1) & (pixels <= size - 0.5).all(axis=1)
    return inside & (point_depth <= depth[iy, ix] + VISIBILITY_TOLERANCE)


def identity_seed_of(seed: int, identity_index: int) -> int:
    """Seed of identity ``identity_index`` in a dataset generated with ``seed``."""
    return int(np.random.SeedSequence(seed, spawn_key=(identity_index,)).generate_state(1)[0])


def split_identities(names: list[str], seed: int, test_fraction: float) -> dict[str, list[str]]:
    """Split by identity: round(test_fraction * n) test identities (>= 1 when the fraction > 0 and n >= 2)."""
    keys = [np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(i, 7))).random() for i in range(len(names))]
    n_test = int(round(test_fraction * len(names)))
    if test_fraction > 0 and len(names) >= 2:
        n_test = max(1, min(n_test, len(names) - 1))
    order = np.argsort(keys, kind="stable")
    test = {names[i] for i in order[:n_test]}
    return {"train": [n for n in names if n not in test], "test": [n for n in names if n in test]}


def _render_and_write(job: tuple) -> int:
    """Worker: render one clip and write it (top-level so process pools can pickle it)."""
    from lsr.data.format import write_clip

    root, name, identity_index, identity_seed, video_index, frames, size, preset, fps, seed, overwrite, framing = job
    clip = render_framed(identity_seed, frames, size, preset, video_index=video_index, fps=fps, framing=framing)
    meta = {"origin": "synthetic", "fps": fps, "generator": {**clip.params, "dataset_seed": seed, "identity_index": identity_index}}
    write_clip(Path(root) / name / f"vid{video_index:03d}", clip.frames, clip.landmarks, clip.pose, meta, clip.segmentation, overwrite=overwrite)
    return frames


def generate_dataset(
    root: str | Path,
    identities: int,
    videos_per_identity: int,
    frames: int,
    size: int = 128,
    seed: int = 0,
    preset: str = "default",
    test_fraction: float = 0.2,
    fps: float = DEFAULT_FPS,
    progress: bool = True,
    overwrite: bool = False,
    workers: int = 1,
    framing: Framing = "aligned",
) -> Path:
    """Write ``identities`` x ``videos_per_identity`` clips of ``frames`` frames and the manifest.

    Returns the manifest path. Layout and files: ``lsr.data.format``. ``workers`` > 1 renders
    clips in a process pool; the output is the same for any number of workers. ``framing``: see
    ``render_framed`` ('aligned', the default, frames faces like inference and ``lsr prepare`` do).
    """
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing

    from tqdm import tqdm

    from lsr.data.format import write_manifest

    if identities < 1 or videos_per_identity < 1 or frames < 1:
        raise ConfigError("identities, videos_per_identity and frames must all be >= 1")
    if not 0.0 <= test_fraction < 1.0:
        raise ConfigError(f"test_fraction must be in [0, 1), got {test_fraction}")
    get_preset(preset)
    if framing not in FRAMINGS:
        raise ConfigError(f"framing must be one of {', '.join(FRAMINGS)}, got {framing!r}")
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    names = [f"id{i:05d}" for i in range(identities)]
    jobs = [
        (str(root), name, i, identity_seed_of(seed, i), v, frames, size, preset, fps, seed, overwrite, framing)
        for i, name in enumerate(names)
        for v in range(videos_per_identity)
    ]
    with tqdm(total=len(jobs) * frames, unit="frame", desc="lsr synth", disable=not progress) as bar:
        if workers <= 1 or len(jobs) == 1:
            for job in jobs:
                bar.update(_render_and_write(job))
        else:
            # spawn: safe even when the caller has torch (and its threads) loaded.
            with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
                for done in pool.map(_render_and_write, jobs):
                    bar.update(done)
    split = split_identities(names, seed, test_fraction)
    extra = {"generator": "lsr.data.synth", "seed": seed, "preset": preset, "size": size, "fps": fps, "framing": framing}
    return write_manifest(root, split, extra)


def benchmark(size: int = 128, frames: int = 200, repeats: int = 3, preset: str = "default", workers: int = 1) -> dict[str, float]:
    """Time ``render_video`` (median of ``repeats``). With workers > 1, ``workers`` clips render in parallel.

    Returns size, workers, frames/s of wall time ("fps") and, for one worker, of process CPU time ("cpu_fps":
    what an idle core would give when the machine is shared).
    """
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing

    render_video(1, 4, size, preset)  # warm-up (imports, caches)
    walls, cpus = [], []
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) if workers > 1 else None
    try:
        if pool is not None:
            list(pool.map(render_video, [1] * workers, [4] * workers, [size] * workers))  # warm the workers
        for r in range(repeats):
            wall, cpu = time.perf_counter(), time.process_time()
            if pool is None:
                render_video(100 + r, frames, size, preset)
            else:
                seeds = [100 + r * workers + w for w in range(workers)]
                list(pool.map(render_video, seeds, [frames] * workers, [size] * workers, [preset] * workers))
            walls.append(time.perf_counter() - wall)
            cpus.append(time.process_time() - cpu)
    finally:
        if pool is not None:
            pool.shutdown()
    total = frames * workers
    result = {"size": size, "workers": workers, "frames": total, "fps": total / float(np.median(walls))}
    result["cpu_fps"] = total / float(np.median(cpus)) if pool is None else float("nan")
    return result


def print_benchmark(preset: str = "default", frames: int = 200) -> None:
    """Print a markdown table of generator speed (sizes 128/256, 1/2 workers) with machine info."""
    import os
    import platform

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}; preset {preset}")
    print("| size | workers | frames | frames/s (wall) | frames/s (CPU time, 1 worker) |")
    print("|---:|---:|---:|---:|---:|")
    for size in (128, 256):
        for workers in (1, 2):
            row = benchmark(size, frames if size == 128 else frames // 2, repeats=3, preset=preset, workers=workers)
            cpu = "" if np.isnan(row["cpu_fps"]) else f"{row['cpu_fps']:.1f}"
            print(f"| {size} | {workers} | {row['frames']} | {row['fps']:.1f} | {cpu} |", flush=True)
