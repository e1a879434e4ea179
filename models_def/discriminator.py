"""Discriminator D: StyleGAN2 residual discriminator with the smallest width reduced to 32 (thesis §4.6, [14])."""

from __future__ import annotations

import math

import torch
from torch import nn

from models_def.blocks import LEAKY_GAIN, DownResBlock, EqualConv2d, EqualLinear, leaky_relu
from models_def.config import ModelConfig
from models_def.serialization import PretrainedMixin
from models_def.shapes import check_shape


def minibatch_stddev_group(group_size: int, batch: int) -> int:
    """Group size for minibatch-stddev that divides the batch: the largest divisor of ``batch`` <= group_size.

    Fine-tuning runs on small batches (§4.3.5), so the StyleGAN2 default of 4 must adapt (batch 3 -> 3, 6 -> 3).
    """
    if batch < 1 or group_size < 1:
        raise ValueError(f"minibatch-stddev needs batch >= 1 and group_size >= 1; got {batch}, {group_size}")
    return max(d for d in range(1, min(group_size, batch) + 1) if batch % d == 0)


def minibatch_stddev(x: torch.Tensor, group_size: int) -> torch.Tensor:
    """Append one channel holding the mean std over groups of samples. x: (B, C, H, W) -> (B, C + 1, H, W)."""
    batch, channels, height, width = x.shape
    group = minibatch_stddev_group(group_size, batch)
    grouped = x.view(group, batch // group, channels, height, width)  # (G, B/G, C, H, W)
    std = torch.sqrt(grouped.var(dim=0, unbiased=False) + 1e-8)  # (B/G, C, H, W)
    std = std.mean(dim=(1, 2, 3)).view(batch // group, 1, 1, 1)  # (B/G, 1, 1, 1)
    return torch.cat([x, std.repeat(group, 1, height, width)], dim=1)


class Discriminator(PretrainedMixin, nn.Module):
    """forward(image: (B, 3, H, W) in [-1, 1], landmark_image: (B, C_lm, H, W) or None) -> logits (B,).

    fromRGB 1x1 -> residual blur-pool blocks down to 4x4 (widths 32 at H, doubling, max 512) ->
    minibatch-stddev -> conv3x3 -> fc -> fc. Pass ``landmark_image`` iff ``discriminator_conditioned``.
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        blocks = int(math.log2(config.resolution)) - 2
        widths = [config.capped(config.discriminator_base_channels * 2**i) for i in range(blocks + 1)]
        in_channels = 3 + (config.landmark_channels if config.discriminator_conditioned else 0)
        self.from_rgb = EqualConv2d(in_channels, widths[0], 1)
        self.blocks = nn.Sequential(*(DownResBlock(a, b) for a, b in zip(widths[:-1], widths[1:])))
        final = widths[-1]
        self.final_conv = EqualConv2d(final + 1, final, 3, gain=LEAKY_GAIN)
        self.final_linear = EqualLinear(final * 4 * 4, final, gain=LEAKY_GAIN)
        self.to_logit = EqualLinear(final, 1, gain=LEAKY_GAIN)

    def forward(self, image: torch.Tensor, landmark_image: torch.Tensor | None = None) -> torch.Tensor:
        size = self.config.resolution
        bound = check_shape("image", image, ("B", 3, size, size))
        if self.config.discriminator_conditioned:
            if landmark_image is None:
                raise ValueError("this discriminator is landmark-conditioned; pass landmark_image (B, C_lm, H, W)")
            check_shape("landmark_image", landmark_image, (bound["B"], self.config.landmark_channels, size, size))
            image = torch.cat([image, landmark_image], dim=1)
        elif landmark_image is not None:
            raise ValueError("this discriminator is unconditional (discriminator_conditioned=False); omit landmark_image")
        x = self.blocks(leaky_relu(self.from_rgb(image)))  # (B, C, 4, 4)
        x = minibatch_stddev(x, self.config.mbstd_group_size)  # (B, C + 1, 4, 4)
        x = leaky_relu(self.final_conv(x))
        x = leaky_relu(self.final_linear(x.flatten(1)))  # (B, C)
        return self.to_logit(x).squeeze(1)  # (B,)
