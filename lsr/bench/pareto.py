"""Pareto front of (cost, quality) points and its plot (OpenCV drawing; matplotlib is not a dependency).

Used by ``lsr bench speed``: x = ms/frame (lower is better), y = an error metric (PSNR or SSIM: higher is
better; NMKE: lower is better).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np


def pareto_front(points: Sequence[tuple[float, float]], *, higher_y_is_better: bool = True) -> list[int]:
    """Indices (sorted by x) of the points no other point dominates. x: cost, lower is better.

    A point is dominated when another is at least as good in both coordinates and strictly better in one.
    Exact duplicates dominate neither each other, so all of them stay on the front. Points with a
    non-finite coordinate are never on the front.
    """
    sign = 1.0 if higher_y_is_better else -1.0
    candidates = [(float(x), sign * float(y), i) for i, (x, y) in enumerate(points) if math.isfinite(x) and math.isfinite(y)]
    front = []
    for x, y, index in candidates:
        dominated = any(ox <= x and oy >= y and (ox < x or oy > y) for ox, oy, _ in candidates)
        if not dominated:
            front.append((x, -y, index))
    return [index for _, _, index in sorted(front)]


_RUNTIME_COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75)]


def _log_ticks(low: float, high: float) -> list[float]:
    """1-2-5 ticks per decade; finer (1, 1.5, 2, 3, 5, 7) when that gives fewer than four."""
    for mantissas in ((1, 2, 5), (1, 1.5, 2, 3, 5, 7), (1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 7, 8, 9)):
        ticks = [m * 10.0**d for d in range(math.floor(math.log10(low)), math.ceil(math.log10(high)) + 1)
                 for m in mantissas if low <= m * 10.0**d <= high]
        if len(ticks) >= 4:
            break
    return ticks


def y_axis_range(ys: np.ndarray, min_span: float = 0.0) -> tuple[float, float]:
    """(low, high) of a y axis showing ``ys`` (finite, non-empty) with a 10 % margin, centred on them, at least
    ``min_span`` wide, so that differences within the metric's run-to-run noise do not fill the axis."""
    low, high = float(ys.min()), float(ys.max())
    span = max(high - low, min_span, 1e-3 * max(1.0, abs(high)))
    centre = (low + high) / 2
    return centre - 0.6 * span, centre + 0.6 * span


def plot_speed_error(
    points: Sequence[tuple[float, float]],
    labels: Sequence[str],
    groups: Sequence[str],
    *,
    y_label: str,
    higher_y_is_better: bool,
    title: str,
    min_y_span: float = 0.0,
    size: tuple[int, int] = (960, 640),
) -> np.ndarray:
    """Scatter of ``points`` (x = ms/frame on a log axis, y linear), one colour per group (runtime), each point
    labelled, the Pareto front joined by a line and circled. The y axis spans at least ``min_y_span`` (see
    ``y_axis_range``). Returns an (H, W, 3) uint8 RGB image."""
    if not (len(points) == len(labels) == len(groups)):
        raise ValueError("points, labels and groups must have the same length")
    width, height = size
    left, right, top, bottom = 80, 250, 50, 70  # the legend lives in the right margin
    canvas = np.full((height, width, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(canvas, title, (left, 30), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    finite = [(x, y) for x, y in points if math.isfinite(x) and math.isfinite(y) and x > 0]
    cv2.rectangle(canvas, (left, top), (width - right, height - bottom), (0, 0, 0), 1)
    cv2.putText(canvas, "ms/frame (log scale, lower is better)", (left + 150, height - 20), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    better = "higher" if higher_y_is_better else "lower"
    cv2.putText(canvas, f"{y_label} ({better} is better)", (left, top - 8), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    if not finite:
        cv2.putText(canvas, "no point has both a time and an error", (left + 20, height // 2), font, 0.6, (0, 0, 200), 1, cv2.LINE_AA)
        return canvas
    xs, ys = np.array([p[0] for p in finite]), np.array([p[1] for p in finite])
    x_low, x_high = float(xs.min()) / 1.3, float(xs.max()) * 1.3
    y_low, y_high = y_axis_range(ys, min_y_span)
    decimals = max(0, 1 - math.floor(math.log10((y_high - y_low) / 5)))

    def to_pixel(x: float, y: float) -> tuple[int, int]:
        u = (math.log10(x) - math.log10(x_low)) / (math.log10(x_high) - math.log10(x_low))
        v = (y - y_low) / (y_high - y_low)
        return int(round(left + u * (width - left - right))), int(round(height - bottom - v * (height - top - bottom)))

    for tick in _log_ticks(x_low, x_high):
        px, _ = to_pixel(tick, y_low)
        cv2.line(canvas, (px, top), (px, height - bottom), (225, 225, 225), 1)
        cv2.putText(canvas, f"{tick:g}", (px - 10, height - bottom + 18), font, 0.4, (60, 60, 60), 1, cv2.LINE_AA)
    for tick in np.linspace(y_low, y_high, 6):
        _, py = to_pixel(x_low, float(tick))
        cv2.line(canvas, (left, py), (width - right, py), (225, 225, 225), 1)
        cv2.putText(canvas, f"{tick:.{decimals}f}", (8, py + 4), font, 0.4, (60, 60, 60), 1, cv2.LINE_AA)
    front = pareto_front(points, higher_y_is_better=higher_y_is_better)
    front_pixels = [to_pixel(*points[i]) for i in front]
    if len(front_pixels) > 1:
        cv2.polylines(canvas, [np.array(front_pixels, np.int32)], False, (120, 120, 120), 1, cv2.LINE_AA)
    group_names = list(dict.fromkeys(groups))
    for index, ((x, y), label, group) in enumerate(zip(points, labels, groups)):
        if not (math.isfinite(x) and math.isfinite(y) and x > 0):
            continue
        colour = _RUNTIME_COLOURS[group_names.index(group) % len(_RUNTIME_COLOURS)]
        px, py = to_pixel(x, y)
        cv2.circle(canvas, (px, py), 5, colour, -1, cv2.LINE_AA)
        if index in front:
            cv2.circle(canvas, (px, py), 9, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(canvas, label, (px + 8, py - 6 - 12 * (index % 2)), font, 0.38, colour, 1, cv2.LINE_AA)
    legend_x, legend_y = width - right + 20, top + 18
    for position, group in enumerate(group_names):
        colour = _RUNTIME_COLOURS[position % len(_RUNTIME_COLOURS)]
        cv2.circle(canvas, (legend_x, legend_y + 20 * position - 4), 5, colour, -1, cv2.LINE_AA)
        cv2.putText(canvas, group, (legend_x + 12, legend_y + 20 * position), font, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.circle(canvas, (legend_x, legend_y + 20 * len(group_names) - 4), 9, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(canvas, "Pareto front (joined)", (legend_x + 12, legend_y + 20 * len(group_names)), font, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return canvas


def write_plot(path: str | Path, image: np.ndarray) -> Path:
    """Write the RGB plot as a PNG atomically."""
    from lsr.train.visualize import write_png

    write_png(Path(path), image)
    return Path(path)
