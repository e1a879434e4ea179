"""The two conditional normalisations of LSR: AdaIN (layout UNet G^l, baseline) and SPADE (image generator G^s).

Both follow the NVlabs/SPADE ``normalization.py`` pattern: a parameter-free InstanceNorm, then a small
network on the condition gives (gamma, beta), then ``x * (1 + gamma) + beta``. Residual blocks only compose
these modules.

Cost note (measured, see ``lsr bench models``): SPADE's per-pixel convolutions dominate the generator
(52 of 70 GFLOP at 256^2 with one hidden projection per norm). The hidden projection depends only on the
condition, so each residual block computes it ONCE (``SpadeConditionProjection``) and hands it to all of its
SPADE norms; the per-norm 3x3 gamma/beta heads stay as in SPADE.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from models_def.blocks import EqualConv2d, EqualLinear

DEFAULT_EPS = 1e-5


def centered_and_inv_std(x: torch.Tensor, eps: float = DEFAULT_EPS) -> tuple[torch.Tensor, torch.Tensor]:
    """x - mean (B, C, H, W) and 1 / sqrt(var + eps) (B, C, 1, 1), per (b, c), in x's dtype.

    Plain mean reductions keep channels-last inputs channels-last (``F.instance_norm`` copies them to NCHW
    and back; ``torch.var_mean`` is 10x slower than two means on this CPU). Centring first keeps the variance
    exact for large offsets. Half-precision inputs get float32 statistics: the variance of values around 1e3
    already overflows float16. A constant map has zero variance; ``eps`` makes its output 0, never NaN.
    """
    work = x.float() if x.dtype in (torch.float16, torch.bfloat16) else x
    centered = work - work.mean(dim=(2, 3), keepdim=True)
    inv_std = torch.rsqrt((centered * centered).mean(dim=(2, 3), keepdim=True) + eps)
    return centered.to(x.dtype), inv_std.to(x.dtype)


def instance_norm(x: torch.Tensor, eps: float = DEFAULT_EPS) -> torch.Tensor:
    """Parameter-free InstanceNorm. x: (B, C, H, W) -> same shape, zero mean / unit variance per (b, c).

    Traced for ONNX, it is one InstanceNormalization node: onnxruntime runs it as one kernel, where the eager ops
    (two means, a subtraction, a square, an epsilon, a root, a reciprocal and a product) are eight nodes, most of
    them a pass over x; 32 norms in the default frame graph. Eager keeps ``centered_and_inv_std`` (channels-last
    friendly, float32 statistics)."""
    if torch.onnx.is_in_onnx_export():
        return F.instance_norm(x, eps=eps)
    centered, inv_std = centered_and_inv_std(x, eps)
    return centered * inv_std


def modulate(normalized: torch.Tensor, scale: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """``normalized * scale + shift``: ``torch.addcmul`` in eager (one fused kernel); a Mul and an Add traced for
    ONNX, where addcmul exports as three nodes (its multiplier of 1 is a Mul of its own: one more pass over the
    activations)."""
    if torch.onnx.is_in_onnx_export():
        return normalized * scale + shift
    return torch.addcmul(shift, normalized, scale)


class AdaIN(nn.Module):
    """Adaptive instance normalisation (Huang & Belongie [132]) driven by a latent code.

    x: (B, C, H, W), latent: (B, D) -> (B, C, H, W).
    gamma, beta come from one equalised linear layer; gamma is a residual scale (initially 0 => identity IN).
    """

    def __init__(self, channels: int, latent_dim: int, eps: float = DEFAULT_EPS) -> None:
        super().__init__()
        self.channels, self.eps = channels, eps
        self.to_gamma_beta = EqualLinear(latent_dim, 2 * channels)

    def forward(self, x: torch.Tensor, latent: torch.Tensor) -> torch.Tensor:
        # split, not chunk: static sizes, where chunk traces its sizes from the tensor's shape (six more ONNX nodes)
        gamma, beta = self.to_gamma_beta(latent)[:, :, None, None].split([self.channels, self.channels], dim=1)
        if torch.onnx.is_in_onnx_export():  # one InstanceNormalization node (see instance_norm)
            return modulate(instance_norm(x, self.eps), 1.0 + gamma, beta)  # 2 x (B, C, 1, 1)
        centered, inv_std = centered_and_inv_std(x, self.eps)
        # (x - mean) * inv_std * (1 + gamma) + beta with the per-channel factors folded: one pass over x.
        return torch.addcmul(beta, centered, inv_std * (1.0 + gamma))


class SpadeConditionProjection(nn.Module):
    """SPADE's shared hidden layer: conv3x3 + ReLU on the condition map (``mlp_shared`` in NVlabs/SPADE).

    condition: (B, cond_channels, H, W), already at the resolution of the block -> (B, hidden, H, W).
    One instance per residual block; its output feeds every SPADE norm of that block.
    """

    def __init__(self, cond_channels: int, hidden_channels: int) -> None:
        super().__init__()
        self.conv = EqualConv2d(cond_channels, hidden_channels, 3)

    def forward(self, condition: torch.Tensor) -> torch.Tensor:
        return F.relu(self.conv(condition))


class SPADE(nn.Module):
    """Spatially-adaptive denormalisation (Park et al. [133]) with InstanceNorm (thesis §4.6).

    x: (B, C, H, W), hidden: (B, hidden_channels, H, W) from ``SpadeConditionProjection`` -> (B, C, H, W).
    gamma and beta come from ONE 3x3 conv producing 2C channels (same FLOPs as two convs, one kernel call).
    Output = InstanceNorm(x) * (1 + gamma) + beta, as in NVlabs/SPADE.
    """

    def __init__(self, channels: int, hidden_channels: int, eps: float = DEFAULT_EPS) -> None:
        super().__init__()
        self.channels, self.eps = channels, eps
        self.to_gamma_beta = EqualConv2d(hidden_channels, 2 * channels, 3)
        one_plus = torch.cat([torch.ones(channels), torch.zeros(channels)])
        self.register_buffer("one_plus", one_plus, persistent=False)

    def forward(self, x: torch.Tensor, hidden: torch.Tensor) -> torch.Tensor:
        head = self.to_gamma_beta
        # The "+1" of (1 + gamma) is added to the gamma half of the conv bias (2C values, not H*W*C).
        bias = head.bias + self.one_plus.to(head.bias.dtype)
        scale_and_beta = F.conv2d(hidden, head.weight * head.scale, bias, 1, head.padding)  # (B, 2C, h, w)
        scale, beta = scale_and_beta.split([self.channels, self.channels], dim=1)  # static sizes (see AdaIN)
        return modulate(instance_norm(x, self.eps), scale, beta)  # x_norm * (1 + gamma) + beta
