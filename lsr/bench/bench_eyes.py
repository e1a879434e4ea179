"""lsr bench eyes: the re-enacted eyes and mouth over whole driving clips, judged beside what the judges can see
(issue 63).

Each clip is the source of one pair and drives the next clip's person (the last drives the first), as
``lsr reenact`` drives it (K shots, relative motion, every frame), once per eye bank (``lsr.core.finish.BANKS``).
Every judged figure stands beside the **agreement** of the two detectors on the drivers' own frames: dlib's 68
points (the judge, ``lsr.eval.part_regions.Judge``) against the driving detector's (the face mesh); a judged correlation
means something only as a share of it.

* ``eye r`` / ``mouth r``: the correlation of the output's eye (mouth) opening with the driver's, both read by the
  judge (``landmarks.shape.expression``), and ``gain``: the output's opening's slope on the driver's
  (``lsr.eval.cross.pooled_gain``); the agreement row: the mesh's reading of the driver against the judge's.
* ``gaze r``: the iris's offset along the eye (``landmarks.parts.appearance.gaze``) in the output against the driver's,
  both in the judge's eyes; the agreement: the iris net's gaze (``landmarks.parts.eyes.iris.gaze_offsets``) against it.
* ``realism``: each output eye's distance to the nearest of the source's real eyes (``landmarks.parts.eyes.eye_realism.eye_realism``:
  1 - the best normalised cross-correlation of the eye's grey patch, cut by its corners, against every frame of
  the source video), the median over eyes and frames, over the **floor**: the same distance for the source's real
  frames, each against its frames at least ``FLOOR_GAP`` frames away. Streaked or smudged eyes lie far from every
  real eye; a frozen eye lies near, which is why realism stands beside the correlations.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lsr.config.bench_options import BenchEyesConfig

JITTER_PARTS = {"eye": slice(36, 48), "mouth": slice(48, 68)}
"""The parts whose steadiness the table reads (iBUG-68 ranges)."""
SECTION = "eyes"
COLUMNS = ("eye_r", "eye_gain", "eye_own_gain", "mouth_r", "mouth_gain", "gaze_r")
"""The judged columns, each with its share of the agreement row in brackets."""
FLOOR_GAP = 5
"""The floor compares a real frame with the source's frames at least this many frames away."""


def source_eyes(video: Path, tracker) -> np.ndarray:
    """Every frame's eyes of a source video as ``eye_realism`` compares them: (N, 2, P) float32 (NaN rows where
    no face was found, so that row i is frame i)."""
    from landmarks.parts.eyes.eye_realism import REALISM_PATCH, realism_patches
    from landmarks.io.video import iter_frames

    rows = []
    for frame in iter_frames(video):
        points = tracker.update(frame)
        rows.append(realism_patches(frame, points) if points is not None and np.isfinite(points).all() else
                    np.full((2, REALISM_PATCH[0] * REALISM_PATCH[1]), np.nan, np.float32))
    return np.stack(rows)


def realism_floor(real: np.ndarray, gap: int = FLOOR_GAP) -> np.ndarray:
    """(N, 2) each real frame's eyes against the others at least ``gap`` frames away (``eye_realism``)."""
    from landmarks.parts.eyes.eye_realism import eye_realism

    count = len(real)
    return eye_realism(real, real, [range(max(0, i - gap + 1), min(count, i + gap)) for i in range(count)])


def driver_readings(video: Path, judge, keep: np.ndarray) -> dict[str, np.ndarray]:
    """The driver's frames ``keep`` read by the mesh (the driving detector, with its iris net's gaze) and by the
    judge: mouth and eye openings and gazes, (T,) each (NaN where a detector found no face)."""
    from landmarks.parts.appearance import gaze
    from landmarks.detect.registry import make_tracker
    from landmarks.shape.expression import eye_opening, mouth_opening
    from landmarks.parts.eyes.iris import gaze_offsets
    from landmarks.io.video import iter_frames

    tracker = make_tracker("mesh")
    names = ("mesh_mouth", "mesh_eye", "mesh_gaze", "judge_mouth", "judge_eye", "judge_gaze", "judge_points")
    readings: dict[str, list] = {name: [] for name in names}
    wanted = set(int(i) for i in keep)
    for index, frame in enumerate(iter_frames(video)):
        points = tracker.update(frame)  # every frame: the track as the re-enactment's
        if index not in wanted:
            continue
        found = points is not None and np.isfinite(points).all()
        irises = getattr(tracker, "irises", None)
        along = gaze_offsets(irises, points)[:, 0] if found and irises is not None else np.full(2, np.nan)
        readings["mesh_mouth"].append(float(mouth_opening(points)) if found else math.nan)
        readings["mesh_eye"].append(float(eye_opening(points)) if found else math.nan)
        readings["mesh_gaze"].append(float(np.nanmean(along)) if np.isfinite(along).any() else math.nan)
        judged = judge.landmarks(frame, points if found else None)
        readings["judge_mouth"].append(float(mouth_opening(judged)) if judged is not None else math.nan)
        readings["judge_eye"].append(float(eye_opening(judged)) if judged is not None else math.nan)
        readings["judge_gaze"].append(float(gaze(frame, judged)[0]) if judged is not None else math.nan)
        readings["judge_points"].append(judged if judged is not None else np.full((68, 2), np.nan))
    return {name: np.asarray(values, np.float64) for name, values in readings.items()}


def output_readings(frames: list, judge, real: np.ndarray) -> dict[str, np.ndarray]:
    """The re-enacted frames (``ReenactedFrame``s, the kept ones; None where the driver had no face) read by the
    judge (openings, gaze) and their eyes' realism against the source's ``real`` eyes ((N, 2, P)); "asked_*": the
    openings of the target's own points, what the re-enactment asked the synthesis to draw."""
    from landmarks.parts.appearance import gaze
    from landmarks.parts.eyes.eye_realism import eye_realism, realism_patches
    from landmarks.shape.expression import eye_opening, mouth_opening

    readings: dict[str, list] = {"judge_mouth": [], "judge_eye": [], "judge_gaze": [], "realism": [],
                                 "judge_points": [], "asked_mouth": [], "asked_eye": []}
    for frame in frames:
        if frame is None or frame.synthesis is None:
            for name in ("judge_mouth", "judge_eye", "judge_gaze", "asked_mouth", "asked_eye"):
                readings[name].append(math.nan)
            readings["realism"].append(np.full(2, np.nan))
            readings["judge_points"].append(np.full((68, 2), np.nan))
            continue
        judged = judge.landmarks(frame.synthesis, frame.landmarks)
        readings["asked_mouth"].append(float(mouth_opening(frame.landmarks)))
        readings["asked_eye"].append(float(eye_opening(frame.landmarks)))
        readings["judge_mouth"].append(float(mouth_opening(judged)) if judged is not None else math.nan)
        readings["judge_eye"].append(float(eye_opening(judged)) if judged is not None else math.nan)
        readings["judge_gaze"].append(float(gaze(frame.synthesis, judged)[0]) if judged is not None else math.nan)
        readings["realism"].append(eye_realism(realism_patches(frame.synthesis, frame.landmarks)[None], real)[0])
        readings["judge_points"].append(judged if judged is not None else np.full((68, 2), np.nan))
    return {name: np.asarray(values, np.float64) for name, values in readings.items()}


def own_scale(openings: np.ndarray) -> np.ndarray:
    """Openings (T,) over their own median (NaN kept; all NaN where the median is not above 0): an eye as a share of
    its own usual opening, so that a narrow-eyed face that shuts as far as the driver, in proportion, has a gain of 1
    against a wide-eyed driver (relative motion moves the lids so: ``landmarks.parts.eyes.lids.lids_as_driver``)."""
    openings = np.asarray(openings, np.float64)
    usual = np.nanmedian(openings) if np.isfinite(openings).any() else math.nan
    return openings / usual if usual > 0 else np.full_like(openings, math.nan)


def steadiness(points: np.ndarray | None, prefix: str = "") -> dict[str, float]:
    """Each part's own motion (``JITTER_PARTS``; ``landmarks.motion.smooth.part_jitter``, inter-ocular distances) of
    (T, 68, 2) points read frame by frame -> {prefix + part + "_jitter": value}, NaN for no points."""
    from landmarks.motion.smooth import part_jitter

    if points is None:
        return dict.fromkeys((f"{prefix}{part}_jitter" for part in JITTER_PARTS), math.nan)
    return {f"{prefix}{part}_jitter": part_jitter(points, where) for part, where in JITTER_PARTS.items()}


def pair_rows(pair: str, driver: dict[str, np.ndarray], outputs: dict[str, dict[str, np.ndarray]], floor: float,
              source_points: np.ndarray | None = None) -> list[dict[str, Any]]:
    """The agreement row and one row per bank of one pair (the module docstring's columns). source_points: the
    judge's reading of the source's own frames (T, 68, 2), whose jitter the agreement row carries beside the
    driver's ("own_*_jitter": how steady the judge reads this face when it is real)."""
    from lsr.eval.cross import opening_correlation, pooled_gain

    def judged(part: str, reading: np.ndarray) -> tuple[float, float]:
        return (opening_correlation(driver[f"judge_{part}"], reading),
                pooled_gain([(driver[f"judge_{part}"], reading)]))

    def own_gain(reading: np.ndarray) -> float:  # the eyes' slope, each face's openings over its own median
        return pooled_gain([(own_scale(driver["judge_eye"]), own_scale(reading))])

    rows = [{"pair": pair, "row": "agreement", **{f"{part}_{what}": value for part in ("eye", "mouth")
             for what, value in zip(("r", "gain"), judged(part, driver[f"mesh_{part}"]))},
             "eye_own_gain": own_gain(driver["mesh_eye"]),
             "gaze_r": opening_correlation(driver["judge_gaze"], driver["mesh_gaze"]), "realism": floor,
             "switches": math.nan, "ms_per_frame": math.nan, **steadiness(driver.get("judge_points")),
             **steadiness(source_points, "own_")}]
    asked = next(iter(outputs.values()), None)  # every bank's target points are the same
    if asked is not None and "asked_eye" in asked:
        rows.append({"pair": pair, "row": "asked", **{f"{part}_{what}": value for part in ("eye", "mouth")
                     for what, value in zip(("r", "gain"), judged(part, asked[f"asked_{part}"]))},
                     "eye_own_gain": own_gain(asked["asked_eye"]),
                     "gaze_r": math.nan, "realism": math.nan, "switches": math.nan, "ms_per_frame": math.nan,
                     **steadiness(None)})
    for bank, reading in outputs.items():
        row = {"pair": pair, "row": bank}
        for part in ("eye", "mouth"):
            row[f"{part}_r"], row[f"{part}_gain"] = judged(part, reading[f"judge_{part}"])
        row["eye_own_gain"] = own_gain(reading["judge_eye"])
        row["gaze_r"] = opening_correlation(driver["judge_gaze"], reading["judge_gaze"])
        row["realism"] = float(np.nanmedian(reading["realism"])) if np.isfinite(reading["realism"]).any() else math.nan
        row["switches"] = float(reading.get("switches", math.nan))
        row["ms_per_frame"] = float(reading.get("ms_per_frame", math.nan))
        row.update(steadiness(reading.get("judge_points")))
        rows.append(row)
    return rows


def eyes_markdown(rows: list[dict[str, Any]], settings: dict[str, Any], machine: str) -> str:
    """Per pair: the agreement row (the two detectors on the driver's frames; realism: the source's real frames'
    floor), then per bank the judged columns and, in brackets, their share of the agreement (gains: their ratio)."""
    lines = [f"clips: {settings['clips']}; K = {settings['k']}; model `{settings['weights']}`; judged frames per "
             f"driver: {settings['frames']}", "",
             "| pair | eyes from | eye r | eye gain | eye gain, own opening | mouth r | mouth gain | gaze r | realism ↓ "
             "(x floor) | switches | ms / frame | eye jitter (x driver, x own) | mouth jitter (x driver, x own) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    agreement: dict[str, Any] = {}
    for row in rows:
        if row["row"] == "agreement":
            agreement = row
            cells = [f"{row.get(c, math.nan):.2f}" for c in COLUMNS]
            jitters = " | ".join(_own(f"{row.get(f'{part}_jitter', math.nan):.4f}", row.get(f"own_{part}_jitter"))
                                 for part in JITTER_PARTS)
            lines.append(f"| {row['pair']} | agreement / floor | {' | '.join(cells)} | {row['realism']:.3f} | | | "
                         f"{jitters} |")
            continue
        cells = [share(row.get(c, math.nan), agreement.get(c, math.nan)) for c in COLUMNS]
        realism = share(row["realism"], agreement.get("realism", math.nan), digits=3)
        switches = "" if not math.isfinite(row["switches"]) else f"{row['switches']:.0f}"
        speed = "" if not math.isfinite(row.get("ms_per_frame", math.nan)) else f"{row['ms_per_frame']:.0f}"
        jitters = " | ".join(share(row.get(f"{part}_jitter", math.nan), agreement.get(f"{part}_jitter", math.nan),
                                   agreement.get(f"own_{part}_jitter", math.nan), digits=4) for part in JITTER_PARTS)
        lines.append(f"| | {row['row']} | {' | '.join(cells)} | {realism} | {switches} | {speed} | {jitters} |")
    lines += ["", "agreement: the face mesh's reading of the driver's frames against dlib's (the judge); asked: the "
              "target's own points (what the re-enactment asks the synthesis to draw; its lids' small motions "
              "multiplied for the warps) against the judge's reading of the driver; eye gain, own opening: the gain with "
              "each face's eye openings over its own median (relative motion shuts a narrow eye in proportion); each bank's "
              "row: the output against the driver, both read by dlib, and in brackets its share of the agreement. "
              "realism: the median distance of the output's eyes to the nearest of the source's real eyes "
              "(1 - NCC), the floor that of the source's real frames to its frames at least "
              f"{FLOOR_GAP} frames away; switches: how often the bank's eye entry changed; ms / frame: the "
              "re-enactment's wall time per driver frame (the banks built before, once per source); jitter: each part's "
              "own frame-to-frame motion (its points' less the face's, dlib's reading, in inter-ocular distances; "
              "``landmarks.motion.smooth.part_jitter``), the driver's in the agreement row, each bank's against it in "
              "brackets (the issue's bar: at most the driver's), then against the source's own (the judge's reading of "
              "the source's real frames, where its clip drives: how steady the judge reads this face when nothing is "
              "synthesised).", "", machine]
    return "\n".join(lines)


def _own(shown: str, own: float | None) -> str:
    """The agreement row's jitter cell: the driver's, and the source's own beside it where known."""
    return f"{shown} (own {own:.4f})" if own is not None and math.isfinite(own) else shown


def share(value: float, *of: float, digits: int = 2) -> str:
    """A bank row's cell: the value, and in brackets its ratio to each of ``of`` that is known and not 0 (the
    agreement's; for jitter, the driver's then the source's own); "–" for an unknown value."""
    if not math.isfinite(value):
        return "–"
    ratios = [f"{value / by:.2f}" for by in of if math.isfinite(by) and by]
    return f"{value:.{digits}f} ({', '.join(ratios)})" if ratios else f"{value:.{digits}f}"


def _zoom(image: np.ndarray, points: np.ndarray, part: slice, width: int, height_share: float) -> np.ndarray:
    """The box around ``points[part]`` (grown along by half, ``height_share`` of its width tall), ``width`` wide."""
    centre, half = points[part].mean(axis=0), max(8.0, float(np.ptp(points[part, 0])) * 0.75)
    x0, y0 = (max(0, int(v)) for v in centre - (half, half * height_share))
    cut = image[y0:int(centre[1] + half * height_share), x0:int(centre[0] + half)]
    return cv2.resize(cut, (width, max(1, round(width * cut.shape[0] / max(1, cut.shape[1])))),
                      interpolation=cv2.INTER_CUBIC)


def figure_row(driver_frame: np.ndarray, outputs: list, width: int = 256) -> np.ndarray:
    """One moment: the driver frame | each bank's output crop, each over its eyes and its mouth zoomed (RGB)."""
    tiles = [cv2.resize(driver_frame, (width, round(width * driver_frame.shape[0] / driver_frame.shape[1])),
                        interpolation=cv2.INTER_AREA)]
    for frame in outputs:
        image, points = frame.synthesis, frame.landmarks
        tiles.append(np.vstack([cv2.resize(image, (width, width), interpolation=cv2.INTER_AREA),
                                _zoom(image, points, slice(36, 48), width, 0.45),
                                _zoom(image, points, slice(48, 68), width, 0.6)]))
    height = max(tile.shape[0] for tile in tiles)
    return np.hstack([np.pad(t, ((0, height - t.shape[0]), (0, 0), (0, 0))) for t in tiles])


def run_bench_eyes(cfg: BenchEyesConfig) -> list[dict[str, Any]]:
    """Entry point of ``lsr bench eyes``: print the table (with --out-md, also its BENCHMARKS.md section)."""
    import torch
    from tqdm import tqdm

    from landmarks.detect.registry import make_tracker
    from landmarks.io.image_files import write_image
    from landmarks.io.video import probe_video
    from lsr.eval.part_regions import Judge
    from lsr.eval.sections import publish
    from lsr.eval.machine import machine_markdown, shown_path
    from lsr.pipeline import Reenactor
    from lsr.weights import resolve_weights

    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    clips = cfg.resolved_clips()
    weights = resolve_weights(cfg.weights)
    reenactor, judge = Reenactor(weights), Judge()
    rows: list[dict[str, Any]] = []
    measured = []  # per pair: (source, driver, the driver's readings, each bank's output readings, the floor)
    figure: list[np.ndarray] = []
    frames_judged = []
    pairs = [(clips[i], clips[(i + 1) % len(clips)]) for i in range(len(clips))]
    for source, driver in tqdm(pairs, desc="eyes", unit="pair", disable=not cfg.progress):
        total = probe_video(driver).frames
        keep = (np.arange(total) if not cfg.max_frames or cfg.max_frames >= total
                else np.linspace(0, total - 1, cfg.max_frames).round().astype(int))
        frames_judged.append(len(keep))
        driver_read = driver_readings(driver, judge, keep)
        real = source_eyes(source, make_tracker("mesh"))
        floor = float(np.nanmedian(realism_floor(real)))
        reenactor.encode_subject(source, k=cfg.k)
        wanted = set(int(i) for i in keep)
        outputs, kept_frames = {}, {}
        for bank in cfg.banks:
            reenactor.bank, reenactor.bank_parts = bank.split("+")[0], "both" if bank.endswith("+mouth") else "eyes"
            track = []
            frames = []
            if reenactor.bank != "none":
                reenactor.subject.part_banks(reenactor.bank, reenactor.detector)  # built once per source, untimed
            started = time.perf_counter()
            for frame in reenactor.reenact(driver):
                if frame.index in wanted:
                    frames.append(frame if frame.has_face else None)
                choice = frame.eye_choice
                track.append(None if choice is None else choice.entry)
            seconds = time.perf_counter() - started  # the re-enactment alone (the bank built before, on encoding)
            outputs[bank] = output_readings(frames, judge, real)
            outputs[bank]["ms_per_frame"] = 1e3 * seconds / max(1, len(track))
            outputs[bank]["switches"] = (sum(a != b and a is not None and b is not None for a, b in zip(track, track[1:]))
                                         if bank != "none" else math.nan)
            kept_frames[bank] = frames
        measured.append((source, driver, driver_read, outputs, floor))
        if cfg.figure is not None:
            figure += _moments(driver_read, kept_frames)
    # each clip drives once: the judge's reading of it then is its own real frames' (the steadiness it reads there)
    as_driver = {driver: read.get("judge_points") for _, driver, read, _, _ in measured}
    for source, driver, driver_read, outputs, floor in measured:
        rows += pair_rows(f"{_short(source.stem)} ← {_short(driver.stem)}", driver_read, outputs, floor,
                          as_driver.get(source))
    settings = {"clips": ", ".join(shown_path(c) for c in clips[:1]) + (f" and {len(clips) - 1} more" if len(clips) > 1
                                                                        else ""),
                "k": cfg.k, "weights": shown_path(weights), "frames": f"{min(frames_judged)}-{max(frames_judged)}"}
    text = eyes_markdown(rows, settings, machine_markdown())
    publish(cfg, "lsr bench eyes", f"{SECTION}_{cfg.set_name}",
            f"The eyes and mouth over whole driving clips: {cfg.set_name} (`lsr bench eyes`)", text)
    if cfg.figure is not None and figure:
        width = max(row.shape[1] for row in figure)
        write_image(cfg.figure, np.vstack([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in figure]))
        print(f"figure written to {cfg.figure}")
    return rows


def _short(name: str, keep: int = 30) -> str:
    """A clip's name for the table: whole, or its start and its end around an ellipsis (the ends tell clips of one
    repository apart)."""
    return name if len(name) <= keep else f"{name[:keep // 2 - 1]}…{name[-(keep // 2):]}"


def mouth_roundness(points: np.ndarray) -> np.ndarray:
    """(T,) how round each open mouth is, an "O": its inner lips' gap (``mouth_opening``'s) over their width ((T, 68,
    2) points, NaN rows kept); NaN for a mouth opened less than ``O_OPENING``."""
    from landmarks.shape.expression import mouth_opening
    from landmarks.shape.measures import inter_ocular_distance

    points = np.asarray(points, np.float64)
    opening = mouth_opening(points)
    with np.errstate(divide="ignore", invalid="ignore"):
        round_ = opening * inter_ocular_distance(points) / np.linalg.norm(points[:, 64] - points[:, 60], axis=-1)
    return np.where(opening >= O_OPENING, round_, np.nan)


O_OPENING = 0.15
"""A mouth counts as an "O" in the figure only when opened at least this far (inter-ocular distances)."""


def _moments(read: dict[str, np.ndarray], frames: dict[str, list]) -> list[np.ndarray]:
    """The driver's widest and most shut eyes, its most aside gaze, its widest mouth and its roundest open mouth (an
    "O", where it opens one): one figure row each, the driver frame the re-enactment carried
    (``ReenactedFrame.driver_frame``) beside each bank's output."""
    picks = []
    read = {**read, "judge_round": mouth_roundness(read["judge_points"])}
    for name, pick in (("judge_eye", np.nanargmax), ("judge_eye", np.nanargmin), ("judge_gaze", None),
                       ("judge_mouth", np.nanargmax), ("judge_round", np.nanargmax)):
        values = read[name]
        usable = np.isfinite(values) & np.array([all(f[i] is not None for f in frames.values())
                                                 for i in range(len(values))])
        if not usable.any():
            continue
        values = np.where(usable, values, np.nan)
        picks.append(int(np.nanargmax(np.abs(values - np.nanmedian(values))) if pick is None else pick(values)))
    first = next(iter(frames.values()))
    return [figure_row(first[p].driver_frame, [f[p] for f in frames.values()]) for p in picks]
