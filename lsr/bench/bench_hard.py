"""``lsr bench hard``: what the re-enactment pipeline does with hard inputs (numerical stability, clear errors).

Every case is built by a deterministic transform of easy material: a real clip of the shared *training* clips
(``../shared/data/real_talking_heads``; its first clip, or ``--clip``) when present, else a synthetic person, and
the synthetic generator for exact head poses (yaw ±60°). No evaluation-only person is used. Each case runs the
library's pipeline (``lsr.pipeline.Reenactor``: source shots -> subject, driver -> frames; no fine-tuning, so the
table isolates the model and the pre/post-processing) and records:

* outcome: ``ok``, or the one-line error the user would see (a traceback is recorded as such and fails the run);
* frames out, driver frames without a face (passed through), synthesised frames with a non-finite value;
* output with a face: the share of synthesised frames in which dlib finds a face;
* PSNR / NMKE against the case's easy twin (the same source and driver without the hardship, frame by frame:
  how far the hardship moves the output; NMKE between the landmarks detected in both outputs);
* seconds and ms per output frame.
"""

from __future__ import annotations

import dataclasses
import math
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from lsr.eval.machine import shown_path

if TYPE_CHECKING:
    from lsr.config import BenchHardConfig

SECTION = "hard_cases"
DRIVER_FRAMES = 24
SOURCE_SHOTS = 8
FRAME_SIDE = 360  # real frames are scaled so their longer side is this (faces stay well above the detector's minimum)
SYNTHETIC_SIDE = 256


@dataclasses.dataclass
class HardCase:
    name: str
    what: str
    source: list[np.ndarray]
    """Source frames (H, W, 3) uint8 RGB."""
    driver: list[np.ndarray] | np.ndarray
    """Driver frames, or an (N, 68, 2) landmark array in frame pixels."""
    twin: str | None = None
    """The easy case this one is compared with, frame by frame."""
    k: int | None = None
    check_faces_every: int = 1
    """Detect faces in every n-th output (long sequences)."""


@dataclasses.dataclass
class CaseResult:
    name: str
    what: str
    outcome: str
    frames: int = 0
    driver_without_face: int = 0
    nonfinite_frames: int = 0
    output_face_share: float | None = None
    psnr_vs_twin: float | None = None
    nmke_vs_twin: float | None = None
    seconds: float = 0.0
    traceback: str | None = None

    @property
    def ms_per_frame(self) -> float | None:
        return 1000 * self.seconds / self.frames if self.frames else None


# ---- material -------------------------------------------------------------------------------------------


def _scale_to(frame: np.ndarray, side: int) -> np.ndarray:
    scale = side / max(frame.shape[:2])
    size = (round(frame.shape[1] * scale), round(frame.shape[0] * scale))
    return cv2.resize(frame, size, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC)


def real_frames(clip: Path, count: int) -> list[np.ndarray]:
    """The first ``count`` frames of a clip, scaled to FRAME_SIDE on the longer side."""
    from landmarks.io.video import iter_frames

    frames = []
    for frame in iter_frames(clip):
        frames.append(_scale_to(frame, FRAME_SIDE))
        if len(frames) >= count:
            break
    return frames


def real_material(clip: Path, frames_needed: int = 96) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(source shots, driver frames) from one real clip: shots from its first half, the driver after them."""
    frames = real_frames(clip, frames_needed)
    half = len(frames) // 2
    picks = np.linspace(0, half - 1, SOURCE_SHOTS).round().astype(int)
    return [frames[i] for i in picks], frames[half : half + DRIVER_FRAMES]


def synthetic_material(identity_seed: int, preset: Any = "default", video_index: int = 0) -> tuple[list, list, np.ndarray]:
    """(shots, driver frames, driver landmarks) of a synthetic person at 256²."""
    from lsr.data.synth.generate import render_video

    clip = render_video(identity_seed, SOURCE_SHOTS + DRIVER_FRAMES, SYNTHETIC_SIDE, preset=preset, video_index=video_index)
    frames = list(clip.frames)
    return frames[:SOURCE_SHOTS], frames[SOURCE_SHOTS:], clip.landmarks[SOURCE_SHOTS:]


def yaw_preset(yaw: float):
    """The default synthetic preset with the head held at ``yaw`` degrees (sign from the seed), no occluders."""
    from lsr.data.synth.distributions import get_preset

    # the generator soft-clips angles as limit * tanh(signal / limit); a huge base saturates tanh at 0.7616
    return dataclasses.replace(get_preset("default"), name=f"yaw{yaw:g}", yaw_base_sd=1e4, yaw_swing=0.0,
                               yaw_limit=yaw / math.tanh(1.0), occluder_fraction=0.0)


def _detect_all(frames: list[np.ndarray]) -> list[np.ndarray | None]:
    from landmarks.detect.registry import make_detector

    detector = make_detector()
    found = []
    for frame in frames:
        faces = detector.detect(frame)
        found.append(faces[0].landmarks if faces else None)
    return found


# ---- transforms (deterministic) ---------------------------------------------------------------------------


def rotate(frame: np.ndarray, degrees: float) -> np.ndarray:
    height, width = frame.shape[:2]
    matrix = cv2.getRotationMatrix2D((width / 2, height / 2), degrees, 1.0)
    return cv2.warpAffine(frame, matrix, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def small_face(frame: np.ndarray, landmarks: np.ndarray | None, face_px: int, canvas: int = 640) -> np.ndarray:
    """The frame shrunk so its face is ``face_px`` wide, in the middle of a ``canvas`` square of its mean colour."""
    width = float(np.ptp(landmarks[:, 0])) if landmarks is not None else frame.shape[1] / 3
    small = cv2.resize(frame, None, fx=face_px / width, fy=face_px / width, interpolation=cv2.INTER_AREA)
    out = np.empty((canvas, canvas, 3), np.uint8)
    out[:] = frame.reshape(-1, 3).mean(axis=0).astype(np.uint8)
    top, left = (canvas - small.shape[0]) // 2, (canvas - small.shape[1]) // 2
    out[top : top + small.shape[0], left : left + small.shape[1]] = small
    return out


def cover_lower_face(frame: np.ndarray, landmarks: np.ndarray | None) -> np.ndarray:
    """A flat skin-grey patch (a hand or a mask) over the face from the nose down."""
    if landmarks is None:
        return frame.copy()
    out = frame.copy()
    x0, x1 = int(landmarks[:, 0].min()) - 6, int(landmarks[:, 0].max()) + 6
    y0, y1 = int(landmarks[29, 1]), int(landmarks[:, 1].max()) + 10  # from the nose bridge's lower part to the chin
    cv2.rectangle(out, (x0, y0), (x1, y1), (196, 160, 140), thickness=-1)
    return out


def motion_blur(frame: np.ndarray, length: int = 21, degrees: float = 30.0) -> np.ndarray:
    kernel = np.zeros((length, length), np.float32)
    kernel[length // 2] = 1.0
    kernel = cv2.warpAffine(kernel, cv2.getRotationMatrix2D((length / 2 - 0.5, length / 2 - 0.5), degrees, 1.0),
                            (length, length))
    return cv2.filter2D(frame, -1, kernel / kernel.sum())


def jpeg(frame: np.ndarray, quality: int = 4) -> np.ndarray:
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    return cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def grey(frame: np.ndarray) -> np.ndarray:
    return np.repeat(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)[:, :, None], 3, axis=2)


def exposure(frame: np.ndarray, gain: float, offset: float = 0.0) -> np.ndarray:
    return np.clip(frame.astype(np.float32) * gain + offset, 0, 255).astype(np.uint8)


def leave_frame(frames: list[np.ndarray]) -> list[np.ndarray]:
    """The camera pans away: the picture slides right, the last third of the frames show no face at all."""
    out = []
    for index, frame in enumerate(frames):
        shift = int(round(frame.shape[1] * 1.2 * min(1.0, index / max(1, (2 * len(frames)) // 3))))
        matrix = np.float32([[1, 0, shift], [0, 1, 0]])
        out.append(cv2.warpAffine(frame, matrix, (frame.shape[1], frame.shape[0]), borderValue=(40, 40, 40)))
    return out


def long_landmarks(landmarks: np.ndarray, frames: int) -> np.ndarray:
    """(frames, 68, 2): the driver's landmarks back and forth (ping-pong), with a deterministic 0.3 px tremor."""
    order = np.concatenate([np.arange(len(landmarks)), np.arange(len(landmarks) - 2, 0, -1)])
    tiled = landmarks[np.resize(order, frames)].astype(np.float32)
    return tiled + np.random.default_rng(0).normal(0.0, 0.3, tiled.shape).astype(np.float32)


# ---- cases ------------------------------------------------------------------------------------------------


def build_cases(clip: Path | None, other_clip: Path | None, long_frames: int, progress: bool = False) -> list[HardCase]:
    """The case list. ``clip`` / ``other_clip``: real training clips (None: synthetic people stand in)."""
    if clip is not None:
        shots, driver = real_material(clip)
        base = f"real clip {clip.parent.name}/{clip.name}"
    else:
        shots, driver, _ = synthetic_material(11)
        base = "synthetic person 11"
    if other_clip is not None:
        _, other_driver = real_material(other_clip)
    else:
        _, other_driver, _ = synthetic_material(23, preset="extreme_pose")
    driver_landmarks = _detect_all(driver)
    found = [points for points in driver_landmarks if points is not None]
    if not found:
        raise RuntimeError(f"no face in the easy driver of {base}; choose another --clip")
    if clip is not None:  # 64 frames spread over the clip's first 128 (fewer frames: some repeat)
        pool = real_frames(clip, 128)
        many_shots = [pool[i] for i in np.linspace(0, len(pool) - 1, 64).round().astype(int)]
    else:
        from lsr.data.synth.generate import render_video

        many_shots = list(render_video(11, 64, SYNTHETIC_SIDE).frames)
    synthetic_shots, synthetic_driver, _ = synthetic_material(5, video_index=0)
    cases = [
        HardCase("easy", f"{base}: {len(shots)} shots, a {len(driver)}-frame driver from later in the clip", shots, driver),
        HardCase("easy_synthetic", "synthetic person 5: 8 shots, a driver of the same person (yaw within ±25°)",
                 synthetic_shots, synthetic_driver),
    ]
    for sign, seed in (("+", 5), ("-", 3)):
        _, yawed, _ = synthetic_material(seed, preset=yaw_preset(60.0), video_index=1)
        pose = "same person" if seed == 5 else "another synthetic person"
        cases.append(HardCase(f"yaw {sign}60", f"driver: {pose} holding the head at yaw {sign}60°", synthetic_shots,
                              yawed, twin="easy_synthetic"))
    def drive(name, what, transform, **extra):
        cases.append(HardCase(name, what, shots, [transform(f, p) for f, p in zip(driver, driver_landmarks)], "easy", **extra))

    drive("roll 45", "driver rotated 45°", lambda f, p: rotate(f, 45.0))
    drive("face 40 px", "driver face 40 px wide in a 640² frame", lambda f, p: small_face(f, p, 40))
    drive("half face covered", "a flat patch over the driver's face from the nose down", cover_lower_face)
    drive("very dark", "driver at 12 % brightness", lambda f, p: exposure(f, 0.12))
    drive("over-exposed", "driver at 2.8x gain + 40, clipped", lambda f, p: exposure(f, 2.8, 40))
    drive("motion blur", "driver blurred along a 21-px line", lambda f, p: motion_blur(f))
    drive("heavy JPEG", "driver JPEG quality 4", lambda f, p: jpeg(f))
    cases.append(HardCase("grayscale", "source shots and driver in grey", [grey(f) for f in shots],
                          [grey(f) for f in driver], "easy"))
    cases.append(HardCase("1 shot", "one source shot", shots[:1], driver, "easy", k=1))
    cases.append(HardCase("64 shots", "64 source frames, --k 32 (the most)", many_shots, driver, "easy", k=32))
    cases.append(HardCase("other face shape", "driver: another person (relative motion)", shots, other_driver))
    cases.append(HardCase("driver leaves frame", "the driver pans out of view over its first 2/3", shots,
                          leave_frame(driver), "easy"))
    cases.append(HardCase("1-frame driver", "a single driver image", shots, driver[:1], "easy"))
    points = np.stack(found)
    cases.append(HardCase(f"{long_frames} landmarks", f"a {long_frames}-frame landmark sequence (.npy, frame pixels)",
                          shots, long_landmarks(points, long_frames), check_faces_every=max(1, long_frames // 20)))
    return cases


# ---- running ----------------------------------------------------------------------------------------------


def _driver_file(case: HardCase, folder: Path) -> Path:
    from landmarks.io.image_files import write_image
    from landmarks.io.video import VideoWriter

    stem = "".join(c if c.isalnum() else "_" for c in case.name)
    if isinstance(case.driver, np.ndarray):
        path = folder / f"{stem}.npy"
        np.save(path, case.driver)
        return path
    if len(case.driver) == 1:
        path = folder / f"{stem}.png"
        write_image(path, case.driver[0])
        return path
    path = folder / f"{stem}.mp4"
    with VideoWriter(path, 25, crf=12) as writer:
        for frame in case.driver:
            writer.write(frame)
    return path


def run_case(reenactor, case: HardCase, folder: Path) -> tuple[CaseResult, list[np.ndarray | None]]:
    """Run one case; returns its result and the synthesised outputs (None where the driver had no face)."""
    from landmarks.exceptions import LandmarksError
    from lsr.errors import LsrError

    result = CaseResult(case.name, case.what, "ok")
    outputs: list[np.ndarray | None] = []
    backend = reenactor.backend
    synthesize = backend.synthesize
    nonfinite = [0]

    def checked(*args, **kwargs):
        image, layout = synthesize(*args, **kwargs)
        nonfinite[0] += int(not np.isfinite(np.asarray(image)).all())
        return image, layout

    backend.synthesize = checked
    started = time.perf_counter()
    try:
        driver = _driver_file(case, folder)
        reenactor.encode_subject(case.source, k=case.k)
        for frame in reenactor.reenact(driver, mode="auto"):
            result.frames += 1
            result.driver_without_face += int(not frame.has_face)
            keep = frame.has_face and frame.index % case.check_faces_every == 0
            outputs.append(frame.synthesis if keep else None)
    except (LsrError, LandmarksError) as exc:  # the temp folder of the case files is no news to the reader
        result.outcome = "error: " + str(exc).replace(f"{folder}/", "")
    except Exception as exc:  # noqa: BLE001 - the point of the bench: a traceback is a finding, not a crash
        result.outcome = f"TRACEBACK {type(exc).__name__}: {exc}"
        result.traceback = traceback.format_exc()
    finally:
        backend.synthesize = synthesize
    result.seconds = time.perf_counter() - started
    result.nonfinite_frames = nonfinite[0]
    return result, outputs


def compare(result: CaseResult, outputs: list, twin_outputs: list | None, detector) -> None:
    """Fill the output-face share and the PSNR / NMKE against the twin's outputs (frame by frame)."""
    from lsr.eval.metrics import nmke, psnr

    checked = [o for o in outputs if o is not None]
    marks = {id(o): (faces[0].landmarks if (faces := detector.detect(o)) else None) for o in checked}
    if checked:
        result.output_face_share = sum(marks[id(o)] is not None for o in checked) / len(checked)
    if not twin_outputs:
        return
    psnrs, errors = [], []
    for mine, theirs in zip(outputs, twin_outputs):
        if mine is None or theirs is None or mine.shape != theirs.shape:
            continue
        psnrs.append(float(psnr(mine[None], theirs[None])[0]))
        faces = detector.detect(theirs)
        if marks.get(id(mine)) is not None and faces:
            errors.append(float(nmke(marks[id(mine)], faces[0].landmarks)))
    finite = [p for p in psnrs if math.isfinite(p)]
    result.psnr_vs_twin = float(np.mean(finite)) if finite else (math.inf if psnrs else None)
    result.nmke_vs_twin = float(np.mean(errors)) if errors else None


def hard_cases(cfg: BenchHardConfig) -> tuple[list[CaseResult], dict[str, Any]]:
    import tempfile

    import torch
    from tqdm import tqdm

    from landmarks.detect.registry import make_detector
    from lsr.pipeline import Reenactor
    from lsr.weights import resolve_weights

    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    clips = cfg.resolved_clips()
    cases = build_cases(clips[0], clips[1], cfg.long_frames)
    if cfg.cases:
        cases = [c for c in cases if c.name in cfg.cases or c.name in ("easy", "easy_synthetic")]
    weights = resolve_weights(cfg.weights)
    reenactor = Reenactor(weights, device="cpu")
    detector = make_detector()
    results, outputs = [], {}
    with tempfile.TemporaryDirectory(prefix="lsr-bench-hard-") as folder:
        for case in tqdm(cases, desc="bench hard", unit="case", disable=not cfg.progress):
            result, produced = run_case(reenactor, case, Path(folder))
            outputs[case.name] = produced
            compare(result, produced, outputs.get(case.twin) if case.twin else None, detector)
            results.append(result)
    settings = {"weights": str(weights), "clips": [str(c) if c else "synthetic" for c in clips],
                "long_frames": cfg.long_frames}
    return results, settings


def _cell(value: float | None, digits: int, suffix: str = "") -> str:
    if value is None:
        return "–"
    if math.isinf(value):
        return "identical"
    return f"{value:.{digits}f}{suffix}"


def hard_markdown(results: list[CaseResult], settings: dict[str, Any], machine: str) -> str:
    lines = [f"Model `{shown_path(settings['weights'])}` (no fine-tuning); real material: "
             f"{', '.join(f'`{shown_path(c)}`' for c in settings['clips'])} (training clips; synthetic when absent).", "",
             "| case | what | outcome | frames out | driver frames without a face | non-finite frames | outputs with a face "
             "| PSNR vs easy twin | NMKE vs easy twin | s | ms/frame |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        outcome = r.outcome.replace("|", "/")
        face = "–" if r.output_face_share is None else f"{100 * r.output_face_share:.0f} %"
        lines.append(f"| {r.name} | {r.what} | {outcome} | {r.frames} | {r.driver_without_face} | {r.nonfinite_frames} | "
                     f"{face} | {_cell(r.psnr_vs_twin, 2)} | {_cell(r.nmke_vs_twin, 3)} | {r.seconds:.1f} | "
                     f"{_cell(r.ms_per_frame, 1)} |")
    lines += ["", "Twins: `easy` for the real material's cases, `easy_synthetic` for the yaw cases; – where a case has no "
              "twin, no frame pair or no face in one of the pair. ms/frame includes detection, tracking and the warps.",
              "", machine]
    return "\n".join(lines)


def run_bench_hard(cfg: BenchHardConfig) -> list[CaseResult]:
    """Entry point of ``lsr bench hard``: print the table (and write its BENCHMARKS.md section with --out-md)."""
    from lsr.errors import LsrError
    from lsr.eval.sections import publish
    from lsr.eval.machine import machine_markdown

    results, settings = hard_cases(cfg)
    text = hard_markdown(results, settings, machine_markdown())
    publish(cfg, "lsr bench hard", SECTION, "Hard inputs (`lsr bench hard`)", text)
    crashed = [r for r in results if r.traceback is not None]
    for r in crashed:
        print(r.traceback)
    if crashed:
        raise LsrError(f"{len(crashed)} hard case(s) ended in a traceback: {', '.join(r.name for r in crashed)}")
    return results
