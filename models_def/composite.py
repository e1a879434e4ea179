"""The warp-guided composite: G^s's output blended with the nearest shots warped onto the target (thesis §4.5.6).

A per-pixel softmax over N + 1 candidates (the N warped references and the generated image) gives each its
weight, so the network chooses, pixel by pixel, which reference is best aligned and where only synthesis
helps (an open mouth no shot shows, the region a warp leaves empty). Invalid reference pixels (the warp
sampled outside the shot) are pushed out of the softmax. The blend runs at the references' resolution:
the network may run lower (its RGB and logits are upsampled), so that detail comes from the shots.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from models_def.blocks import channel_softmax
from models_def.shapes import check_shape

# The flow outputs are multiplied by this before the tanh: with Adam, the flow rows of G^s's last conv then learn
# FLOW_GAIN times faster than the blend logits beside them (without it a warm-started flow head stays near zero:
# mean |w| 0.0013 against the logits' 0.14 after 900 steps). Zero weights are still the identity.
FLOW_GAIN = 10.0

# Added to the logit of an invalid reference pixel: e^-30 ~ 1e-13 of the weight, finite in fp16 and ONNX.
INVALID_LOGIT_PENALTY = 30.0


def blend_references(
    references: torch.Tensor,
    reference_masks: torch.Tensor,
    generated: torch.Tensor,
    blend_logits: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """references: (B, N, 3, H, W) in [-1, 1]; reference_masks: (B, N, 1, H, W) in [0, 1] (1 = valid);
    generated: (B, 3, h, w) in [-1, 1]; blend_logits: (B, N + 1, h, w), the last one the generated image's
    -> (image (B, 3, H, W), weights (B, N + 1, H, W) summing to 1). h, w may be lower than H, W (bilinear)."""
    batch, count, _, height, width = references.shape
    check_shape("reference_masks", reference_masks, (batch, count, 1, height, width))
    check_shape("blend_logits", blend_logits, (batch, count + 1, "h", "w"))
    check_shape("generated", generated, (batch, 3, blend_logits.shape[2], blend_logits.shape[3]))
    if blend_logits.shape[2:] != (height, width):
        blend_logits = F.interpolate(blend_logits, size=(height, width), mode="bilinear", align_corners=False)
        generated = F.interpolate(generated, size=(height, width), mode="bilinear", align_corners=False)
    masks = reference_masks[:, :, 0].clamp(0.0, 1.0)  # (B, N, H, W)
    reference_logits = blend_logits[:, :count] + INVALID_LOGIT_PENALTY * (masks - 1.0)
    weights = channel_softmax(torch.cat([reference_logits, blend_logits[:, count:]], dim=1))  # (B, N + 1, H, W)
    image = (weights[:, :count, None] * references).sum(dim=1) + weights[:, count:] * generated  # (B, 3, H, W)
    return image, weights


def shift_references(references: torch.Tensor, reference_masks: torch.Tensor, flow: torch.Tensor,
                     max_shift: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Resample each warped reference (and its mask) by a residual flow G^s predicts: the correction of the landmark
    TPS where its sparse points leave the warp wrong (mouth, jaw, hair edge).

    references: (B, N, 3, H, W); reference_masks: (B, N, 1, H, W); flow: (B, 2N, h, w) raw outputs (x then y per
    reference; bilinearly upsampled to H, W), times ``FLOW_GAIN``, bounded by tanh to ``max_shift`` of the crop
    side. Zero flow is the identity (up to float rounding). -> (references, masks) of the same shapes. ONNX parity
    of a flow model is 1e-3, not 1e-4: FLOW_GAIN amplifies the runtimes' rounding of the raw flow."""
    batch, count, _, height, width = references.shape
    check_shape("flow", flow, (batch, 2 * count, "h", "w"))
    if flow.shape[2:] != (height, width):
        flow = F.interpolate(flow, size=(height, width), mode="bilinear", align_corners=False)
    offsets = torch.tanh(FLOW_GAIN * flow) * (2.0 * max_shift)  # grid units: the crop side spans 2
    offsets = offsets.view(batch * count, 2, height, width).permute(0, 2, 3, 1)  # (B*N, H, W, 2) x, y
    ys = (torch.arange(height, dtype=flow.dtype, device=flow.device) + 0.5) * (2.0 / height) - 1.0
    xs = (torch.arange(width, dtype=flow.dtype, device=flow.device) + 0.5) * (2.0 / width) - 1.0
    identity = torch.stack(torch.meshgrid(xs, ys, indexing="xy"), dim=-1)  # (H, W, 2) pixel centres
    grid = identity[None] + offsets
    stacked = torch.cat([references, reference_masks], dim=2).flatten(0, 1)  # (B*N, 4, H, W)
    moved = F.grid_sample(stacked, grid, mode="bilinear", padding_mode="border", align_corners=False)
    moved = moved.view(batch, count, 4, height, width)
    return moved[:, :, :3], moved[:, :, 3:]


def gaussian_blur(images: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of (B, C, H, W) with a ``sigma``-pixel kernel (radius ceil(3 sigma), reflect padding).

    Two depthwise convolutions with a fixed kernel. The channel count is read as a Python int, so an ONNX trace
    keeps the kernel's shape static (C is a model constant: 3 for an image, 3N for N references); torch eager runs
    a depthwise conv ~6x faster than the same blur as C separate 1-channel planes."""
    radius = max(1, math.ceil(3.0 * sigma))
    radius = min(radius, images.shape[-1] - 1, images.shape[-2] - 1)  # reflect padding needs radius < side
    taps = torch.arange(-radius, radius + 1, dtype=images.dtype, device=images.device)
    kernel = torch.exp(-0.5 * (taps / sigma) ** 2)
    kernel = kernel / kernel.sum()
    channels = int(images.shape[1])
    padded = F.pad(images, (radius, radius, radius, radius), mode="reflect")
    rows = F.conv2d(padded, kernel.view(1, 1, 1, -1).repeat(channels, 1, 1, 1), groups=channels)
    return F.conv2d(rows, kernel.view(1, 1, -1, 1).repeat(channels, 1, 1, 1), groups=channels)


# From this blur width up, ``low_band`` blurs at half resolution: ~7x fewer multiply-adds, and at sigma 3 px (the
# default's detail split at 256^2) its result is within 55 dB PSNR of the exact blur on real faces.
HALF_RESOLUTION_MIN_SIGMA = 2.0


def low_band(images: torch.Tensor, sigma: float) -> torch.Tensor:
    """``gaussian_blur`` of (B, C, H, W), made at half resolution when ``sigma`` >= HALF_RESOLUTION_MIN_SIGMA and
    H, W are even: a 2x2 mean, a Gaussian of the remaining width (the mean and the bilinear upsampling each blur by
    a variance of about 1/4 px^2, resp. 1/8 px^2 on average, at full resolution), then a bilinear 2x upsampling.
    Below that width, or for odd sides, the exact ``gaussian_blur``. Depthwise convs are the slowest op of the
    ONNX frame graph on a CPU; this takes the detail split at 256^2 from ~8 ms to ~2 ms of it."""
    height, width = images.shape[-2:]
    if sigma < HALF_RESOLUTION_MIN_SIGMA or height % 2 or width % 2:
        return gaussian_blur(images, sigma)
    remaining = math.sqrt(sigma**2 - 0.25 - 0.125) / 2.0  # in half-resolution pixels
    small = gaussian_blur(F.avg_pool2d(images, 2), remaining)
    return F.interpolate(small, scale_factor=2.0, mode="bilinear", align_corners=False)


def _median3(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    return torch.maximum(torch.minimum(x, y), torch.minimum(torch.maximum(x, y), z))


def median_over_references(values: torch.Tensor) -> torch.Tensor:
    """Per-pixel median over dim 1 of (B, N, ...) -> (B, ...); an even N gives the mean of the two middle values.

    N = 3 and 5 (the shipped default) use min/max networks (the median of 5 is the median of the fifth value and the
    two middle candidates of the first four): elementwise, 30x faster than a sort in torch eager, and exported to
    ONNX as Min/Max nodes. Other N sort."""
    count = values.shape[1]
    if count == 1:
        return values[:, 0]
    if count == 3:
        return _median3(*values.unbind(1))
    if count == 5:
        a, b, c, d, e = values.unbind(1)
        low_of_high = torch.minimum(torch.maximum(a, b), torch.maximum(c, d))  # not the largest of a..d
        high_of_low = torch.maximum(torch.minimum(a, b), torch.minimum(c, d))  # not the smallest of a..d
        return _median3(e, high_of_low, low_of_high)
    ordered = values.sort(dim=1).values
    middle = count // 2
    return ordered[:, middle] if count % 2 else 0.5 * (ordered[:, middle - 1] + ordered[:, middle])


def add_reference_detail(image: torch.Tensor, references: torch.Tensor, reference_masks: torch.Tensor,
                         generated_weight: torch.Tensor, sigma: float) -> torch.Tensor:
    """The blend's fine detail replaced by the references' consensus detail.

    A soft blend of several warps is blurred where they disagree by a pixel or two; one warp alone is sharp but its
    misplacements cost more than the blur. This keeps the blend's low band (a Gaussian of ``sigma`` pixels,
    ``low_band``) and adds the per-pixel median of the references' high bands: detail that most warps agree on
    survives at full contrast, detail only one of them has is dropped. Scaled by the references' share of the blend (none where G^s's own image
    is used). image: (B, 3, H, W); references: (B, N, 3, H, W); reference_masks: (B, N, 1, H, W); generated_weight:
    (B, 1, H, W) -> (B, 3, H, W), clamped to [-1, 1]. The median of an even N is the mean of the two middle values.
    """
    batch, count, _, height, width = references.shape
    check_shape("image", image, (batch, 3, height, width))
    check_shape("generated_weight", generated_weight, (batch, 1, height, width))
    stacked = references.flatten(1, 2)  # (B, 3N, H, W): one depthwise blur for all references
    details = (stacked - low_band(stacked, sigma)).view(batch, count, 3, height, width) * reference_masks
    median = median_over_references(details)
    return (low_band(image, sigma) + (1.0 - generated_weight) * median).clamp(-1.0, 1.0)
