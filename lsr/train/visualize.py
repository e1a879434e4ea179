"""Training previews: image grids and loss curves (layout pictures come from ``lsr.layout_view``).

Everything returns uint8 RGB numpy arrays (H, W, 3) so TensorBoard, PNG writers and tests share them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import torch
from torch import Tensor

from lsr.layout_view import (  # noqa: F401 - re-exported for the training previews
    LayoutPCA,
    images_to_uint8,
    layout_argmax_rgb,
    layout_pca_rgb,
    segmentation_rgb,
)

if TYPE_CHECKING:
    from lsr.config import CurvesConfig


def image_grid(rows: Sequence[Tensor], max_columns: int = 8) -> np.ndarray:
    """Stack rows of (B, 3, H, W) images in [-1, 1] into one (rows*H, B*W, 3) uint8 grid (one sample per column)."""
    if not rows:
        raise ValueError("image_grid needs at least one row")
    arrays = [images_to_uint8(row[:max_columns].to(torch.float32).cpu()) for row in rows]
    height, width = arrays[0].shape[1:3]
    lines = []
    for array in arrays:
        if array.shape[1:3] != (height, width):
            array = np.stack([cv2.resize(a, (width, height), interpolation=cv2.INTER_NEAREST) for a in array])
        lines.append(np.concatenate(list(array), axis=1))
    columns = max(line.shape[1] for line in lines)
    lines = [np.pad(line, ((0, 0), (0, columns - line.shape[1]), (0, 0))) for line in lines]
    return np.concatenate(lines, axis=0)


# ---- loss curves --------------------------------------------------------------------------------------

_CURVE_COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
                  (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]


def read_tensorboard_scalars(log_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """All scalar series of a TensorBoard run folder: tag -> [(step, value), ...] sorted by step."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    accumulator = EventAccumulator(str(log_dir), size_guidance={"scalars": 0})
    accumulator.Reload()
    return {tag: [(e.step, e.value) for e in accumulator.Scalars(tag)] for tag in accumulator.Tags()["scalars"]}


def plot_curves(series: Mapping[str, Sequence[tuple[int, float]]], panel_size: tuple[int, int] = (420, 260)) -> np.ndarray:
    """One small line plot per tag (opencv drawing; no matplotlib), tiled 3 per row. Returns (H, W, 3) uint8."""
    panels = []
    width, height = panel_size
    margin = 36
    for index, (tag, points) in enumerate(sorted(series.items())):
        panel = np.full((height, width, 3), 255, np.uint8)
        cv2.putText(panel, tag, (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        finite = [(s, v) for s, v in points if np.isfinite(v)]
        if len(finite) >= 1:
            steps = np.array([s for s, _ in finite], float)
            values = np.array([v for _, v in finite], float)
            low, high = float(values.min()), float(values.max())
            if high - low < 1e-12:
                low, high = low - 0.5, high + 0.5
            span_steps = max(1.0, steps.max() - steps.min())
            xs = margin + (steps - steps.min()) / span_steps * (width - margin - 10)
            ys = height - margin + (values - low) / (high - low) * -(height - 2 * margin)
            colour = _CURVE_COLOURS[index % len(_CURVE_COLOURS)][::-1]
            cv2.polylines(panel, [np.stack([xs, ys], 1).round().astype(np.int32)], False, colour, 1, cv2.LINE_AA)
            for y_value, y_pixel in ((high, margin), (low, height - margin)):
                cv2.putText(panel, f"{y_value:.3g}", (2, int(y_pixel)), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (80, 80, 80), 1)
            cv2.putText(panel, f"step {int(steps.min())}..{int(steps.max())}", (margin, height - 8),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.35, (80, 80, 80), 1)
        cv2.rectangle(panel, (margin, margin), (width - 10, height - margin), (200, 200, 200), 1)
        panels.append(panel)
    if not panels:
        raise ValueError("no scalar series to plot")
    per_row = 3
    blank = np.full_like(panels[0], 255)
    while len(panels) % per_row:
        panels.append(blank)
    return np.concatenate([np.concatenate(panels[i : i + per_row], axis=1) for i in range(0, len(panels), per_row)])


def write_png(path: Path, image: np.ndarray) -> None:
    """Write an RGB uint8 image atomically (temp file + os.replace)."""
    import os

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}.png")
    if not cv2.imwrite(str(tmp), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {path}")
    os.replace(tmp, path)


def tensorboard_to_png(log_dir: Path, png_path: Path, tags: Sequence[str] | None = None) -> Path:
    """Export a run's TensorBoard scalars (optionally only ``tags``) as a tiled PNG of line plots."""
    series = read_tensorboard_scalars(log_dir)
    if tags is not None:
        series = {tag: series[tag] for tag in tags if tag in series}
    write_png(png_path, plot_curves(series))
    return Path(png_path)


def run_curves(cfg: CurvesConfig) -> Path:
    """Entry point of ``lsr curves RUN --out PNG`` (``lsr.config.CurvesConfig``)."""
    from landmarks.io.image_files import check_output_path
    from lsr.errors import ConfigError

    check_output_path(cfg.out)
    log_dir = Path(cfg.run) / "tensorboard" if (Path(cfg.run) / "tensorboard").is_dir() else Path(cfg.run)
    series = read_tensorboard_scalars(log_dir)
    if not series:
        raise ConfigError(f"no TensorBoard scalars under {log_dir}: give the run folder of `lsr train --out RUN`")
    path = tensorboard_to_png(log_dir, cfg.out, cfg.tags or None)
    print(f"curves of {len(series)} scalar(s) written to {path}")
    return path
