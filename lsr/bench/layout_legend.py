"""``lsr bench layout-legend``: what each channel of a model's latent layout covers, as names for its legend.

The latent layout (thesis §4.3.4) is learnt without labels, so its channels have no names. This survey runs the
model over frames of a prepared dataset whose segmentation maps it has (``lsr prepare``'s face parsing), takes
each pixel's strongest channel (``lsr.layout_view.layout_parts_rgb``) and counts which face part it falls on.
Each channel is named by the parts that make up at least ``NAME_SHARE`` of its pixels (the largest first, at most
two), e.g. "lips / mouth"; the names go to ``<weights>/layout_legend.json`` (``lsr.layout_view.LEGEND_FILE``),
which the side-by-side, the app and the live tab show beside the layout. The table says how pure each channel is.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

NAME_SHARE = 0.2


def survey(reenactor, data: Path, split: str, clips: int, every: int, k: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """(C_l, 19) pixel counts: layout channel x segmentation class, over every ``every``-th frame after the first
    ``k`` (the shots) of ``clips`` clips of ``split`` spread over the dataset, each re-enacted onto its own
    landmarks; and (C_l,) each channel's mean height in the face: 0 at the eyes, 1 at the mouth."""
    from tqdm import tqdm

    from lsr.data.classes import NUM_SEG_CLASSES
    from lsr.data.format import ClipReader, list_clips
    from lsr.pipeline import subject_shots_from_training

    folders = list_clips(data, split)
    folders = [folders[i] for i in np.linspace(0, len(folders) - 1, min(clips, len(folders))).round().astype(int)]
    counts = None
    for folder in tqdm(folders, desc="layout legend", unit="clip"):
        reader = ClipReader(folder)
        if not reader.has_segmentation:
            continue
        frames, landmarks = np.stack(list(reader.frames())), reader.landmarks
        valid = np.flatnonzero(np.isfinite(landmarks).all(axis=(1, 2)))
        if len(valid) <= k:
            continue
        reenactor.encode_subject(subject_shots_from_training(frames[valid[:k]], landmarks[valid[:k]]))
        for index in valid[k::every]:
            _, _, layout = reenactor.synthesize_crop(landmarks[index], with_layout=True)
            strongest = layout.argmax(axis=0)
            side = strongest.shape[0]
            classes = cv2.resize(reader.segmentation(index), (side, side), interpolation=cv2.INTER_NEAREST)
            if counts is None:
                counts = np.zeros((layout.shape[0], NUM_SEG_CLASSES), np.int64)
                heights = np.zeros(layout.shape[0])
            np.add.at(counts, (strongest.ravel(), classes.ravel().astype(int)), 1)
            points = landmarks[index] * (side / frames.shape[1])
            eyes, mouth = points[36:48, 1].mean(), points[48:68, 1].mean()
            rows = (np.arange(side, dtype=np.float64)[:, None] - eyes) / max(mouth - eyes, 1e-6)
            np.add.at(heights, strongest.ravel(), np.broadcast_to(rows, strongest.shape).ravel())
    if counts is None:
        raise FileNotFoundError(f"no clip of split {split!r} in {data} has segmentation maps and more than {k} frames")
    return counts, heights / np.maximum(counts.sum(axis=1), 1)


def legend_names(counts: np.ndarray, heights: np.ndarray | None = None) -> list[str]:
    """A name per channel from ``survey``'s counts: its parts of at least ``NAME_SHARE`` (at most two, largest
    first), "unused" where it is never the strongest; skin is told apart by where it lies (``heights``: forehead,
    eyes, cheeks, mouth, chin)."""
    from lsr.data.classes import SEG_CLASSES

    readable = {"l_brow": "brow", "r_brow": "brow", "l_eye": "eye", "r_eye": "eye", "l_ear": "ear", "r_ear": "ear",
                "u_lip": "upper lip", "l_lip": "lower lip", "cloth": "clothes", "mouth": "mouth (inside)"}
    names = []
    for row in counts:
        total = row.sum()
        if total == 0:
            names.append("unused")
            continue
        parts: dict[str, float] = {}
        for index in np.argsort(row)[::-1]:
            part = readable.get(SEG_CLASSES[index], SEG_CLASSES[index])
            parts[part] = parts.get(part, 0.0) + row[index] / total
        kept = [part for part, share in sorted(parts.items(), key=lambda item: -item[1]) if share >= NAME_SHARE][:2]
        kept = kept or [max(parts, key=parts.get)]
        if heights is not None and kept[0] == "skin":
            kept[0] = f"skin ({_where(float(heights[len(names)]))})"
        names.append(" / ".join(kept))
    return names


def _where(height: float) -> str:
    """A face height (0 at the eyes, 1 at the mouth) in words."""
    for limit, word in ((-0.45, "forehead"), (0.25, "eyes"), (0.7, "cheeks"), (1.2, "mouth"), (np.inf, "chin")):
        if height < limit:
            return word
    return "chin"


def run_bench_layout_legend(cfg) -> str:
    """Entry point of ``lsr bench layout-legend`` (``lsr.config.BenchLayoutLegendConfig``)."""
    from landmarks.io.image_files import atomic_output
    from lsr.data.classes import SEG_CLASSES
    from lsr.layout_view import LEGEND_FILE
    from lsr.eval.machine import machine_markdown, shown_path
    from lsr.pipeline import Reenactor
    from lsr.weights import resolve_weights

    weights = resolve_weights(cfg.weights)
    reenactor = Reenactor(weights)
    counts, heights = survey(reenactor, cfg.data, cfg.split, cfg.clips, cfg.every)
    names = legend_names(counts, heights)
    total = counts.sum()
    rows = []
    for channel, (row, name) in enumerate(zip(counts, names)):
        top = np.argsort(row)[::-1][:3]
        parts = ", ".join(f"{SEG_CLASSES[i]} {row[i] / max(row.sum(), 1):.2f}" for i in top if row[i])
        rows.append(f"| {channel} | {name} | {row.sum() / total:.3f} | {heights[channel]:.2f} | {parts or '–'} |")
    table = "\n".join([
        f"Model `{shown_path(weights)}`, {cfg.clips} clips of `{shown_path(cfg.data)}` ({cfg.split}), every "
        f"{cfg.every}th frame after the 8 shots, each re-enacted onto its own landmarks; each pixel's strongest layout "
        "channel against the prepared face parsing.",
        "",
        "| channel | legend name | share of pixels | height (eyes 0, mouth 1) | its parts (share of the channel) |",
        "|---|---|---|---|---|",
        *rows,
        "",
        machine_markdown(),
    ])
    path = Path(weights) / LEGEND_FILE
    text = json.dumps({"channels": names, "from": f"lsr bench layout-legend {shown_path(cfg.data)} ({cfg.split}, "
                       f"{cfg.clips} clips)"}, indent=2) + "\n"
    with atomic_output(path) as temp:
        Path(temp).write_text(text)
    from lsr.eval import sections

    sections.publish(cfg, "lsr bench layout-legend", "layout_legend",
                     "What the latent layout's channels cover (`lsr bench layout-legend`)", table)
    print(f"legend written to {path}")
    return table
