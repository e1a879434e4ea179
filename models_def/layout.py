"""AdaIN UNet: the layout predictor G^l (thesis §4.3.2, §4.6) and, with an RGB output, the FSTH-like baseline.

"A traditional UNet with residual blocks ... InstanceNorm and AdaIN ... the smallest and largest number of
feature maps are 32 and 512 ... blur-pool and bilinear upsampling" (§4.6).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from models_def.blocks import LEAKY_GAIN, BlurPool2d, EqualConv2d, leaky_relu
from models_def.config import ModelConfig
from models_def.norms import AdaIN


class AdaINResBlock(nn.Module):
    """Pre-activation residual block: (AdaIN -> lrelu -> conv3x3) x 2, plus a 1x1 shortcut when widths differ.

    x: (B, in, H, W), latent: (B, D) -> (B, out, H, W).
    """

    def __init__(self, in_channels: int, out_channels: int, latent_dim: int, eps: float) -> None:
        super().__init__()
        self.norm_0 = AdaIN(in_channels, latent_dim, eps)
        self.conv_0 = EqualConv2d(in_channels, out_channels, 3, gain=LEAKY_GAIN)
        self.norm_1 = AdaIN(out_channels, latent_dim, eps)
        self.conv_1 = EqualConv2d(out_channels, out_channels, 3, gain=LEAKY_GAIN)
        self.shortcut = EqualConv2d(in_channels, out_channels, 1, bias=False) if in_channels != out_channels else None

    def forward(self, x: torch.Tensor, latent: torch.Tensor) -> torch.Tensor:
        residual = self.conv_0(leaky_relu(self.norm_0(x, latent)))
        residual = self.conv_1(leaky_relu(self.norm_1(residual, latent)))
        skip = x if self.shortcut is None else self.shortcut(x)
        return skip + residual


class AdaINUNet(nn.Module):
    """UNet of AdaIN residual blocks driven by a latent code.

    forward(x: (B, in_channels, H, W), latent: (B, latent_dim), with_aux_rgb=False)
      -> (output: (B, out_channels, H, W) raw (no activation), aux_rgb: (B, 3, H, W) in [-1, 1] or None)

    ``levels`` resolutions H, H/2, ..., widths base*2**i capped at max (32 ... 512 in the thesis).
    """

    def __init__(
        self,
        *,
        in_channels: int,
        out_channels: int,
        widths: list[int],
        latent_dim: int,
        eps: float,
        aux_rgb_head: bool,
    ) -> None:
        super().__init__()
        self.stem = EqualConv2d(in_channels, widths[0], 3)
        self.down_pools = nn.ModuleList(BlurPool2d(width) for width in widths[:-1])
        encoder_in = [widths[0]] + widths[:-1]
        self.down_blocks = nn.ModuleList(
            AdaINResBlock(a, b, latent_dim, eps) for a, b in zip(encoder_in, widths)
        )
        # Up path: upsample the deeper level, concatenate the skip connection of this level.
        self.up_blocks = nn.ModuleList(
            AdaINResBlock(widths[level + 1] + widths[level], widths[level], latent_dim, eps)
            for level in range(len(widths) - 1)
        )
        self.to_output = EqualConv2d(widths[0], out_channels, 3, gain=LEAKY_GAIN)
        self.to_aux_rgb = EqualConv2d(widths[0], 3, 3, gain=LEAKY_GAIN) if aux_rgb_head else None

    def forward(
        self, x: torch.Tensor, latent: torch.Tensor, with_aux_rgb: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        features = self.stem(x)
        skips: list[torch.Tensor] = []
        for level, block in enumerate(self.down_blocks):
            if level > 0:
                features = self.down_pools[level - 1](features)  # (B, C, H / 2**level, W / 2**level)
            features = block(features, latent)
            skips.append(features)
        for level in reversed(range(len(self.up_blocks))):
            features = F.interpolate(features, scale_factor=2.0, mode="bilinear", align_corners=False)
            features = self.up_blocks[level](torch.cat([features, skips[level]], dim=1), latent)
        features = leaky_relu(features)  # (B, widths[0], H, W)
        output = self.to_output(features)
        if not with_aux_rgb:
            return output, None
        if self.to_aux_rgb is None:
            raise ValueError("this model was built with aux_rgb_head=False; it cannot return the auxiliary RGB")
        return output, torch.tanh(self.to_aux_rgb(features))


def layout_unet_widths(config: ModelConfig) -> list[int]:
    return [config.capped(config.layout_base_channels * 2**i) for i in range(config.layout_levels)]


def build_layout_predictor(config: ModelConfig) -> AdaINUNet:
    """G^l: target landmark image (B, C_lm, H, W) + layout latent z^l -> layout logits (B, C_l, H, W) (+ R_t)."""
    return AdaINUNet(
        in_channels=config.landmark_channels,
        out_channels=config.layout_channels,
        widths=layout_unet_widths(config),
        latent_dim=config.latent_dim,
        eps=config.norm_eps,
        aux_rgb_head=config.aux_rgb_head,
    )


def build_baseline_generator(config: ModelConfig) -> AdaINUNet:
    """FSTH-like baseline (Table 4.2 'Baseline'): landmarks -> RGB through the AdaIN UNet, driven by z^s."""
    return AdaINUNet(
        in_channels=config.landmark_channels,
        out_channels=3,
        widths=layout_unet_widths(config),
        latent_dim=config.latent_dim,
        eps=config.norm_eps,
        aux_rgb_head=False,
    )
