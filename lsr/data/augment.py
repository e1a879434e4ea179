"""Consistent augmentation of frames, landmarks and segmentation maps (kornia).

One geometric transform per frame (small rotation, scale and shift about the image centre) is
applied to the frame (bilinear), its landmarks (the same 2x3 matrix) and its class map (nearest),
so the three stay registered. Colour jitter (brightness, contrast, saturation, hue) is drawn once
per *episode* and applied to all its frames: the generator must reproduce the shots' colours in
the target (thesis §4.3), so shots and target may not disagree in colour.

Randomness comes only from the ``torch.Generator`` passed in, so an episode's augmentation is a
function of its seed (independent of DataLoader workers).
"""

from __future__ import annotations

import dataclasses
import math

import torch
from kornia.enhance import adjust_brightness, adjust_contrast, adjust_hue, adjust_saturation
from kornia.geometry.transform import get_rotation_matrix2d, warp_affine

from lsr.errors import ConfigError


@dataclasses.dataclass(frozen=True)
class AugmentConfig:
    """Ranges of the random augmentation (each drawn uniformly in [-x, x] unless noted)."""

    max_rotation_deg: float = 5.0
    max_scale: float = 0.05
    """Scale factor drawn in [1 - max_scale, 1 + max_scale]."""
    max_shift: float = 0.03
    """Shift as a fraction of the image side."""
    brightness: float = 0.1
    """Added to [0, 1] intensities."""
    contrast: float = 0.1
    """Contrast factor in [1 - contrast, 1 + contrast]."""
    saturation: float = 0.1
    """Saturation factor in [1 - saturation, 1 + saturation]."""
    hue: float = 0.02
    """Hue shift as a fraction of a full turn."""

    def validate(self) -> None:
        values = dataclasses.asdict(self)
        if any(v < 0 for v in values.values()):
            raise ConfigError(f"augmentation ranges must be >= 0, got {values}")
        if self.max_scale >= 1 or self.contrast >= 1 or self.saturation >= 1 or self.hue > 0.5:
            raise ConfigError("max_scale, contrast and saturation must be < 1 and hue <= 0.5")


def _uniform(generator: torch.Generator, count: int, limit: float) -> torch.Tensor:
    return (torch.rand(count, generator=generator, dtype=torch.float64) * 2.0 - 1.0) * limit


def sample_affine(generator: torch.Generator, count: int, size: int, config: AugmentConfig) -> torch.Tensor:
    """``count`` random 2x3 matrices (count, 2, 3) float32 mapping source pixels to output pixels
    (pixel centres at integers, the convention of the dataset landmarks)."""
    angle = _uniform(generator, count, config.max_rotation_deg)
    scale = 1.0 + _uniform(generator, count, config.max_scale)
    shift = _uniform(generator, 2 * count, config.max_shift * size).reshape(count, 2)
    centre = torch.full((count, 2), (size - 1) / 2.0, dtype=torch.float32)
    matrices = get_rotation_matrix2d(centre, angle.float(), scale.float().unsqueeze(1).repeat(1, 2))  # (count, 2, 3)
    matrices[:, :, 2] += shift.float()
    return matrices


def sample_colour(generator: torch.Generator, config: AugmentConfig) -> torch.Tensor:
    """(4,) float32: brightness offset, contrast factor, saturation factor, hue shift (fraction of a turn)."""
    draws = _uniform(generator, 4, 1.0)
    return torch.tensor(
        [draws[0] * config.brightness, 1 + draws[1] * config.contrast, 1 + draws[2] * config.saturation, draws[3] * config.hue],
        dtype=torch.float32,
    )


def warp_frames(images: torch.Tensor, matrices: torch.Tensor) -> torch.Tensor:
    """images: (N, C, S, S) float; matrices: (N, 2, 3). Bilinear, border replicated."""
    size = images.shape[-2:]
    return warp_affine(images, matrices.to(images.dtype), (int(size[0]), int(size[1])), mode="bilinear",
                       padding_mode="border", align_corners=True)


def warp_segmentation(segmentation: torch.Tensor, matrices: torch.Tensor) -> torch.Tensor:
    """segmentation: (N, S, S) int64 class ids (negative = ignore); nearest, border replicated (as the frames)."""
    as_float = segmentation.unsqueeze(1).to(torch.float32)
    size = segmentation.shape[-2:]
    warped = warp_affine(as_float, matrices.to(torch.float32), (int(size[0]), int(size[1])), mode="nearest",
                         padding_mode="border", align_corners=True)
    return warped.squeeze(1).round().to(torch.int64)


def warp_landmarks(landmarks: torch.Tensor, matrices: torch.Tensor) -> torch.Tensor:
    """landmarks: (N, 68, 2) float x, y; matrices: (N, 2, 3). NaN rows stay NaN."""
    matrices = matrices.to(landmarks.dtype)
    return landmarks @ matrices[:, :, :2].transpose(1, 2) + matrices[:, None, :, 2]


def adjust_colour(images: torch.Tensor, colour: torch.Tensor) -> torch.Tensor:
    """images: (N, 3, S, S) float in [0, 1]; colour: (4,) from ``sample_colour``. Returns [0, 1]."""
    images = adjust_brightness(images, float(colour[0]))
    images = adjust_contrast(images, float(colour[1]))
    images = adjust_saturation(images, float(colour[2]))
    images = adjust_hue(images, float(colour[3]) * 2.0 * math.pi)  # kornia: radians in [-pi, pi]
    return images.clamp(0.0, 1.0)


def augment_frames(
    images: torch.Tensor,
    landmarks: torch.Tensor,
    segmentation: torch.Tensor | None,
    generator: torch.Generator,
    config: AugmentConfig,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Augment the N frames of one episode consistently.

    images: (N, 3, S, S) float in [0, 1]; landmarks: (N, 68, 2) float pixels; segmentation: None or
    (N, S, S) int64. Returns the same shapes: a random affine per frame, one colour jitter for all.
    """
    if images.ndim != 4 or images.shape[1] != 3 or images.shape[-1] != images.shape[-2]:
        raise ValueError(f"images must be (N, 3, S, S), got {tuple(images.shape)}")
    if landmarks.shape != (images.shape[0], 68, 2):
        raise ValueError(f"landmarks must be ({images.shape[0]}, 68, 2), got {tuple(landmarks.shape)}")
    matrices = sample_affine(generator, images.shape[0], images.shape[-1], config)
    colour = sample_colour(generator, config)
    images = adjust_colour(warp_frames(images, matrices), colour)
    landmarks = warp_landmarks(landmarks, matrices)
    if segmentation is not None:
        segmentation = warp_segmentation(segmentation, matrices)
    return images, landmarks, segmentation
