"""Building blocks shared by every LSR network.

* Equalised learning rate (thesis §4.6, "we follow [11] and use equalized learning rate in all of our
  networks"): weights are stored as N(0, 1) samples and scaled at run time by ``gain / sqrt(fan_in)``, as in
  rosinality/stylegan2-pytorch. Plain PyTorch, no custom kernels.
* Blur-pool (§4.6, "replacing average-pooling with blur-pooling"): a fixed 3x3 binomial low-pass filter
  applied depthwise with stride 2.
* The down-sampling residual block used by the encoders and the discriminator.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from kornia.filters.kernels import get_pascal_kernel_2d
from torch import nn

LEAKY_SLOPE = 0.2
# Gain that keeps the activation variance of a leaky ReLU at 1 (StyleGAN2). It is folded into the scale of
# the convolution that *follows* the activation, so it costs no extra full-resolution multiply.
LEAKY_GAIN = math.sqrt(2.0)


class EqualConv2d(nn.Module):
    """Conv2d with equalised learning rate: ``conv(x, weight * gain / sqrt(in * k * k)) + bias``.

    x: (B, in_channels, H, W) -> (B, out_channels, H', W'); "same" padding by default.
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int,
        *,
        stride: int = 1,
        bias: bool = True,
        gain: float = 1.0,
    ) -> None:
        super().__init__()
        self.in_channels, self.out_channels = in_channels, out_channels
        self.kernel_size, self.stride, self.padding = kernel_size, stride, kernel_size // 2
        self.weight = nn.Parameter(torch.randn(out_channels, in_channels, kernel_size, kernel_size))
        self.scale = gain / math.sqrt(in_channels * kernel_size * kernel_size)
        self.bias = nn.Parameter(torch.zeros(out_channels)) if bias else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.conv2d(x, self.weight * self.scale, self.bias, self.stride, self.padding)

    def extra_repr(self) -> str:
        return (
            f"{self.in_channels}, {self.out_channels}, k={self.kernel_size}, stride={self.stride}, "
            f"bias={self.bias is not None}, scale={self.scale:.4g}"
        )


class EqualLinear(nn.Module):
    """Linear layer with equalised learning rate. x: (B, in_features) -> (B, out_features)."""

    def __init__(
        self, in_features: int, out_features: int, *, bias: bool = True, bias_init: float = 0.0, gain: float = 1.0
    ) -> None:
        super().__init__()
        self.in_features, self.out_features = in_features, out_features
        self.weight = nn.Parameter(torch.randn(out_features, in_features))
        self.scale = gain / math.sqrt(in_features)
        self.bias = nn.Parameter(torch.full((out_features,), float(bias_init))) if bias else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.linear(x, self.weight * self.scale, self.bias)

    def extra_repr(self) -> str:
        return f"{self.in_features}, {self.out_features}, bias={self.bias is not None}, scale={self.scale:.4g}"


class BlurPool2d(nn.Module):
    """Anti-aliased 2x down-sampling: 3x3 binomial blur ([1, 2, 1] outer product / 16), stride 2.

    x: (B, C, H, W) with H, W >= 2 -> (B, C, ceil(H / 2), ceil(W / 2)). Reflect padding keeps borders
    unbiased (zero padding would darken them). The kernel is a non-persistent buffer: not in the weights file.
    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.channels = channels
        kernel = get_pascal_kernel_2d(3, norm=True).reshape(1, 1, 3, 3).repeat(channels, 1, 1, 1)  # (C, 1, 3, 3)
        self.register_buffer("kernel", kernel, persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.pad(x, (1, 1, 1, 1), mode="reflect")
        return F.conv2d(x, self.kernel.to(x.dtype), stride=2, groups=self.channels)

    def extra_repr(self) -> str:
        return f"{self.channels}"


def leaky_relu(x: torch.Tensor) -> torch.Tensor:
    return F.leaky_relu(x, LEAKY_SLOPE)


class DownResBlock(nn.Module):
    """StyleGAN2-style residual block that halves the resolution (encoders and discriminator, §4.6).

    main: conv3x3(in->in) -> lrelu -> blur-pool -> conv3x3(in->out) -> lrelu
    skip: blur-pool -> conv1x1(in->out, no bias)
    out = (main + skip) / sqrt(2)   (keeps unit variance, StyleGAN2)

    The convolution is applied after the blur-pool so that the costly out-channel conv runs at the low
    resolution. x: (B, in, H, W) -> (B, out, ceil(H/2), ceil(W/2)).
    """

    def __init__(self, in_channels: int, out_channels: int) -> None:
        super().__init__()
        # Inputs to conv_0 and skip come after an lrelu in the previous block, hence LEAKY_GAIN.
        self.conv_0 = EqualConv2d(in_channels, in_channels, 3, gain=LEAKY_GAIN)
        self.blur_main = BlurPool2d(in_channels)
        self.conv_1 = EqualConv2d(in_channels, out_channels, 3, gain=LEAKY_GAIN)
        self.blur_skip = BlurPool2d(in_channels)
        self.skip = EqualConv2d(in_channels, out_channels, 1, bias=False, gain=LEAKY_GAIN)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        main = leaky_relu(self.conv_0(x))
        main = leaky_relu(self.conv_1(self.blur_main(main)))
        skip = self.skip(self.blur_skip(x))
        return (main + skip) * (1.0 / math.sqrt(2.0))


def channel_softmax(x: torch.Tensor) -> torch.Tensor:
    """Softmax over the channels (dim 1) of (B, C, H, W), written out: the values of ``x.softmax(dim=1)`` up to float
    rounding. ONNX Runtime runs a Softmax on a non-last axis through transposes: the default's two (the layout's 19
    classes, the blend's 6 candidates) took 15 % of its frame time; these reductions run along the channels in place."""
    shifted = x - x.amax(dim=1, keepdim=True)
    exp = shifted.exp()
    return exp / exp.sum(dim=1, keepdim=True)

