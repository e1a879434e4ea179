"""Subject encoding: the two-headed encoder E = {E^l, E^s} and K-shot latent averaging (thesis §4.3.1, §4.6).

Design choice: by default E^l and E^s share one ResNet trunk and differ only in their final fully connected
layer ("a two-headed encoder", §4.3.1). This halves the cost of encoding a subject; ``share_encoder_trunk=False``
gives two separate trunks (the literal reading of §4.6, "a resnet encoder for both ... encoders").
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from models_def.blocks import LEAKY_GAIN, DownResBlock, EqualConv2d, EqualLinear, leaky_relu
from models_def.config import ModelConfig
from models_def.shapes import check_shape


class ResNetTrunk(nn.Module):
    """fromRGB conv -> ``encoder_downsamplings`` blur-pool residual blocks (32 maps, doubling, max 512) -> mean.

    x: (N, in_channels, H, W) -> (N, trunk_channels). Spatial mean pooling keeps the trunk resolution-agnostic.
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        base = config.encoder_base_channels
        widths = [config.capped(base * 2**i) for i in range(config.encoder_downsamplings + 1)]
        self.from_input = EqualConv2d(config.encoder_input_channels, widths[0], 3)
        self.blocks = nn.Sequential(*(DownResBlock(a, b) for a, b in zip(widths[:-1], widths[1:])))
        self.out_channels = widths[-1]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        features = self.blocks(leaky_relu(self.from_input(x)))  # (N, C, H / 32, W / 32)
        return leaky_relu(features).mean(dim=(2, 3))  # (N, C)


class TwoHeadedEncoder(nn.Module):
    """Per-shot encoder. shot_input: (N, 3 + landmark_channels, H, W) -> (layout_latent, style_latent), each (N, D)."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.layout_trunk = ResNetTrunk(config)
        # None when shared: registering the same trunk twice would duplicate its weights in the state dict.
        self.style_trunk = None if config.share_encoder_trunk else ResNetTrunk(config)
        channels = self.layout_trunk.out_channels
        # The trunk output went through an lrelu, hence LEAKY_GAIN.
        self.layout_head = EqualLinear(channels, config.latent_dim, gain=LEAKY_GAIN)  # E^l
        self.style_head = EqualLinear(channels, config.latent_dim, gain=LEAKY_GAIN)  # E^s

    def forward(self, shot_input: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        layout_features = self.layout_trunk(shot_input)
        style_features = layout_features if self.style_trunk is None else self.style_trunk(shot_input)
        return self.layout_head(layout_features), self.style_head(style_features)


def encode_k_shots(
    encoder: Callable[[torch.Tensor], torch.Tensor | tuple[torch.Tensor, ...]], shots: torch.Tensor
) -> torch.Tensor | tuple[torch.Tensor, ...]:
    """Encode K shots per subject and average the K latents (thesis eqs. 4.1 and 4.3: z = 1/K sum_i E(I_i)).

    shots: (B, K, C, H, W). ``encoder`` maps (N, C, H, W) to (N, D) or a tuple of (N, D_j).
    Returns (B, D) (or a tuple of (B, D_j)): K is folded into the batch, encoded once, unfolded, averaged.
    """
    check_shape("shots", shots, ("B", "K", "C", "H", "W"))
    batch, shots_per_subject = shots.shape[0], shots.shape[1]
    encoded = encoder(shots.flatten(0, 1))  # (B * K, D) or tuple thereof

    def average(latents: torch.Tensor) -> torch.Tensor:
        return latents.unflatten(0, (batch, shots_per_subject)).mean(dim=1)  # (B, K, D) -> (B, D)

    if isinstance(encoded, tuple):
        return tuple(average(latents) for latents in encoded)
    return average(encoded)


class SubjectEncoder(nn.Module):
    """Subject encoding graph: K shots and their landmark images -> averaged (layout_latent, style_latent).

    Run once per subject; its outputs are the per-frame generator's latent inputs.
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = TwoHeadedEncoder(config)

    def forward(
        self, shots: torch.Tensor, shot_landmark_images: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """shots: (B, K, 3, H, W) float in [-1, 1]; shot_landmark_images: (B, K, landmark_channels, H, W) in [-1, 1].

        Values outside [-1, 1] are clamped.

        Returns layout_latent z^l and style_latent z^s, each (B, latent_dim).
        """
        size = self.config.resolution
        check_shape("shots", shots, ("B", "K", 3, size, size))
        check_shape(
            "shot_landmark_images",
            shot_landmark_images,
            (shots.shape[0], shots.shape[1], self.config.landmark_channels, size, size),
        )
        # Out-of-range values are clamped to the contract: +-1e4 inputs would overflow float16 activations.
        shot_inputs = torch.cat([shots, shot_landmark_images], dim=2).clamp(-1.0, 1.0)  # (B, K, 3 + C_lm, H, W)
        layout_latent, style_latent = encode_k_shots(self.encoder, shot_inputs)
        return layout_latent, style_latent
