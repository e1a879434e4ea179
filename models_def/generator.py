"""Image generator G^s: a SPADE generator with InstanceNorm (thesis §4.3.3, §4.6).

"32 feature maps at the last generator layer and 64 feature maps in each SPADE block ... The input to each
SPADE block is the concatenation of the predicted layout map and the facial landmarks" (§4.6). The style
latent z^s is mapped by a fully connected layer to the lowest-resolution input tensor (SPADE's VAE mode).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from models_def.blocks import LEAKY_GAIN, EqualConv2d, EqualLinear, leaky_relu
from models_def.config import ModelConfig
from models_def.norms import SPADE, SpadeConditionProjection


class SpadeResBlock(nn.Module):
    """SPADE residual block (Park et al. [133]) with ONE condition projection shared by its norms.

    x: (B, in, h, w), condition: (B, cond_channels, h, w) -> (B, out, h, w).
    main: SPADE -> lrelu -> conv3x3 -> SPADE -> lrelu -> conv3x3;  shortcut: SPADE -> conv1x1 (if in != out).
    With ``shared_input_modulation`` the shortcut reuses the main path's SPADE of x (both modulate the same x).
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        cond_channels: int,
        hidden_channels: int,
        eps: float,
        shared_input_modulation: bool,
    ) -> None:
        super().__init__()
        middle = min(in_channels, out_channels)
        self.projection = SpadeConditionProjection(cond_channels, hidden_channels)
        self.norm_0 = SPADE(in_channels, hidden_channels, eps)
        self.conv_0 = EqualConv2d(in_channels, middle, 3, gain=LEAKY_GAIN)
        self.norm_1 = SPADE(middle, hidden_channels, eps)
        self.conv_1 = EqualConv2d(middle, out_channels, 3, gain=LEAKY_GAIN)
        self.learned_shortcut = in_channels != out_channels
        self.norm_s = (
            SPADE(in_channels, hidden_channels, eps)
            if self.learned_shortcut and not shared_input_modulation
            else None
        )
        self.conv_s = EqualConv2d(in_channels, out_channels, 1, bias=False) if self.learned_shortcut else None

    def forward(self, x: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        hidden = self.projection(condition)  # (B, hidden, h, w), computed once per block
        modulated = self.norm_0(x, hidden)
        residual = self.conv_0(leaky_relu(modulated))
        residual = self.conv_1(leaky_relu(self.norm_1(residual, hidden)))
        if self.conv_s is None:
            return x + residual
        shortcut_input = modulated if self.norm_s is None else self.norm_s(x, hidden)
        return self.conv_s(shortcut_input) + residual


def condition_pyramid(condition: torch.Tensor, levels: int) -> list[torch.Tensor]:
    """[condition at H, H/2, ..., H/2**levels] by repeated 2x2 average pooling.

    SPADE resizes its condition with nearest-neighbour sampling, which drops thin landmark lines at low
    resolution; averaging keeps them (and is one cheap op per level).
    """
    pyramid = [condition]
    for _ in range(levels):
        pyramid.append(F.avg_pool2d(pyramid[-1], 2))  # (B, C, H / 2**i, W / 2**i)
    return pyramid


class SpadeGenerator(nn.Module):
    """G^s. forward(condition: (B, cond_channels, H, W), style_latent: (B, D)) -> image (B, 3, H, W) in [-1, 1]
    (warp_guided: (B, 3 + N + 1, H, W), the RGB in [-1, 1] then N + 1 raw blend logits).

    Blocks (SPADE 'normal', thesis widths x ``width``): fc(z^s) -> 512 @ H/32 -> head -> up -> middle x2 -> up
    -> 512->256 -> up -> 256->128 -> up -> 128->64 -> up -> 64->32 -> conv3x3 -> tanh.
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        ups = config.generator_upsamplings
        last = config.generator_last_channels
        top = config.capped(last * 2 ** (ups - 1))
        # Output widths of the blocks after each upsampling: the thesis' 512, 256, 128, 64, 32 at H/16 ... H.
        tail = [config.capped(last * 2 ** (ups - 1 - i)) for i in range(ups)]
        self.start_size = config.resolution // 2**ups
        self.start_channels = top
        self.upsamplings = ups
        self.style_to_input = EqualLinear(config.latent_dim, top * self.start_size**2)
        spade = dict(
            cond_channels=config.spade_condition_channels,
            hidden_channels=config.scaled(config.spade_hidden_channels),
            eps=config.norm_eps,
            shared_input_modulation=config.spade_shared_input_modulation,
        )
        self.head = SpadeResBlock(top, top, **spade)
        self.middle = SpadeResBlock(top, top, **spade)  # at H/16 (SPADE's G_middle_0)
        self.middle_2 = SpadeResBlock(top, top, **spade)  # at H/16 (SPADE's G_middle_1)
        widths = [top] + tail[1:]  # after the middle blocks, ups - 1 more upsampling blocks
        self.up_blocks = nn.ModuleList(SpadeResBlock(a, b, **spade) for a, b in zip(widths[:-1], widths[1:]))
        self.to_rgb = EqualConv2d(widths[-1], config.generator_output_channels, 3, gain=LEAKY_GAIN)

    def forward(self, condition: torch.Tensor, style_latent: torch.Tensor) -> torch.Tensor:
        pyramid = condition_pyramid(condition, self.upsamplings)  # index i: resolution H / 2**i
        batch = style_latent.shape[0]
        x = self.style_to_input(style_latent).view(batch, self.start_channels, self.start_size, self.start_size)
        x = self.head(x, pyramid[self.upsamplings])  # (B, top, H/32, W/32)
        x = F.interpolate(x, scale_factor=2.0, mode="nearest")
        x = self.middle(x, pyramid[self.upsamplings - 1])
        x = self.middle_2(x, pyramid[self.upsamplings - 1])  # (B, top, H/16, W/16)
        for index, block in enumerate(self.up_blocks):
            x = F.interpolate(x, scale_factor=2.0, mode="nearest")
            x = block(x, pyramid[self.upsamplings - 2 - index])
        output = self.to_rgb(leaky_relu(x))  # (B, 3 [+ N + 1 blend logits], H, W)
        rgb = torch.tanh(output[:, :3])
        return rgb if output.shape[1] == 3 else torch.cat([rgb, output[:, 3:]], dim=1)
