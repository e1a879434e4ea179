"""``lsr bench lids``: how far the synthesised lids follow the lids they are asked for (issue 40: eyes that shut and
open as the driver's).

The cross-identity eye correlation of ``lsr eval`` mixes three things: how the driver's lids are retargeted onto the
source, how far the synthesis moves the lids it is given, and how the judge reads what is drawn. This bench takes
the middle one alone, on real people, with no driver: each identity's hold-outs are re-enacted with their upper
lids set (``landmarks.parts.eyes.lids.set_lid_gaps``, on the 68 points and the mesh alike) to a range of aperture shares of
the K shots' own lids at rest (``BenchLidsConfig.shares``: 0 shut, 1 as open as the shots, 1.5 wider; the aperture
is the lid gap less the closed gap, ``lids.closed_gaps``), and each output is read twice:

* by the driving detector (the mesh's 68 points), as an aperture share against the same rest
  (``landmarks.parts.eyes.driver_lids.aperture_share``). Synthesis that follows reads back each share it was asked for. The
  first warped shot (``landmarks.warp.piecewise_affine.warp_references_mesh``, before the network and the drawn lids) is read
  too, so the table says whether the motion is lost in the warp or after it. The slopes are pooled over the
  hold-outs (one intercept per hold-out), for closing (shares up to 1) and opening (from 1 on);
* by the judge (dlib's 68 points, ``lsr.eval.part_regions.Judge``), as an eye opening (``landmarks.shape.expression.eye_opening``).
  Its slope on the asked opening (pooled as above) is set against its slope on the identities' real frames, read by
  both detectors (one intercept per identity): 1 = the judge reads the synthesised lids' motion as far as it reads
  real lids'. The judged eye gain of ``lsr eval`` cannot pass this ratio for long.

The K shots are drawn as ``lsr eval`` draws them (``sample_shots``), the hold-outs evenly among those with a face.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lsr.config import BenchLidsConfig

SECTION = "lids"
CROP = (0.35, 0.3)
"""The figure's eye strip: the eye corners' box grown by these fractions of the eye distance (across, up and down)."""


@dataclasses.dataclass
class LidSweep:
    """What ``sweep`` read. Arrays are (identities, hold-outs, shares), NaN where no face was read."""

    identities: list[str]
    shares: np.ndarray
    reference: np.ndarray
    """The first warped shot's aperture share, read by the driving detector."""
    output: dict[str, np.ndarray]
    """Per ``--lids`` choice, the output's aperture share, read by the driving detector."""
    asked_opening: np.ndarray
    """``eye_opening`` of the landmarks asked for."""
    judged_opening: dict[str, np.ndarray]
    """Per ``--lids`` choice, ``eye_opening`` of the judge's landmarks of the output."""
    real: list[np.ndarray]
    """Per identity, (frames, 2): ``eye_opening`` of its real frames by the driving detector and by the judge."""
    strips: dict[str, list[np.ndarray]]
    """Per ``--lids`` choice, per identity, the first hold-out's eyes at every share side by side (the figure)."""


def lid_targets(landmarks: np.ndarray, mesh: np.ndarray, rest: np.ndarray, mesh_rest: np.ndarray,
                shares: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """A hold-out's 68 points (68, 2) and mesh (468, 3) with their upper lids at each aperture share of the rest
    lid gaps (``rest`` of the 68 points, ``mesh_rest`` of the meshes, (2,) each): (S, 68, 2), (S, 468, 3) float64.
    ``aperture_share`` of the s-th set of points against ``rest`` is ``shares[s]``."""
    from landmarks.parts.eyes.lids import closed_gaps, set_lid_gaps

    rest, mesh_rest = np.asarray(rest, np.float64), np.asarray(mesh_rest, np.float64)
    shut, mesh_shut = closed_gaps(rest), closed_gaps(mesh_rest)
    points = np.stack([set_lid_gaps(landmarks, shut + s * (rest - shut)) for s in shares])
    meshes = np.stack([set_lid_gaps(mesh, mesh_shut + s * (mesh_rest - mesh_shut)) for s in shares])
    return points, meshes


def pooled_slope(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of ``y`` on ``x`` with one intercept per row: the sum over rows of their covariances over
    the sum of their variances (the pairs where either is NaN left out; rows with fewer than 2 pairs add nothing).
    x, y: (G, n) or a list of (n_g,) arrays -> float (NaN when no row varies). ``lsr.eval.cross.pooled_gain`` pools
    the same way but leaves out a sequence whose output does not move, which here is the answer: a synthesis that
    keeps its lids reads at 0."""
    covariance = variance = 0.0
    for row_x, row_y in zip(x, y):
        row_x, row_y = np.asarray(row_x, np.float64), np.asarray(row_y, np.float64)
        keep = np.isfinite(row_x) & np.isfinite(row_y)
        if keep.sum() < 2:
            continue
        dx = row_x[keep] - row_x[keep].mean()
        covariance += float(dx @ (row_y[keep] - row_y[keep].mean()))
        variance += float(dx @ dx)
    return covariance / variance if variance > 0 else float("nan")


def eye_strip(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Both eyes of ``image`` (H, W, 3) around ``landmarks`` (68, 2): the eye corners' box grown by ``CROP``."""
    from landmarks.shape.measures import inter_ocular_distance

    points = np.asarray(landmarks, np.float64)
    scale = float(inter_ocular_distance(points[None])[0])
    eyes = points[36:48]
    x0, x1 = eyes[:, 0].min() - CROP[0] * scale, eyes[:, 0].max() + CROP[0] * scale
    y0, y1 = eyes[:, 1].mean() - CROP[1] * scale, eyes[:, 1].mean() + CROP[1] * scale
    height, width = image.shape[:2]
    x0, y0 = max(0, int(np.floor(x0))), max(0, int(np.floor(y0)))
    x1, y1 = min(width, int(np.ceil(x1))), min(height, int(np.ceil(y1)))
    return np.ascontiguousarray(image[y0:y1, x0:x1])


Reader = Callable[[np.ndarray, "np.ndarray | None"], "np.ndarray | None"]
"""(image, fallback landmarks or None) -> (68, 2) landmarks or None."""


def sweep(method: Any, identities: Sequence[Any], *, k: int, holdouts: int, shares: Sequence[float],
          lids: Sequence[str], read: Reader, judge: Reader | None, seed: int = 0, progress: bool = True) -> LidSweep:
    """Re-enact each identity's ``holdouts`` hold-outs at each lid share (module docstring) with ``method`` (an
    ``LsrModelMethod``) under each ``lids`` choice, and read them. ``read``: the driving detector; ``judge``: the
    independent one (None: not judged). Identities need meshes (``lsr.eval.protocol.attach_meshes``)."""
    from tqdm import tqdm

    from landmarks.parts.eyes.drawn_lids import shot_lid_gaps
    from landmarks.parts.eyes.driver_lids import aperture_share
    from landmarks.parts.eyes.lids import lid_gaps
    from landmarks.shape.expression import eye_opening
    from landmarks.warp.piecewise_affine import warp_references_mesh
    from lsr.errors import DatasetError
    from lsr.eval.protocol import sample_shots

    def share_of(image: np.ndarray, rest: np.ndarray) -> tuple[float, np.ndarray | None]:
        found = read(image, None)
        return (aperture_share(found, rest), found) if found is not None else (float("nan"), None)

    def opening(points: np.ndarray | None) -> float:
        return float(eye_opening(points)) if points is not None else float("nan")

    shares = np.asarray(shares, np.float64)
    size = (len(identities), holdouts, len(shares))
    reference, asked = np.full(size, np.nan), np.full(size, np.nan)
    output = {choice: np.full(size, np.nan) for choice in lids}
    judged = {choice: np.full(size, np.nan) for choice in lids}
    real, strips = [], {choice: [] for choice in lids}
    bar = tqdm(total=len(identities) * holdouts * (1 + len(lids)), desc="bench lids", disable=not progress)
    for i, identity in enumerate(identities):
        candidates = np.flatnonzero(np.isfinite(identity.input_landmarks).all(axis=(1, 2))
                                    & np.isfinite(identity.input_meshes).all(axis=(1, 2)))
        targets = np.flatnonzero(np.isfinite(identity.holdout_landmarks).all(axis=(1, 2))
                                 & np.isfinite(identity.holdout_meshes).all(axis=(1, 2)))
        if len(candidates) < 1 or len(targets) < 1:
            raise DatasetError(f"{identity.name}: no shot or hold-out with a face mesh; the bench needs both")
        chosen = sample_shots(candidates, min(k, len(candidates)), seed, identity.name)
        shots = [identity.input_frames[c] for c in chosen]
        stacked = np.stack(shots)
        shot_landmarks = identity.input_landmarks[chosen].astype(np.float64)
        shot_meshes = identity.input_meshes[chosen].astype(np.float64)
        rest = shot_lid_gaps(shot_landmarks)
        mesh_rest = np.median([lid_gaps(mesh) for mesh in shot_meshes], axis=0)
        picked = targets[np.linspace(0, len(targets) - 1, min(holdouts, len(targets))).round().astype(int)]
        for t, row in enumerate(picked):
            points, meshes = lid_targets(identity.holdout_landmarks[row], identity.holdout_meshes[row], rest,
                                         mesh_rest, shares)
            asked[i, t] = eye_opening(points)
            for s in range(len(shares)):
                warped = warp_references_mesh(stacked, shot_meshes, shot_landmarks, meshes[s], points[s], 1)
                reference[i, t, s] = share_of(warped[0][0], rest)[0]
            bar.update(1)
            for choice in lids:
                method.reenactor.lids = choice
                frames = method.reenact(shots, shot_landmarks, points.astype(np.float32),
                                        shot_meshes=shot_meshes.astype(np.float32),
                                        target_meshes=meshes.astype(np.float32))
                for s, frame in enumerate(frames):
                    output[choice][i, t, s], found = share_of(frame, rest)
                    if judge is not None:
                        judged[choice][i, t, s] = opening(judge(frame, found if found is not None else points[s]))
                if t == 0:  # every share cut at the same place: around the eyes as open as the shots'
                    around = points[int(np.argmin(np.abs(shares - 1.0)))]
                    strips[choice].append(np.concatenate([eye_strip(frame, around) for frame in frames], axis=1))
                bar.update(1)
        if judge is not None:  # the real frames, read by both
            frames = list(identity.input_frames) + list(identity.holdout_frames)
            stored = np.concatenate([identity.input_landmarks, identity.holdout_landmarks]).astype(np.float64)
            pairs = [(float(eye_opening(points)), opening(judge(frame, points)))
                     for frame, points in zip(frames, stored) if np.isfinite(points).all()]
            real.append(np.array(pairs, np.float64).reshape(-1, 2))
    bar.close()
    return LidSweep([identity.name for identity in identities], shares, reference, output, asked, judged, real, strips)


def _slopes(sweep_result: LidSweep, read: np.ndarray) -> tuple[float, float]:
    """Pooled slopes of a read share on the asked one, closing (shares <= 1) and opening (>= 1)."""
    shares = sweep_result.shares
    asked = np.broadcast_to(shares, read.shape).reshape(-1, len(shares))
    flat = read.reshape(-1, len(shares))
    closing, opening = shares <= 1.0 + 1e-9, shares >= 1.0 - 1e-9
    return pooled_slope(asked[:, closing], flat[:, closing]), pooled_slope(asked[:, opening], flat[:, opening])


def judged_ratio(sweep_result: LidSweep, choice: str) -> tuple[float, float]:
    """(the judge's pooled slope on the synthesised lids' asked opening, its pooled slope on real frames)."""
    synthesised = pooled_slope(sweep_result.asked_opening.reshape(-1, len(sweep_result.shares)),
                               sweep_result.judged_opening[choice].reshape(-1, len(sweep_result.shares)))
    real = pooled_slope([pairs[:, 0] for pairs in sweep_result.real], [pairs[:, 1] for pairs in sweep_result.real])
    return synthesised, real


def _number(value: float) -> str:
    """Two decimals, with no "-0.00" for a value that rounds to zero."""
    text = f"{value:.2f}"
    return "0.00" if text == "-0.00" else text


def sweep_markdown(result: LidSweep, settings: dict[str, Any], machine: str) -> str:
    from lsr.eval.machine import shown_path

    def cells(values: np.ndarray) -> str:
        means = [np.nanmean(column) if np.isfinite(column).any() else np.nan for column in
                 values.reshape(-1, len(result.shares)).T]
        return " | ".join(_number(value) for value in means)

    holdouts = result.reference.shape[1]
    asked = " | ".join(f"asked {share:g}" for share in result.shares)
    lines = [f"{len(result.identities)} identities of `{shown_path(settings['data'])}`, K = {settings['k']} shots each "
             f"(seed {settings['seed']}), {holdouts} hold-outs each with their upper lids set to each share of the "
             f"shots' aperture at rest; model `{shown_path(settings['weights'])}`.", "",
             "Aperture share read by the driving detector (the mesh's 68 points), mean over hold-outs:", "",
             f"| read | {asked} | slope closing →1 | slope opening →1 |",
             "|---|" + "---|" * (len(result.shares) + 2)]
    rows = [("first warped shot", result.reference)] + [(f"output, lids {choice}", read)
                                                         for choice, read in result.output.items()]
    for label, read in rows:
        closing, opening = _slopes(result, read)
        lines.append(f"| {label} | {cells(read)} | {_number(closing)} | {_number(opening)} |")
    if result.real:
        lines += ["", "Judged (dlib's 68 points): slope of its eye opening on the asked one, against its slope on the "
                  "same identities' real frames (on the driving detector's reading):", "",
                  "| output | judged slope, synthesised | judged slope, real frames | ratio →1 |",
                  "|---|---|---|---|"]
        for choice in result.output:
            synthesised, real = judged_ratio(result, choice)
            ratio = _number(synthesised / real)
            lines.append(f"| lids {choice} | {_number(synthesised)} | {_number(real)} | {ratio} |")
    lines += ["", "Shares: (lid gap - closed gap) / (the shots' median lid gap - closed gap), both eyes' mean "
              "(landmarks.parts.eyes.driver_lids.aperture_share); 1 = as open as the shots. Slopes: least squares, one intercept "
              "per hold-out (judged on real frames: per identity), closing over shares <= 1, opening over shares >= 1; "
              "1 = the synthesis moves its lids as far as it is asked.", "", machine]
    return "\n".join(lines)


def save_sweep(result: LidSweep, path: Path) -> None:
    """The readings as an .npz (written atomically): shares, identities, reference, asked_opening, and per ``--lids``
    choice output_<choice> and judged_<choice>."""
    from landmarks.io.image_files import atomic_output

    arrays = {"shares": result.shares, "identities": np.array(result.identities), "reference": result.reference,
              "asked_opening": result.asked_opening}
    for choice in result.output:
        arrays[f"output_{choice}"], arrays[f"judged_{choice}"] = result.output[choice], result.judged_opening[choice]
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as temp, open(temp, "wb") as handle:
        np.savez(handle, **arrays)


def write_figure(result: LidSweep, path: Path) -> None:
    """Per identity and ``--lids`` choice, its first hold-out's eyes at every share, left (shut) to right (wide)."""
    import cv2

    from landmarks.io.image_files import write_image

    rows = []
    for choice, strips in result.strips.items():
        for name, strip in zip(result.identities, strips):
            labelled = cv2.resize(strip, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)
            cv2.putText(labelled, f"{name} lids {choice}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 0), 1)
            rows.append(labelled)
    width = max(row.shape[1] for row in rows)
    write_image(path, np.concatenate([np.pad(row, ((0, 0), (0, width - row.shape[1]), (0, 0))) for row in rows]))


def run_bench_lids(cfg: BenchLidsConfig) -> LidSweep:
    """Entry point of ``lsr bench lids``: print the table (with --out-md, also its BENCHMARKS.md section)."""
    import torch

    from landmarks.detect.registry import make_detector
    from lsr.eval.model_method import LsrModelMethod
    from lsr.eval.part_regions import Judge
    from lsr.eval.protocol import attach_meshes, detect_faces, detect_layout, load_fsth_sample, load_lsr_split
    from lsr.eval.sections import publish
    from lsr.eval.machine import machine_markdown
    from lsr.weights import resolve_weights

    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    data, cache = cfg.resolved_data(), Path(cfg.out) / "cache"
    detector = make_detector("mesh")
    if detect_layout(data) == "fsth":
        identities = load_fsth_sample(data, detector, cache_dir=cache, progress=cfg.progress)
    else:
        identities = load_lsr_split(data, "test")
        attach_meshes(identities, detector, cache_dir=cache, progress=cfg.progress)
    identities = identities[: cfg.max_identities] if cfg.max_identities else identities
    weights = resolve_weights(cfg.weights)
    method = LsrModelMethod(weights)
    if not method.reenactor.warp_references:
        from lsr.errors import ConfigError

        raise ConfigError(f"{weights} is not a warp-guided model: lsr bench lids reads its warped shots")

    def read(image: np.ndarray, fallback: np.ndarray | None) -> np.ndarray | None:
        found = detect_faces([image], detector)[0][0]
        return found.astype(np.float64) if np.isfinite(found).all() else None

    judge = Judge().landmarks if cfg.judge else None
    result = sweep(method, identities, k=cfg.k, holdouts=cfg.holdouts, shares=cfg.shares, lids=cfg.lids, read=read,
                   judge=judge, seed=cfg.seed, progress=cfg.progress)
    settings = {"data": str(data), "k": cfg.k, "seed": cfg.seed, "weights": str(weights)}
    save_sweep(result, Path(cfg.out) / "lids.npz")
    text = sweep_markdown(result, settings, machine_markdown())
    if cfg.figure is not None:
        write_figure(result, cfg.figure)
        print(f"figure written to {cfg.figure}")
        if cfg.out_md is not None:  # linked from the section, relative to it
            link = os.path.relpath(Path(cfg.figure).resolve(), Path(cfg.out_md).resolve().parent)
            figure = (f"![Each identity's first hold-out, its eyes at every share asked, shut (left) to wide "
                      f"(right)]({link})")
            text = text.replace("\n\n| machine |", f"\n\n{figure}\n\n| machine |", 1)
    publish(cfg, "lsr bench lids", SECTION, "Lids asked and drawn (`lsr bench lids`)", text)
    return result
