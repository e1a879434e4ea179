"""The one writer of a re-enacted video, for ``lsr reenact`` and the app: the frames of the inference core
(``lsr.core.engine``) written as H.264 with the driver's fps and audio, provenance tags, the side-by-side panels
(driver | landmarks | layout | output), and the stage table of a run. The CLI and the app call it; neither imports
the other.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from pathlib import Path

import cv2
import numpy as np

from landmarks.parts.coverage import describe
from lsr import __version__
from lsr.core.engine import STAGES, ReenactorBase, ReenactStats, square_resize
from lsr.core.inputs import coverage_features, describe_driver
from lsr.core.provenance import draw_watermark, provenance_metadata
from lsr.errors import LsrError


# ---- side-by-side -----------------------------------------------------------------------------------------


def layout_panel(layout: np.ndarray | None, kind: str, size: int, legend: list[str] | None = None) -> np.ndarray:
    """(C_l, S, S) layout -> (size, size, 3) uint8, enlarged without blur: argmax class colours for segmentations;
    a latent layout as parts (each pixel's strongest channel in a fixed colour, ``lsr.layout_view.layout_parts_rgb``)
    with a legend of the channels it shows (``legend``: the model's channel names, ``load_layout_legend``)."""
    if layout is None:
        return np.zeros((size, size, 3), np.uint8)
    from lsr.layout_view import draw_layout_legend, layout_parts_rgb

    if kind == "segmentation":
        from lsr.data.classes import colorize_segmentation

        rgb = colorize_segmentation(layout.argmax(axis=0).astype(np.uint8))
    else:
        rgb = layout_parts_rgb(layout)
    panel = cv2.resize(rgb, (size, size), interpolation=cv2.INTER_NEAREST)
    return panel if kind == "segmentation" else draw_layout_legend(panel, layout, legend)


SIDE_BY_SIDE_MIN_PANEL = 256


def side_by_side_frame(frame, kind: str, size: int, legend: list[str] | None = None) -> np.ndarray:
    """driver | landmarks | latent layout | output, each an (S, S) panel (``legend``: see ``layout_panel``)."""
    blank = np.zeros((size, size, 3), np.uint8)
    driver = blank if frame.driver_frame is None else square_resize(frame.driver_frame, size)
    landmarks = blank if frame.landmark_image is None else frame.landmark_image
    output = frame.image if frame.image.shape[:2] == (size, size) else square_resize(frame.image, size)
    panels = [driver, landmarks, layout_panel(frame.layout, kind, max(size, SIDE_BY_SIDE_MIN_PANEL), legend), output]
    # the network's panels (landmarks, layout) are at the model resolution, the crop may be larger (warp_guided)
    panels = [p if p.shape[0] == size else cv2.resize(p, (size, size), interpolation=cv2.INTER_NEAREST) for p in panels]
    if size < SIDE_BY_SIDE_MIN_PANEL:  # low-resolution models: enlarge so the panels stay legible
        panels = [cv2.resize(p, (SIDE_BY_SIDE_MIN_PANEL,) * 2, interpolation=cv2.INTER_NEAREST) for p in panels]
    return np.concatenate(panels, axis=1)


# ---- running ----------------------------------------------------------------------------------------------


@dataclasses.dataclass
class WrittenVideo:
    """What ``write_reenactment`` wrote: the run's stats, warnings for the user, and the first driven landmarks."""

    stats: ReenactStats
    warnings: list[str]
    first_landmarks: np.ndarray | None
    """(68, 2) crop pixels of the first frame with a face (None: no face in any frame)."""
    coverage_features: tuple[np.ndarray, np.ndarray] | None = None
    """What the shots and the driven frames show (``lsr.core.inputs.coverage_features``), for a picture of it
    (``landmarks.parts.coverage.coverage_picture``); None: no face."""

    @property
    def coverage(self) -> str | None:
        """One line on how much of the driver lies beyond the shots (``landmarks.parts.coverage.describe``; None: no face)."""
        return None if self.coverage_features is None else describe(*self.coverage_features)


def write_reenactment(reenactor: ReenactorBase, driver, output: Path, *, runtime: str, mode: str = "auto",
                      smooth: bool = True, paste_back: bool = False, scene: str = "source", watermark: bool = False,
                      fps: float | None = None,
                      landmark_space=None, landmark_size: int | None = None, progress: bool = False,
                      side_by_side: Path | None = None, panel_sink=None, retarget: str = "2d") -> WrittenVideo:
    """The one writer of a re-enacted video, for ``lsr reenact`` and the app. The subject must be encoded.

    Writes ``output`` (and ``side_by_side``) atomically with the driver's fps and audio, provenance metadata and,
    with ``watermark``, the visible mark; ``panel_sink(index, panel)`` receives each side-by-side panel (driver |
    landmarks | layout | output, unmarked). A landmark or image-folder driver that yields another number of frames
    than it has is an error; a video that decodes fewer frames than it declares (a cut file) is a warning.
    """
    from landmarks.io.video import VideoWriter
    from lsr.core.overlap import Drain

    info = describe_driver(driver, fps=fps)
    metadata = provenance_metadata(__version__, runtime)
    audio = driver if info.kind == "video" and info.has_audio else None
    with_layout = side_by_side is not None or panel_sink is not None
    frames = reenactor.reenact(driver, mode=mode, smooth=smooth, paste_back=paste_back, scene=scene, retarget=retarget,
                               with_layout=with_layout,
                               landmark_space=landmark_space, landmark_size=landmark_size, progress=progress)
    first_landmarks, driven = None, []
    kind, size = reenactor.backend.layout_kind, reenactor.crop_size
    legend = None
    if with_layout:  # layout_view imports torch: a run without the side-by-side on onnxruntime never does
        from lsr.layout_view import load_layout_legend

        legend = load_layout_legend(getattr(reenactor, "weights_path", None))
    encoded = [0.0]

    def encode(frame) -> None:  # on the encoding thread, in frame order, behind the synthesis
        started = time.perf_counter()
        writer.write(draw_watermark(frame.image) if watermark else frame.image)
        encoded[0] += time.perf_counter() - started
        if with_layout:
            panel = side_by_side_frame(frame, kind, size, legend)
            if sbs_writer is not None:
                sbs_writer.write(draw_watermark(panel) if watermark else panel)
            if panel_sink is not None:
                panel_sink(frame.index, panel)

    with contextlib.ExitStack() as stack:
        writer = stack.enter_context(VideoWriter(output, info.fps, audio_from=audio, metadata=metadata))
        sbs_writer = None
        if side_by_side is not None:
            sbs_writer = stack.enter_context(VideoWriter(side_by_side, info.fps, audio_from=audio, metadata=metadata))
        stack.callback(frames.close)  # stopped early (an error, Ctrl-C): the stages' threads stop before the writers
        with Drain(encode) as drain:  # closed (every frame written) before the writers
            for frame in frames:
                if frame.landmarks is not None:
                    first_landmarks = frame.landmarks if first_landmarks is None else first_landmarks
                    driven.append(frame.landmarks)
                drain.put(frame)
        encode_seconds = encoded[0]
        stats = reenactor.last_stats
        if stats.frames != info.frames and info.kind != "video":
            raise LsrError(f"{driver}: produced {stats.frames} frames for {info.frames} driver frames")
        started = time.perf_counter()
    stats.add("encode", encode_seconds + time.perf_counter() - started)  # includes the final flush and audio mux
    warnings = []
    if info.kind == "video" and stats.frames < info.frames:
        warnings.append(f"warning: {Path(driver).name}: decoded {stats.frames} of its {info.frames} declared frames "
                        "(truncated file?); the output has the decoded ones")
    features = coverage_features(reenactor.subject.shots, np.stack(driven), size) if driven else None
    return WrittenVideo(stats, warnings, first_landmarks, features)


# Stages that run once per subject or run, not per frame (their rate is not shown).
ONCE_PER_RUN = ("shot detection", "subject_encoding", "finetune", "latent averaging")


def stage_table(stats: ReenactStats) -> str:
    """Markdown table of seconds per stage (``lsr.core.engine.STAGES``, fine-tuning, encode and any added stage),
    with frames per second for the per-frame ones: the one stage table of ``lsr reenact`` and the app."""
    rows = ["| stage | seconds | fps (frames / stage seconds) |", "|---|---|---|"]
    ordered = (*STAGES[:3], "finetune", *STAGES[3:], "encode")
    for stage in (*ordered, *(s for s in stats.seconds if s not in ordered)):
        seconds = stats.seconds.get(stage, 0.0)
        per_frame = seconds > 0 and stage not in ONCE_PER_RUN
        rows.append(f"| {stage} | {seconds:.2f} | {f'{stats.frames / seconds:.1f}' if per_frame else '–'} |")
    return "\n".join(rows)
