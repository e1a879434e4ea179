"""Image-space effects: transient occluders, exposure, motion blur, sensor noise.

Occluders are drawn over the rendered frame only; the class map and the landmarks keep the
*unoccluded* truth (what the face looks like behind the hand or caption), which is what the
layout predicted from landmarks should be. Which frames are occluded, by what and where is
recorded per frame (``OccluderPlan``) and written to ``meta.json["generator"]["occluders"]``.
Occluders come in short runs (0.3-1 s), like a hand passing or a caption showing up.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

_TEXT = "ABCDEFGHIJKLMNOPQRSTUVWXYZ abcdefghijklmnopqrstuvwxyz 0123456789"


@dataclasses.dataclass(frozen=True)
class Occluder:
    """kind: "hand" | "caption"; centre (x, y) and size as fractions of the image; angle in degrees."""

    kind: str
    centre: tuple[float, float]
    size: float
    angle: float
    colour: tuple[float, float, float]
    text_seed: int


def plan_occluders(rng: np.random.Generator, num_frames: int, fps: float, fraction: float, size_factor: float) -> list[Occluder | None]:
    """Per-frame occluder (or None); about ``fraction`` of the frames are covered."""
    plan: list[Occluder | None] = [None] * num_frames
    if fraction <= 0:
        return plan
    target = int(round(fraction * num_frames))
    covered = 0
    attempts = 0
    while covered < target and attempts < 1000:
        attempts += 1
        length = min(target - covered, max(1, int(rng.uniform(0.3, 1.0) * fps)))
        start = int(rng.integers(0, max(1, num_frames - length + 1)))
        if any(plan[i] is not None for i in range(start, start + length)):
            if fraction < 0.9 and attempts < 200:
                continue
        kind = "hand" if rng.random() < 0.6 else "caption"
        skin = np.clip(np.array([0.85, 0.65, 0.5]) * rng.uniform(0.5, 1.1), 0, 1)
        occluder = Occluder(
            kind=kind,
            centre=(float(rng.uniform(0.3, 0.7)), float(rng.uniform(0.35, 0.75) if kind == "hand" else rng.uniform(0.6, 0.9))),
            size=float(rng.uniform(0.18, 0.3) * size_factor),
            angle=float(rng.uniform(-60, 60)),
            colour=tuple(float(c) for c in (skin if kind == "hand" else rng.uniform(0.0, 0.3, 3))),
            text_seed=int(rng.integers(2**31)),
        )
        for i in range(start, start + length):
            if plan[i] is None:
                covered += 1
            plan[i] = occluder
    return plan


def draw_occluder(image: np.ndarray, occluder: Occluder, frame_offset: int) -> np.ndarray:
    """Draw onto (S, S, 3) float32 image in place; returns the (S, S) bool mask of covered pixels.

    frame_offset moves the occluder a little over its run (a hand drifts).
    """
    size = image.shape[0]
    mask = np.zeros((size, size), np.uint8)
    cx = occluder.centre[0] * size + 0.004 * size * frame_offset
    cy = occluder.centre[1] * size
    extent = occluder.size * size
    colour = np.float32(occluder.colour)
    if occluder.kind == "hand":
        rot = np.radians(occluder.angle)
        direction = np.array([np.sin(rot), -np.cos(rot)])
        across = np.array([direction[1], -direction[0]])
        palm = np.array([cx, cy])
        cv2.ellipse(mask, (int(cx), int(cy)), (max(1, int(extent * 0.42)), max(1, int(extent * 0.5))), occluder.angle, 0, 360, 1, -1)
        for finger in range(4):
            base = palm + direction * extent * 0.35 + across * extent * (finger - 1.5) * 0.2
            tip = base + direction * extent * (0.45 + 0.12 * (finger in (1, 2)))
            cv2.line(mask, tuple(int(v) for v in base), tuple(int(v) for v in tip), 1, max(1, int(extent * 0.14)))
        thumb_base = palm - across * extent * 0.3
        cv2.line(mask, tuple(int(v) for v in thumb_base), tuple(int(v) for v in thumb_base - across * extent * 0.4 + direction * extent * 0.2), 1, max(1, int(extent * 0.15)))
        covered = mask.astype(bool)
        yy = (np.arange(size, dtype=np.float32)[:, None] - cy) / max(extent, 1.0)
        shade = np.clip(1.05 - 0.35 * yy, 0.6, 1.15)
        image[covered] = (colour * np.broadcast_to(shade, (size, size))[..., None])[covered]
    else:
        height = max(4, int(extent * 0.35))
        y0 = int(np.clip(cy - height / 2, 0, size - height))
        mask[y0 : y0 + height] = 1
        covered = mask.astype(bool)
        image[covered] = 0.35 * image[covered] + 0.65 * colour
        rng = np.random.default_rng(occluder.text_seed)
        text = "".join(rng.choice(list(_TEXT), 18))
        scale = height / 40.0
        overlay = np.zeros((size, size), np.uint8)
        cv2.putText(overlay, text, (int(size * 0.04), y0 + int(height * 0.72)), cv2.FONT_HERSHEY_SIMPLEX, scale, 255, max(1, int(scale * 2)))
        image[overlay > 0] = 0.95
    return covered


def expose(image: np.ndarray, gain: float, gamma: float) -> np.ndarray:
    """Exposure gain then gamma on a float image in [0, ~1]; clipped to [0, 1]."""
    out = np.clip(image * gain, 0.0, 1.0)
    if gamma != 1.0:
        out = out**gamma
    return out


def motion_blur(image: np.ndarray, length_px: float, angle: float) -> np.ndarray:
    """Linear motion blur of ``length_px`` pixels along ``angle`` (radians)."""
    if length_px < 1.0:
        return image
    k = int(np.ceil(length_px)) | 1
    kernel = np.zeros((k, k), np.float32)
    centre = k // 2
    for t in np.linspace(-length_px / 2, length_px / 2, 4 * k):
        kernel[int(round(centre + t * np.sin(angle))), int(round(centre + t * np.cos(angle)))] = 1.0
    return cv2.filter2D(image, -1, kernel / kernel.sum(), borderType=cv2.BORDER_REFLECT)


def to_uint8(image: np.ndarray, rng: np.random.Generator | None = None, noise_sd: float = 0.0) -> np.ndarray:
    """Float [0, 1] -> uint8, with optional Gaussian noise of ``noise_sd`` (in 0..255 units)."""
    out = image * 255.0
    if noise_sd > 0 and rng is not None:
        out = out + rng.normal(0.0, noise_sd, out.shape).astype(np.float32)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)
