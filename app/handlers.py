"""The app's callbacks: a thin layer over ``lsr.pipeline`` / ``deploy`` (no Gradio layout here; see ``app.ui``).

Everything heavy (torch, the face models, the model) loads on the first request, once, in ``ModelStore``. Each
handler turns the library's typed errors (``LsrError``, ``LandmarksError``) into ``gr.Error`` so the page
shows their message (which already says what to do). Files a run writes live in a per-session folder
(``SessionFiles``) that is replaced by the next run and removed when the browser tab closes.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import re
import shutil
import tempfile
import threading
import time
import uuid
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from lsr.core import MAX_K

LOG = logging.getLogger("lsr.app")
DISPLAY_SIDE = 256  # shots, per-shot results and side-by-side tiles are shown at least this large
PANEL_TITLES = ("driver frame", "landmarks", "latent layout", "output")
LIVE_NETWORK_THREADS = 1  # onnxruntime threads of the live network: on 2 cores, 1 thread ran it as fast as 2 (45 ms)
# and 2.4x faster than its default threads while another process kept a core busy (58 against 141 ms)


def how_to_get_weights() -> str:
    return (
        "**No model loaded.** The default model is missing from this install (reinstall with `pip install -e .`), "
        "or $LSR_WEIGHTS points at a folder without one. Or train one, for example a small one on procedural "
        "synthetic faces:\n\n"
        "`lsr train --synthetic-identities 16 --preset tiny --out runs/lsr` (writes `runs/lsr/weights`), then "
        "`lsr app --weights runs/lsr/weights`.\n\n"
        "To try the interface first: `lsr app --random-init` serves an untrained tiny model (its output is noise)."
    )


@dataclasses.dataclass(frozen=True)
class Limits:
    """What the app accepts (``lsr.config.AppConfig``)."""

    max_video_seconds: float = 20.0
    max_video_frames: int = 500
    max_upload_mb: float = 50.0
    max_k: int = MAX_K


def default_weights() -> Path | None:
    """$LSR_WEIGHTS, else the shipped default model (``lsr.weights``); None when neither holds a model."""
    from lsr.weights import MissingWeightsError
    from lsr.weights import default_weights as installed

    try:
        return installed()
    except MissingWeightsError:
        return None


def random_init_weights(folder: Path, seed: int = 0) -> Path:
    """A randomly initialised ``tiny`` model saved into ``folder`` (config.json + model.safetensors)."""
    import torch

    from models_def import LSRModel, preset_config

    if (folder / "config.json").is_file():
        return folder
    torch.manual_seed(seed)
    return LSRModel(preset_config("tiny")).save_pretrained(folder)


class ModelStore:
    """The runtimes, each loaded once on first use (thread-safe). ``weights`` None = no model (see ``problem``)."""

    def __init__(self, weights: Path | None, device: str = "auto") -> None:
        self.weights = Path(weights) if weights is not None else None
        self.device = device
        self._lock = threading.Lock()
        self._torch = None
        self._onnx = None
        self._live = None
        self._detector = None

    @property
    def problem(self) -> str | None:
        """Markdown explaining why no model can run, or None."""
        return how_to_get_weights() if self.weights is None else None

    @property
    def detector(self):
        with self._lock:
            if self._detector is None:
                from landmarks.detect.registry import make_detector

                self._detector = make_detector()
            return self._detector

    def _require_weights(self) -> Path:
        if self.weights is None:
            from lsr.errors import WeightsError

            raise WeightsError("no model loaded: start the app with `lsr app --weights DIR` (see the note at the top)")
        return self.weights

    def reenactor(self, runtime: str):
        """The torch ``Reenactor`` or the ``OnnxReenactor`` (from WEIGHTS/onnx, made by ``lsr export``)."""
        weights = self._require_weights()
        detector = self.detector
        with self._lock:
            if runtime == "onnx":
                if self._onnx is None:
                    from deploy.runtime import OnnxReenactor
                    from lsr.export.find_bundle import onnx_bundle_folder

                    self._onnx = OnnxReenactor(onnx_bundle_folder(weights), detector=detector)
                return self._onnx
            if self._torch is None:
                from lsr.pipeline import Reenactor
                from lsr.devices import resolve_device

                self._torch = Reenactor(weights, device=resolve_device(self.device), detector=detector)
            return self._torch

    def live_reenactor(self):
        """The live tab's ``OnnxReenactor``: one network thread, so that the next camera frame's tracking and warps
        run beside it on the other core (``LiveStream.step``); shared by every live stream."""
        weights = self._require_weights()
        detector = self.detector
        with self._lock:
            if self._live is None:
                from deploy.runtime import OnnxReenactor
                from lsr.export.find_bundle import onnx_bundle_folder

                self._live = OnnxReenactor(onnx_bundle_folder(weights), detector=detector, threads=LIVE_NETWORK_THREADS)
            return self._live

    @contextlib.contextmanager
    def finetuned(self, reenactor, steps: int) -> Iterator[float | None]:
        """Fine-tune a copy of the generators for this run only (thesis §4.3.5); yields seconds spent (None if 0 steps)."""
        if steps <= 0:
            yield None
            return
        from lsr.train.finetune import finetuned

        started = time.perf_counter()
        with finetuned(reenactor, steps, progress=True):  # the shared base model is back after the run
            yield time.perf_counter() - started


class SessionFiles:
    """Per-session temp folders under one root: each run gets a fresh folder, the previous one is removed."""

    def __init__(self, root: Path | None = None) -> None:
        self.root = Path(root) if root is not None else Path(tempfile.mkdtemp(prefix="lsr-app-"))
        self.root.mkdir(parents=True, exist_ok=True)

    def new_run(self, session: str | None) -> Path:
        session_dir = self.root / _safe_name(session or "anonymous")
        if session_dir.is_dir():
            for old in session_dir.iterdir():
                if not old.name.startswith("keep-"):
                    shutil.rmtree(old, ignore_errors=True)
        run = session_dir / f"run-{uuid.uuid4().hex[:12]}"
        run.mkdir(parents=True)
        return run

    def folder(self, session: str | None, name: str) -> Path:
        """A named folder of the session that runs leave alone (e.g. a saved pose), removed with the session."""
        folder = self.root / _safe_name(session or "anonymous") / f"keep-{_safe_name(name)}"
        folder.mkdir(parents=True, exist_ok=True)
        return folder

    def drop(self, session: str | None) -> None:
        shutil.rmtree(self.root / _safe_name(session or "anonymous"), ignore_errors=True)

    def drop_all(self) -> None:
        shutil.rmtree(self.root, ignore_errors=True)


def _safe_name(text: str) -> str:
    return "".join(c for c in text if c.isalnum() or c in "-_")[:64] or "anonymous"


@contextlib.contextmanager
def readable_errors(what: str) -> Iterator[None]:
    """Typed library errors -> ``gr.Error`` with their message; anything else -> a short message + a server log."""
    import gradio as gr

    from landmarks.exceptions import LandmarksError, NoFaceError
    from lsr.errors import LsrError

    try:
        yield
    except gr.Error:
        raise
    except NoFaceError as exc:
        raise gr.Error(user_facing(str(exc)), title="No face found", print_exception=False) from exc
    except (LsrError, LandmarksError) as exc:
        raise gr.Error(user_facing(str(exc)), title=f"Cannot {what}", print_exception=False) from exc
    except Exception as exc:  # a bug, not user input: keep the page usable, log the traceback
        LOG.exception("unexpected error while trying to %s", what)
        raise gr.Error(f"{type(exc).__name__}: {user_facing(str(exc))} (an internal error; the server log has the "
                       "details)", title=f"Cannot {what}") from exc


_SERVER_PATH = re.compile(r"(?:/[^\s/:;,'\"()]+)+/([^\s/:;,'\"()]+)")


def user_facing(message: str) -> str:
    """A message for the page: server paths (upload temp folders, the cache) shortened to the file's own name,
    which is the name the user uploaded."""
    return _SERVER_PATH.sub(r"\1", message)


# ---- inputs ----------------------------------------------------------------------------------------------


def upload_paths(files) -> list[Path]:
    """gr.File values (str paths, or objects with .name) -> paths."""
    if files is None:
        return []
    items = files if isinstance(files, (list, tuple)) else [files]
    # str / PathLike from type="filepath"; objects with a .name (temp-file wrappers) from older clients
    return [Path(item) if isinstance(item, (str, os.PathLike)) else Path(item.name) for item in items if item]


def check_upload_size(path: Path, limits: Limits) -> None:
    from landmarks.exceptions import InputFileError

    megabytes = path.stat().st_size / 1e6
    if megabytes > limits.max_upload_mb:
        raise InputFileError(f"{path.name} is {megabytes:.1f} MB; the limit is {limits.max_upload_mb:g} MB "
                             "(a shorter or smaller file, or start the app with a larger --max-upload-mb)")


def check_driver(driver: Path, limits: Limits):
    """``describe_driver`` plus the app's length limits; returns the ``DriverInfo``."""
    from lsr.core.inputs import describe_driver
    from landmarks.exceptions import InputFileError

    check_upload_size(driver, limits)
    info = describe_driver(driver)
    seconds = info.frames / info.fps
    if info.kind == "video" and seconds > limits.max_video_seconds:
        raise InputFileError(f"the driver video is {seconds:.1f} s long; this app accepts up to "
                             f"{limits.max_video_seconds:g} s (trim it, or use `lsr reenact` for long videos)")
    if info.frames > limits.max_video_frames:
        raise InputFileError(f"the driver has {info.frames} frames; this app accepts up to {limits.max_video_frames} "
                             "(trim it, or use `lsr reenact` for long inputs)")
    return info


def load_shots(files: Sequence, k: int, size: int, detector, limits: Limits):
    """Uploaded images (1..32, each one shot) or one video (sampled) -> (``SubjectShots`` of <= k crops, notes).

    Images without a face are skipped and named in the notes (an error only when none has a face).
    """
    from lsr.core.inputs import (DEFAULT_K, SubjectShots, load_subject_shots, of_the_person, set_anchor,
                                  cover_shots)
    from landmarks.exceptions import InputFileError, NoFaceError
    from landmarks.io.image_files import IMAGE_SUFFIXES
    from landmarks.io.video import VIDEO_SUFFIXES, probe_video

    paths = upload_paths(files)
    if not paths:
        raise InputFileError("no source yet: upload 1-32 photos of one person (or a short video), or load the example")
    if not 1 <= int(k) <= limits.max_k:
        raise InputFileError(f"K must be in 1..{limits.max_k}, got {k}")
    for path in paths:
        check_upload_size(path, limits)
    videos = [p for p in paths if p.suffix.lower() in VIDEO_SUFFIXES]
    others = [p for p in paths if p.suffix.lower() not in VIDEO_SUFFIXES + IMAGE_SUFFIXES]
    if others:
        raise InputFileError(f"unsupported source file {others[0].name}: upload images ({', '.join(IMAGE_SUFFIXES)}) "
                             f"or one video ({', '.join(VIDEO_SUFFIXES)})")
    if videos:
        if len(paths) > 1:
            raise InputFileError("upload either images or one video as the source, not both / several videos")
        info = probe_video(videos[0])
        if info.frames / info.fps > limits.max_video_seconds:
            raise InputFileError(f"the source video is {info.frames / info.fps:.1f} s long; the limit is "
                                 f"{limits.max_video_seconds:g} s: trim it or upload a few photos instead")
        # Up to DEFAULT_K the engine samples min(8, usable) shots and we thin them to K; a larger K is asked
        # for explicitly (the engine then says how many frames had a face if there are too few).
        shots = load_subject_shots(videos[0], size, k=None if k <= DEFAULT_K else int(k), detector=detector)
        if len(shots.frames) > k:
            shots = set_anchor(cover_shots(shots, int(k)))
        return shots, [f"{len(shots.frames)} shot(s) sampled from {videos[0].name}", *shots.notes]
    if len(paths) > MAX_K:
        raise InputFileError(f"{len(paths)} images uploaded; give at most {MAX_K} shots (K <= {MAX_K})")
    frames, points, names, notes = [], [], [], []
    meshes: list = []
    unreadable, full_frames = [], {}
    for path in paths:  # one image = one candidate shot; a face-less or unreadable one is skipped, not fatal
        try:
            one = load_subject_shots(path, size, detector=detector)
        except NoFaceError:
            notes.append(f"no face in {path.name}: skipped")
            continue
        except InputFileError as exc:
            unreadable.append(exc)
            notes.append(f"cannot read {path.name} as an image: skipped")
            continue
        frames.append(one.frames[0])
        points.append(one.landmarks[0])
        meshes.append(None if one.meshes is None else one.meshes[0])
        names.append(path.name)
        full_frames[path.name] = (one.anchor_frame, one.anchor_frame_landmarks)  # the scene, if it is the anchor
    if not frames:
        if len(unreadable) == len(paths):
            raise unreadable[0]
        raise NoFaceError(f"no face found in the {len(paths)} uploaded image(s); upload frontal, well-lit photos of one person")
    person, note = of_the_person(frames, points, list(range(len(frames))))  # photos of another person left out
    notes += [note] if note else []
    frames, points, names = [frames[i] for i in person], [points[i] for i in person], [names[i] for i in person]
    meshes = [meshes[i] for i in person]
    all_meshes = np.stack(meshes) if all(mesh is not None for mesh in meshes) else None
    shots = set_anchor(cover_shots(SubjectShots(np.stack(frames), np.stack(points), names, meshes=all_meshes), int(k)),
                       full_frames=full_frames)
    notes.insert(0, f"using {len(shots.frames)} of {len(frames)} shot(s) with a face of the person (K={k})")
    return shots, notes


# ---- pictures --------------------------------------------------------------------------------------------


def enlarge(image: np.ndarray, side: int = DISPLAY_SIDE) -> np.ndarray:
    """(S, S, 3) uint8 -> (side, side, 3): small model crops are shown at a readable size."""
    import cv2

    if image.shape[0] >= side:
        return image
    return cv2.resize(image, (side, side), interpolation=cv2.INTER_CUBIC)


def shot_gallery(shots) -> list[tuple[np.ndarray, str]]:
    """Each shot enlarged with its detected landmarks drawn over it, captioned with its file."""
    from landmarks.io.annotate import draw_overlay

    items = []
    for frame, points, name in zip(shots.frames, shots.landmarks, shots.names):
        big = enlarge(frame)
        scale = big.shape[0] / frame.shape[0]
        items.append((draw_overlay(big, (points + 0.5) * scale - 0.5), Path(name.split("#")[0]).name))
    return items


def labelled_panel(panel: np.ndarray, tiles: int = 4) -> np.ndarray:
    """(S, tiles*S, 3) side-by-side -> enlarged tiles under a title strip (``PANEL_TITLES``)."""
    import cv2

    side = panel.shape[0]
    big_side = max(side, DISPLAY_SIDE)
    tiles_big = [enlarge(np.ascontiguousarray(panel[:, i * side : (i + 1) * side]), big_side) for i in range(tiles)]
    strip = np.full((28, big_side * tiles, 3), 32, np.uint8)
    for i, title in enumerate(PANEL_TITLES[:tiles]):
        cv2.putText(strip, title, (i * big_side + 8, 19), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (235, 235, 235), 1, cv2.LINE_AA)
    return np.concatenate([strip, np.concatenate(tiles_big, axis=1)], axis=0)


def latent_averaging(reenactor, shots, target_landmarks: np.ndarray) -> list[tuple[np.ndarray, str]]:
    """Each shot encoded alone, then all K averaged, synthesised at one target pose (thesis Fig. 4.10, eq. 4.3).

    target_landmarks: (68, 2) crop pixels (the first driven frame's target). A warp-guided model warps the same
    nearest shots for every panel, so the panels differ by the latents only.
    """
    from lsr.core.engine import to_network
    from lsr.core.inputs import resize_shots
    from landmarks.shape.raster import draw_landmarks

    size = reenactor.resolution
    small = resize_shots(shots, size)
    landmark_images = np.stack([draw_landmarks(points, size) for points in small.landmarks])  # (K, S, S, 3)
    items = []
    for i in range(len(shots.frames)):
        latents = reenactor.backend.encode_subject(
            to_network(small.frames[i : i + 1])[None], to_network(landmark_images[i : i + 1])[None]  # (1, 1, 3, S, S)
        )
        image, _, _ = reenactor.synthesize_crop(target_landmarks, latents=latents)
        items.append((enlarge(image), f"shot {i + 1} alone"))
    image, _, _ = reenactor.synthesize_crop(target_landmarks)
    items.append((enlarge(image), f"average of K={len(shots.frames)}"))
    return items


# ---- the run ---------------------------------------------------------------------------------------------


@dataclasses.dataclass
class RunResult:
    """What one re-enactment shows on the page."""

    video: Path
    """H.264 MP4 (driver's fps and audio, provenance metadata, optional watermark)."""
    frames: int
    shots: list[tuple[np.ndarray, str]]
    averaging: list[tuple[np.ndarray, str]]
    panels_dir: Path
    """One PNG per frame: driver | landmarks | layout | output (``panel_path``)."""
    timing: str
    summary: str
    coverage: np.ndarray | None = None
    """(H, W, 3) uint8: what the shots cover of the driven frames (``landmarks.parts.coverage.coverage_picture``); None
    when no frame had a face."""


def panel_path(panels_dir: str | os.PathLike, index: int) -> Path:
    return Path(panels_dir) / f"{int(index):05d}.png"


def run_reenactment(store: ModelStore, limits: Limits, run_dir: Path, source_files, k: int, driver, *,
                    motion: str = "relative", smooth: bool = True, paste_back: bool = False, finetune_steps: int = 0,
                    runtime: str = "auto", watermark: bool = True) -> RunResult:
    """Shots -> subject latents (K-shot average) -> one output frame per driver frame, written as the app shows them.
    runtime: as ``lsr reenact --runtime`` (``lsr.config.inference.resolve_runtime``)."""
    from landmarks.parts.coverage import coverage_picture
    from landmarks.exceptions import InputFileError
    from landmarks.io.image_files import write_image
    from lsr.config.inference import resolve_runtime
    from lsr.writer import stage_table, write_reenactment

    runtime = resolve_runtime(runtime, int(finetune_steps))
    reenactor = store.reenactor(runtime)  # first: without a model nothing else matters
    driver_paths = upload_paths(driver)
    if not driver_paths:
        raise InputFileError("no driver yet: upload a video or a landmark file (.npy/.json), or pick a bundled example")
    driver = driver_paths[0]
    if motion not in ("relative", "absolute"):
        raise InputFileError(f"motion must be 'relative' or 'absolute', got {motion!r}")
    if not 0 <= int(finetune_steps) <= 1000:
        raise InputFileError(f"fine-tuning steps must be in 0..1000, got {finetune_steps}")
    info = check_driver(driver, limits)
    started = time.perf_counter()
    shots, notes = load_shots(source_files, k, reenactor.crop_size, store.detector, limits)
    shot_seconds = time.perf_counter() - started
    if runtime == "onnx" and int(finetune_steps) > 0:  # the ONNX runtime cannot train: run without, and say so
        notes.append(f"the ONNX runtime cannot fine-tune: ran without the {int(finetune_steps)} fine-tuning steps "
                     "(choose runtime 'torch' for them)")
        finetune_steps = 0
    reenactor.encode_subject(shots)
    encode_seconds = reenactor.last_stats.seconds["subject_encoding"]  # reenact() starts new stats
    kind = reenactor.backend.layout_kind
    output = run_dir / "reenacted.mp4"
    panels_dir = run_dir / "panels"
    panels_dir.mkdir()
    with store.finetuned(reenactor, int(finetune_steps)) as finetune_seconds:
        written = write_reenactment(
            reenactor, driver, output, runtime=runtime, mode=motion, smooth=smooth, paste_back=paste_back, scene="source",
            watermark=watermark, progress=True,
            panel_sink=lambda index, panel: write_image(panel_path(panels_dir, index), panel),
        )
        stats = written.stats
        notes += written.warnings
        notes += [written.coverage] if written.coverage else []
        tick = time.perf_counter()
        # no face anywhere in the driver: show the averaging at the first shot's pose
        target_landmarks = written.first_landmarks if written.first_landmarks is not None else shots.landmarks[0]
        averaging = latent_averaging(reenactor, shots, target_landmarks)
        stats.add("latent averaging", time.perf_counter() - tick)
    stats.add("shot detection", shot_seconds)
    stats.add("subject_encoding", encode_seconds)
    if finetune_seconds is not None:
        stats.add("finetune", finetune_seconds)
    if kind == "none":
        notes.append("this model variant has no layout stage: the layout panel stays black")
    if info.kind == "landmarks":
        notes.append("a landmark driver has no pictures: the 'driver frame' panel stays black")
    if info.kind == "landmarks" and paste_back:
        notes.append("a landmark driver has no frames: the face is composited into the source's anchor shot")
    audio = info.kind == "video" and info.has_audio
    notes.append(f"{stats.frames} frame(s) at {info.fps:g} fps"
                 + (f", {stats.no_face} without a face (passed through)" if stats.no_face else "")
                 + (", audio kept" if audio else ""))
    coverage = None if written.coverage_features is None else coverage_picture(*written.coverage_features)
    return RunResult(output, stats.frames, shot_gallery(shots), averaging, panels_dir, stage_table(stats),
                     "\n".join(f"- {note}" for note in notes), coverage)

