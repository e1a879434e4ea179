"""``lsr bench landmarks``: speed, detection rate, accuracy and jitter of both face trackers, as markdown tables.

Trackers (``landmarks.detect.registry``): "mesh", MediaPipe's detector + 468-point mesh with the 68 points mapped from it
(``landmarks.shape.mesh68``), the default; "hog", dlib's HOG detector + 68-point shape predictor.

1. Speed, on the timing clip resized to size x size, ms per frame (median, p90, mean): full detection on every
   frame; tracking (detection on loss only); the landmark net alone in the tracked region; then rasterise,
   One-Euro and head pose once. The tracker goal is on the tracking row's mean, which amortises the detections.
2. Detection rate and NME of the mesh's 68 points against dlib's on real clips at their own size: over all frames
   where both have points, over frontal ones (|yaw|, |pitch| < 15 degrees by dlib's points, seen along the line of
   sight), and for the jaw and the inner points apart (a fixed mapping is weakest on the silhouette). dlib is the
   reference, not the truth: the NME says how far the mesh's points sit from those the project was built on.
3. Jitter (raw) on the still stretches of those clips (``still_stretches``), and of a static face (one frame
   repeated with pixel noise) before and after One-Euro smoothing.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from lsr.config import BenchLandmarksConfig
from lsr.config.shared import shared_data_dir
from lsr.errors import ConfigError

DEFAULT_CLIP = "clips/tpsmm_driving.mp4"
TRACKERS = ("mesh", "hog")
TRACKER_LABELS = {"mesh": "mesh (MediaPipe)", "hog": "dlib (HOG)"}
TRACKER_GOAL_MS = 10.0  # per frame on the 2-core CPU, detection amortised
NME_GOAL = 0.05  # of the inter-ocular distance, frontal frames
FRONTAL_DEGREES = 15.0
JAW = slice(0, 17)
INNER = slice(17, 68)
RIGID_POINTS = (36, 39, 42, 45, *range(27, 36))  # eye corners and nose: they move with the head only
STILL_MIN_FRAMES = 8
STILL_MAX_MOTION = 0.01  # inter-ocular distances per frame, of the smoothed rigid centre
STILL_WINDOW = 5
STATIC_REPEATS, STATIC_NOISE = 50, 4.0  # the static face: one frame this many times, pixel noise sigma (grey levels)
GROSS_NME = 0.25  # beyond this the two trackers put the face in different places: one of them is off it




def default_video() -> Path:
    path = shared_data_dir() / DEFAULT_CLIP
    if not path.is_file():
        raise ConfigError(
            f"no video given and the shared clip {path} is absent; pass --video PATH (any talking-head video) "
            "or set LSR_SHARED_DATA"
        )
    return path


def default_clips() -> list[Path]:
    """Every .mp4 under the shared clips folder (recursively, sorted); empty when it is absent."""
    folder = shared_data_dir() / "clips"
    return sorted(folder.rglob("*.mp4")) if folder.is_dir() else []


def static_jitter(
    frame: np.ndarray,
    *,
    kind: str = "hog",
    repeats: int = STATIC_REPEATS,
    noise_sigma: float = STATIC_NOISE,
    fps: float = 25.0,
    min_cutoff: float = 1.0,
    beta: float = 0.05,
    seed: int = 0,
) -> tuple[float, float, int]:
    """Jitter (inter-ocular units per frame, all 68 points) of a static face before and after One-Euro smoothing.

    frame: (H, W, 3) uint8 RGB with a face. It is repeated ``repeats`` times with fresh Gaussian pixel noise (sigma
    in grey levels), so any landmark motion is jitter. kind: the tracker ("mesh", "hog", "cnn"). Returns
    (raw jitter, smoothed jitter, missing frames).
    """
    from landmarks.detect.registry import make_tracker
    from landmarks.motion.smooth import jitter, smooth_sequence

    rng = np.random.default_rng(seed)

    def noisy_frames():
        for _ in range(repeats):
            noise = rng.normal(0.0, noise_sigma, frame.shape)
            yield np.clip(frame.astype(np.float32) + noise, 0, 255).astype(np.uint8)

    tracked = make_tracker(kind).track_frames(noisy_frames())
    smoothed = smooth_sequence(tracked.landmarks, fps, min_cutoff=min_cutoff, beta=beta)
    return jitter(tracked.landmarks), jitter(smoothed), int(tracked.missing.sum())


# -- accuracy and stillness ------------------------------------------------------------------------------------------
def _check_sequence(landmarks: np.ndarray, name: str) -> np.ndarray:
    landmarks = np.asarray(landmarks, dtype=np.float64)
    if landmarks.ndim != 3 or landmarks.shape[1:] != (68, 2):
        raise ValueError(f"{name} must be (N, 68, 2), got {landmarks.shape}")
    return landmarks


def nme(points: np.ndarray, reference: np.ndarray, index: slice | Sequence[int] = slice(None)) -> np.ndarray:
    """Per-frame normalised mean error: (N,) float64 mean distance of the ``index`` points of ``points`` from
    ``reference``'s, over ``reference``'s inter-ocular distance (eye centres 36-41, 42-47).

    points, reference: (N, 68, 2), NaN rows where missing; NaN where either is missing.
    """
    from landmarks.shape.measures import inter_ocular_distance

    points, reference = _check_sequence(points, "points"), _check_sequence(reference, "reference")
    if points.shape != reference.shape:
        raise ValueError(f"points {points.shape} and reference {reference.shape} differ")
    index = index if isinstance(index, slice) else list(index)
    distance = np.linalg.norm(points[:, index] - reference[:, index], axis=-1).mean(axis=1)  # (N,)
    return distance / inter_ocular_distance(reference)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[(start, stop)] of the runs of True in a (N,) bool mask, half-open."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def still_stretches(
    reference: np.ndarray,
    *,
    min_frames: int = STILL_MIN_FRAMES,
    max_motion: float = STILL_MAX_MOTION,
    window: int = STILL_WINDOW,
) -> list[tuple[int, int]]:
    """Runs of frames where the head barely moves: [(start, stop)], half-open.

    reference: (N, 68, 2) float, NaN rows for frames that do not count (missing in either tracker). The centre of
    the rigid points (``RIGID_POINTS``), averaged over a centred ``window``-frame window (cut short at gaps and
    ends), must move less than ``max_motion`` inter-ocular distances per frame all through the run, which is at
    least ``min_frames`` long. Frames within window // 2 of a motion are not still: the average already sees it.
    """
    from landmarks.shape.measures import inter_ocular_distance

    reference = _check_sequence(reference, "reference")
    valid = np.isfinite(reference).all(axis=(1, 2))
    centre = reference[:, list(RIGID_POINTS)].mean(axis=1)  # (N, 2)
    smoothed = np.full_like(centre, np.nan)
    half = window // 2
    for start, stop in _runs(valid):
        length = stop - start
        sums = np.concatenate([np.zeros((1, 2)), np.cumsum(centre[start:stop], axis=0)])  # (length + 1, 2)
        low = np.maximum(np.arange(length) - half, 0)
        high = np.minimum(np.arange(length) + half + 1, length)
        smoothed[start:stop] = (sums[high] - sums[low]) / (high - low)[:, None]
    iod = inter_ocular_distance(reference)
    motion = np.linalg.norm(np.diff(smoothed, axis=0), axis=1) / iod[1:]  # (N-1,), NaN across gaps
    with np.errstate(invalid="ignore"):
        steady = motion < max_motion  # step t -> t+1
    # A run of steady steps [a, b) joins frames a..b.
    return [(a, b + 1) for a, b in _runs(steady) if b + 1 - a >= min_frames]


def stretch_jitter(points: np.ndarray, reference: np.ndarray, stretches: Sequence[tuple[int, int]]) -> np.ndarray:
    """Frame-to-frame displacement of the rigid points of ``points`` over ``reference``'s inter-ocular distance (mean
    of the two frames), for every step inside ``stretches``: (steps,) float64.

    points, reference: (N, 68, 2); the frames of the stretches must have points in both.
    """
    from landmarks.shape.measures import inter_ocular_distance

    points, reference = _check_sequence(points, "points"), _check_sequence(reference, "reference")
    rigid = list(RIGID_POINTS)
    steps = []
    for start, stop in stretches:
        moved = np.linalg.norm(np.diff(points[start:stop, rigid], axis=0), axis=-1).mean(axis=1)  # (stop-start-1,)
        iod = inter_ocular_distance(reference[start:stop])
        steps.append(moved / (0.5 * (iod[1:] + iod[:-1])))
    return np.concatenate(steps) if steps else np.zeros(0)


@dataclasses.dataclass
class ClipReport:
    """One clip's numbers. detected: frames with points per tracker; the NME arrays hold one value per counted frame
    (``both``: both trackers have points; ``frontal``: of those, the frontal ones); jitter: per tracker, one value
    per step inside the still stretches."""

    name: str
    size: tuple[int, int]
    frames: int
    detected: dict[str, int]
    nme_all: np.ndarray
    nme_frontal: np.ndarray
    nme_jaw: np.ndarray
    nme_inner: np.ndarray
    still_frames: int
    stretches: int
    jitter: dict[str, np.ndarray]


def track_clip(path: Path, max_frames: int) -> tuple[dict[str, np.ndarray], tuple[int, int]]:
    """Both trackers over the first ``max_frames`` frames of ``path`` (one decode): ({kind: (N, 68, 2) float32, NaN
    rows where missing}, (H, W))."""
    from landmarks.detect.registry import make_tracker
    from landmarks.io.video import iter_frames

    trackers = {kind: make_tracker(kind) for kind in TRACKERS}
    rows: dict[str, list[np.ndarray]] = {kind: [] for kind in TRACKERS}
    nan_row = np.full((68, 2), np.nan, np.float32)
    size = (0, 0)
    for frame in itertools.islice(iter_frames(path), max_frames):
        size = frame.shape[:2]
        for kind, tracker in trackers.items():
            points = tracker.update(frame)
            rows[kind].append(nan_row if points is None else points)
    if not rows[TRACKERS[0]]:
        raise ConfigError(f"{path} has no frames; pass a readable video")
    return {kind: np.stack(found) for kind, found in rows.items()}, size


def clip_report(name: str, tracks: dict[str, np.ndarray], size: tuple[int, int]) -> ClipReport:
    """Detection, NME of the mesh against dlib and still-stretch jitter of one clip's tracks (``track_clip``)."""
    from landmarks.motion.head_pose import estimate_head_pose
    from landmarks.motion.retarget_points import RIGID_INDEX

    mesh, dlib = tracks["mesh"], tracks["hog"]
    has = {kind: np.isfinite(points).all(axis=(1, 2)) for kind, points in tracks.items()}
    both = has["mesh"] & has["hog"]
    # The pose relative to the line of sight, which is what makes a face look frontal: the points are moved so their
    # centre sits on the optical axis (an off-centre face is seen at an angle, up to ~15 degrees in a portrait frame).
    # Rigid points only: an open mouth must not read as the head pitching down.
    rigid = list(RIGID_INDEX)
    image_centre = np.array([size[1] / 2.0, size[0] / 2.0], np.float32)
    pose = np.stack([estimate_head_pose(points - points[rigid].mean(axis=0) + image_centre, size, RIGID_INDEX)
                     for points in dlib])  # (N, 3) yaw, pitch, roll; NaN rows where dlib has none
    with np.errstate(invalid="ignore"):
        frontal = both & (np.abs(pose[:, 0]) < FRONTAL_DEGREES) & (np.abs(pose[:, 1]) < FRONTAL_DEGREES)
    errors = nme(mesh, dlib)
    reference = np.where(both[:, None, None], dlib, np.nan)
    stretches = still_stretches(reference)
    return ClipReport(
        name=name,
        size=size,
        frames=len(dlib),
        detected={kind: int(found.sum()) for kind, found in has.items()},
        nme_all=errors[both],
        nme_frontal=errors[frontal],
        nme_jaw=nme(mesh, dlib, JAW)[both],
        nme_inner=nme(mesh, dlib, INNER)[both],
        still_frames=sum(stop - start for start, stop in stretches),
        stretches=len(stretches),
        jitter={kind: stretch_jitter(tracks[kind], dlib, stretches) for kind in TRACKERS},
    )


# -- tables ----------------------------------------------------------------------------------------------------------
def _mean(values: np.ndarray) -> float:
    return float(np.mean(values)) if len(values) else float("nan")


def _number(value: float, digits: int = 4) -> str:
    return f"{value:.{digits}f}" if np.isfinite(value) else "n/a"


def _agreeing(errors: np.ndarray) -> np.ndarray:
    """The NMEs of the frames where the two trackers do not disagree grossly."""
    return errors[errors <= GROSS_NME]


def _percent(part: int, whole: int) -> str:
    return f"{100.0 * part / whole:.1f} %" if whole else "n/a"


def accuracy_table(reports: Sequence[ClipReport]) -> list[str]:
    """Detection rate and NME per clip and pooled over all frames of all clips (markdown lines)."""
    lines = [
        f"| clip | size | frames | mesh detected | dlib detected | both | gross > {GROSS_NME:g} | NME | frontal frames "
        "| NME frontal | NME frontal w/o gross | NME jaw 0-16 | NME inner 17-67 |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]

    def row(name: str, size: str, group: Sequence[ClipReport]) -> str:
        frames = sum(report.frames for report in group)
        detected = {kind: sum(report.detected[kind] for report in group) for kind in TRACKERS}
        pooled = {
            field: np.concatenate([getattr(report, field) for report in group])
            for field in ("nme_all", "nme_frontal", "nme_jaw", "nme_inner")
        }
        return (
            f"| {name} | {size} | {frames} | {_percent(detected['mesh'], frames)} | {_percent(detected['hog'], frames)} "
            f"| {len(pooled['nme_all'])} | {int((pooled['nme_all'] > GROSS_NME).sum())} "
            f"| {_number(_mean(pooled['nme_all']))} | {len(pooled['nme_frontal'])} "
            f"| {_number(_mean(pooled['nme_frontal']))} | {_number(_mean(_agreeing(pooled['nme_frontal'])))} "
            f"| {_number(_mean(pooled['nme_jaw']))} "
            f"| {_number(_mean(pooled['nme_inner']))} |"
        )

    for report in reports:
        lines.append(row(report.name, f"{report.size[1]}x{report.size[0]}", [report]))
    lines.append(row("**all clips**", "", reports))
    return lines


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

    from landmarks.io.video import iter_frames, probe_video

    fps = probe_video(video).fps
    frames = []
    for frame in itertools.islice(iter_frames(video), count):
        frames.append(np.ascontiguousarray(cv2.resize(frame, (size, size), interpolation=cv2.INTER_AREA)))
    if not frames:
        raise ConfigError(f"{video} has no frames; pass a readable video with --video")
    return frames, fps


@dataclasses.dataclass
class SpeedRow:
    tracker: str
    stage: str
    times: np.ndarray  # (frames,) ms
    note: str = ""


def time_trackers(frames: list[np.ndarray], raster_size: int, fps: float) -> tuple[list[SpeedRow], dict[str, float], int]:
    """Time every stage of both trackers on ``frames`` ((H, W, 3) uint8 RGB, one size). Returns (rows, mean
    tracking ms per tracker, the index of the first frame the mesh tracked, for the static-face jitter)."""
    from landmarks.detect import mediapipe_mesh as face_mesh
    from landmarks.detect.face_detector import predict_landmarks
    from landmarks.detect.registry import make_detector, make_tracker
    from landmarks.motion.head_pose import estimate_head_pose
    from landmarks.motion.smooth import OneEuroFilter

    count, height = len(frames), frames[0].shape[0]
    rows: list[SpeedRow] = []
    tracking_ms: dict[str, float] = {}
    tracked: dict[str, list[np.ndarray | None]] = {}
    for kind in TRACKERS:
        label = TRACKER_LABELS[kind]
        detector = make_detector(kind)
        detector.detect(frames[0])  # load the models outside the timings
        full = "BlazeFace + mesh" if kind == "mesh" else "HOG + shape predictor"
        rows.append(SpeedRow(label, f"full detection ({full}), every frame",
                             _time_per_frame(lambda i: detector.detect(frames[i]), count)))
        tracker = make_tracker(detector)
        points: list[np.ndarray | None] = [None] * count
        meshes: list[np.ndarray | None] = [None] * count

        def track_step(index: int) -> None:
            points[index] = tracker.update(frames[index])
            meshes[index] = getattr(tracker, "mesh", None)

        times = _time_per_frame(track_step, count)
        missing = sum(found is None for found in points)
        tracking_ms[kind] = float(times.mean())
        rows.append(SpeedRow(label, "tracking (detection on loss only)", times,
                             f"{tracker.detections} detections, {missing} missing"))
        tracked[kind] = points
        if kind == "mesh":
            follow = [i for i in range(1, count) if meshes[i - 1] is not None]
            regions = {i: face_mesh.region_from_mesh(meshes[i - 1]) for i in follow}
            net_ms = _time_per_frame(lambda k: face_mesh.predict_mesh(frames[follow[k]], regions[follow[k]]), len(follow))
            rows.append(SpeedRow(label, "mesh net only (in the tracked region)", net_ms))
        else:
            valid = [i for i, found in enumerate(points) if found is not None]
            boxes = {i: tracker.box_from_landmarks(points[i]) for i in valid}
            predictor_ms = _time_per_frame(lambda k: predict_landmarks(frames[valid[k]], boxes[valid[k]]), len(valid))
            rows.append(SpeedRow(label, "shape predictor only (in the tracked box)", predictor_ms))

    # The stages after the tracker, once, on the default tracker's points (dlib's if it found none).
    kind = "mesh" if any(found is not None for found in tracked["mesh"]) else "hog"
    valid_points = [found for found in tracked[kind] if found is not None]
    first = next((i for i, found in enumerate(tracked[kind]) if found is not None), 0)
    if valid_points:
        try:
            from landmarks.shape.raster import draw_landmarks
        except ImportError:  # the rasteriser's optional drawing backend is absent
            draw_landmarks = None
        if draw_landmarks is not None:
            factor = raster_size / height
            rows.append(SpeedRow("both", f"rasterise at {raster_size}x{raster_size}", _time_per_frame(
                lambda k: draw_landmarks(valid_points[k] * factor, raster_size), len(valid_points))))
        one_euro = OneEuroFilter(fps)
        rows.append(SpeedRow("both", "One-Euro smoothing",
                             _time_per_frame(lambda k: one_euro(valid_points[k]), len(valid_points))))
        shape = frames[0].shape[:2]
        rows.append(SpeedRow("both", "head pose (solvePnP)", _time_per_frame(
            lambda k: estimate_head_pose(valid_points[k], shape), len(valid_points))))
    return rows, tracking_ms, first


def speed_table(rows: Sequence[SpeedRow]) -> list[str]:
    lines = ["| tracker | stage | median ms/frame | p90 ms/frame | mean ms/frame | notes |", "|---|---|---:|---:|---:|---|"]
    for row in rows:
        if len(row.times) == 0:
            lines.append(f"| {row.tracker} | {row.stage} | n/a | n/a | n/a | no frames to time |")
            continue
        lines.append(f"| {row.tracker} | {row.stage} | {np.median(row.times):.2f} | {np.percentile(row.times, 90):.2f} "
                     f"| {row.times.mean():.2f} | {row.note} |")
    return lines


def _verdict(value: float, goal: float) -> str:
    if not np.isfinite(value):
        return "not measured"
    return "met" if value <= goal else "NOT met"


def _clip_name(path: Path) -> str:
    from lsr.eval.machine import shown_path

    clips = shared_data_dir() / "clips"
    resolved = Path(path).resolve()
    if clips.is_dir() and clips.resolve() in resolved.parents:
        return str(resolved.relative_to(clips.resolve()))
    return shown_path(path)


def run_bench_landmarks(cfg: BenchLandmarksConfig) -> str:
    """Time, compare and measure both trackers; print (and return) the markdown tables, and with ``cfg.out_md``
    write them as the BENCHMARKS.md section "landmarks"."""
    from tqdm import tqdm

    from lsr.eval import sections
    from lsr.eval.machine import machine_markdown, shown_path

    clips = [Path(clip) for clip in cfg.clips] if cfg.clips else default_clips()
    if cfg.video is not None:
        video = Path(cfg.video)
    elif (shared_data_dir() / DEFAULT_CLIP).is_file() or not clips:
        video = default_video()  # the clear error when there is nothing to run on
    else:
        video = clips[0]

    frames, fps = _load_frames(video, cfg.frames, cfg.size)
    speed_rows, tracking_ms, first_face = time_trackers(frames, cfg.raster_size, fps)
    lines = [
        f"**Speed** on `{shown_path(video)}`: {len(frames)} frames resized to {cfg.size}x{cfg.size}, ms per frame. "
        "Tracking runs the landmark net in the region from the previous frame and detects only on loss; its mean "
        "amortises those detections.",
        "",
        *speed_table(speed_rows),
        "",
    ]

    reports = []
    if clips:
        for clip in tqdm(clips, desc="clips", unit="clip", disable=not cfg.progress):
            tracks, size = track_clip(clip, cfg.clip_frames)
            reports.append(clip_report(_clip_name(clip), tracks, size))
        lines += [
            f"**Detection and accuracy** on {len(clips)} real clip(s) (at most {cfg.clip_frames} frames each, at their "
            "own size): detected = frames with landmarks / frames; NME = mean distance of the mesh's 68 mapped "
            "points from dlib's / dlib's inter-ocular distance (eye centres), over the frames where both have "
            f"points; gross: frames with NME > {GROSS_NME:g} (the two put the face in different places: one of them "
            f"is off it); frontal: |yaw| and |pitch| < {FRONTAL_DEGREES:g} degrees (head pose of dlib's points, "
            "relative to the line of sight). dlib is the reference, not ground truth.",
            "",
            *accuracy_table(reports),
            "",
        ]
    else:
        lines += ["Note: no real clips (the shared ../shared/data/clips is absent and no --clips given): detection "
                  "rate, NME and still-stretch jitter skipped.", ""]

    jitter_rows = []
    if reports:
        still = sum(report.still_frames for report in reports)
        stretches = sum(report.stretches for report in reports)
        for kind in TRACKERS:
            steps = np.concatenate([report.jitter[kind] for report in reports])
            jitter_rows.append(f"| still stretches of the real clips ({stretches} stretch(es)) | {TRACKER_LABELS[kind]} "
                               f"| {still} | {_number(_mean(steps))} | - |")
    static = frames[first_face]
    for kind in TRACKERS:
        raw, smoothed, missing = static_jitter(static, kind=kind, fps=fps)
        note = f" ({missing} missing)" if missing else ""
        jitter_rows.append(f"| static face, one frame x{STATIC_REPEATS} with pixel noise sigma {STATIC_NOISE:g}{note} "
                           f"| {TRACKER_LABELS[kind]} | {STATIC_REPEATS} "
                           f"| {_number(raw)} | {_number(smoothed)} |")
    lines += [
        "**Jitter**: mean frame-to-frame landmark motion / inter-ocular distance, no smoothing unless stated. Still "
        f"stretches: runs of >= {STILL_MIN_FRAMES} frames where both trackers have points and the centre of dlib's "
        f"eye corners and nose ({STILL_WINDOW}-frame centred average) moves < {STILL_MAX_MOTION:g} inter-ocular "
        "distances per frame; jitter of those rigid points, over dlib's inter-ocular distance. Static face: all 68 "
        f"points, raw and One-Euro (min_cutoff 1.0, beta 0.05, {fps:g} fps).",
        "",
        "| sequence | tracker | frames | jitter (raw) | jitter (One-Euro) |",
        "|---|---|---:|---:|---:|",
        *jitter_rows,
        "",
    ]

    frontal = np.concatenate([report.nme_frontal for report in reports]) if reports else np.zeros(0)
    goals = ", ".join(f"{TRACKER_LABELS[kind]} {tracking_ms[kind]:.2f} ms {_verdict(tracking_ms[kind], TRACKER_GOAL_MS)}"
                      for kind in TRACKERS)
    lines += [
        f"Goals: the tracker <= {TRACKER_GOAL_MS:g} ms per frame on the 2-core CPU, detection amortised (tracking "
        f"mean): {goals}. NME of the mesh's 68 points <= {NME_GOAL:g} of the inter-ocular distance on frontal "
        f"frames: {_number(_mean(frontal))} {_verdict(_mean(frontal), NME_GOAL)} ({_number(_mean(_agreeing(frontal)))} "
        f"{_verdict(_mean(_agreeing(frontal)), NME_GOAL)} without the {int((frontal > GROSS_NME).sum())} gross "
        "disagreements).",
        "",
        machine_markdown(),
    ]
    text = "\n".join(lines)
    sections.publish(cfg, "lsr bench landmarks", "landmarks",
                     "Face landmarks: speed, detection, NME and jitter of both trackers (`lsr bench landmarks`)", text)
    return text
