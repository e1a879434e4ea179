"""lsr bench plate: how well the scene plate's fill guesses the background beside a person (``landmarks.scene.compositing``'s
``background_plate``, ``PLATE_TRUST``).

What a moved head uncovers is drawn from the plate: the background with the person filled in from around. Its
truth is never seen, so the bench hides a band of real background just outside the person (beyond the plate's
own margin, ``PERSON_REACH``), fills it as the plate fills the person (``fill_in`` at each trust) and compares the
fill with the real pixels there, beside the head (above the chin). One frame of the first clip of each person, at
most ``PLATE_SIDE`` pixels wide and high (the size the plate is filled at).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lsr.config.bench_options import BenchPlateConfig

SECTION = "plate"


def band_errors(frame: np.ndarray, landmarks: np.ndarray, matte: np.ndarray, trusts: tuple[float, ...],
                band: float = 0.08) -> dict[float, float] | None:
    """Mean absolute error (grey levels, all channels) of the fill in a band ``band`` face sides wide just outside
    the person, beside the head, per trust; None where the band holds under 50 background pixels. frame: (H, W, 3)
    uint8; landmarks: (68, 2) frame pixels; matte: (H, W) float32 in [0, 1]."""
    from landmarks.scene.compositing import face_side, fill_in, plate_hole

    person = plate_hole(matte, landmarks)  # what the plate fills: the band lies just beyond it
    width = max(2, round(band * face_side(landmarks)))
    grown = cv2.dilate(person, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * width + 1, 2 * width + 1)))
    hidden = (grown > 0) & (person == 0) & (matte < 0.02)  # sure background
    hidden[int(math.ceil(landmarks[8, 1])):] = False  # beside the head: where its motion uncovers background
    if hidden.sum() < 50:
        return None
    image = frame.astype(np.float32)
    known = (1 - grown).astype(np.float32)
    return {trust: float(np.abs(fill_in(image, known, trust)[hidden] - image[hidden]).mean()) for trust in trusts}


def first_clips(root: Path) -> list[tuple[str, Path]]:
    """(person, clip) for the first clip of each person under ``root``, as ``lsr prepare`` finds them
    (``lsr.data.prepare.discover_sources``)."""
    from lsr.data.prepare import discover_sources

    found: dict[str, Path] = {}
    for source in discover_sources(root):
        if source.kind == "video":
            found.setdefault(source.identity, source.path)
    return sorted(found.items())


def _frame(clip: Path, index: int) -> np.ndarray | None:
    """Frame ``index`` of a clip (its last where it is shorter), upright (``landmarks.io.video.iter_frames``)."""
    import itertools

    from landmarks.io.video import iter_frames

    frame = None
    for frame in itertools.islice(iter_frames(clip), index + 1):
        pass
    return frame


def plate_markdown(errors: dict[float, list[float]], people: int, settings: dict[str, Any], machine: str) -> str:
    """The table: per trust, the people measured and the mean and median band error; the shipped trust marked."""
    from landmarks.scene.compositing import PLATE_TRUST

    lines = [f"data: `{settings['data']}` ({people} people, frame {settings['frame']} of each first clip, at most "
             f"{settings['side']} px); band: {settings['band']:g} face sides beyond the plate's margin, beside the "
             "head; error: mean absolute difference from the real background, grey levels", "",
             "| trust | people | mean error ↓ | median error ↓ |", "|---|---|---|---|"]
    for trust, values in errors.items():
        shipped = " (shipped)" if trust == PLATE_TRUST else ""
        lines.append(f"| {trust:g}{shipped} | {len(values)} | {np.mean(values):.2f} | {np.median(values):.2f} |")
    lines += ["", "trust 1 is the plain push-pull: a pyramid level's mean is taken only where all of its footprint is "
              "known; a larger trust carries the nearest background further into the hole.", "", machine]
    return "\n".join(lines)


def run_bench_plate(cfg: BenchPlateConfig) -> dict[float, list[float]]:
    """Entry point of ``lsr bench plate``: print the table (with --out-md, also its BENCHMARKS.md section)."""
    from tqdm import tqdm

    from landmarks.detect.mediapipe_tracker import MeshTracker
    from landmarks.scene.compositing import PLATE_SIDE
    from landmarks.scene.person_matte import person_matte
    from lsr.eval.sections import publish
    from lsr.eval.machine import machine_markdown, shown_path

    clips = first_clips(cfg.resolved_data())
    clips = clips[: cfg.max_people] if cfg.max_people else clips
    errors: dict[float, list[float]] = {trust: [] for trust in cfg.trusts}
    for _, clip in tqdm(clips, desc="plate", unit="person", disable=not cfg.progress):
        frame = _frame(clip, cfg.frame)
        if frame is None:
            continue
        scale = PLATE_SIDE / max(frame.shape[:2])
        if scale < 1:
            frame = cv2.resize(frame, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        landmarks = MeshTracker().update(frame)
        if landmarks is None:
            continue
        found = band_errors(frame, landmarks.astype(np.float64), person_matte(frame), cfg.trusts, cfg.band)
        for trust, value in (found or {}).items():
            errors[trust].append(value)
    people = len(next(iter(errors.values())))
    settings = {"data": shown_path(cfg.resolved_data()), "frame": cfg.frame, "side": PLATE_SIDE, "band": cfg.band}
    text = plate_markdown(errors, people, settings, machine_markdown())
    publish(cfg, "lsr bench plate", SECTION, "The scene plate's fill beside the person (`lsr bench plate`)", text)
    return errors
