"""The warp-guided composite: G^s's output blended with the nearest shots warped onto the target (thesis §4.5.6).

A per-pixel softmax over N + 1 candidates (the N warped references and the generated image) gives each its
weight, so the network chooses, pixel by pixel, which reference is best aligned and where only synthesis
helps (an open mouth no shot shows, the region a warp leaves empty). Invalid reference pixels (the warp
sampled outside the shot) are pushed out of the softmax. The blend runs at the references' resolution:
the network may run lower (its RGB and logits are upsampled), so that detail comes from the shots.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

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
    if not _blurs_at_half_resolution(images, sigma):
        return gaussian_blur(images, sigma)
    small = gaussian_blur(F.avg_pool2d(images, 2), _half_resolution_sigma(sigma))
    return F.interpolate(small, scale_factor=2.0, mode="bilinear", align_corners=False)


def _blurs_at_half_resolution(images: torch.Tensor, sigma: float) -> bool:
    return sigma >= HALF_RESOLUTION_MIN_SIGMA and images.shape[-2] % 2 == 0 and images.shape[-1] % 2 == 0


def _half_resolution_sigma(sigma: float) -> float:
    """The Gaussian left to apply after a 2x2 mean and before a bilinear 2x upsampling, in half-resolution pixels."""
    return math.sqrt(sigma**2 - 0.25 - 0.125) / 2.0


# onnxruntime's CPU convolutions, pools and resizes run in blocks of 8 (AVX2) or 16 (AVX-512) channels (its NCHWc
# layout). A depthwise blur or a bilinear resize whose channel count is off that grid runs a plain per-channel loop
# instead: 15 reference channels at 128^2, blurred and upsampled 2x, took 2.0 ms against 0.8 ms for 16 (one thread).
CHANNEL_BLOCK = 16


def blocked_low_band(images: torch.Tensor, sigma: float, pooled: torch.Tensor | None = None) -> torch.Tensor:
    """``low_band`` of (B, C, H, W) with the channels zero-padded to a multiple of CHANNEL_BLOCK: -> (B, C', H, W),
    C' >= C, whose first C channels are ``low_band(images, sigma)`` up to float rounding and the rest zeros. A caller
    splits the channels it needs off the result (one Split in ONNX, no Slice copy first). ``pooled``: the 2x2 mean
    ``F.avg_pool2d(images, 2)`` when the caller has it already (used only on the half-resolution branch)."""
    padding = (0, 0, 0, 0, 0, (-images.shape[1]) % CHANNEL_BLOCK)
    if not _blurs_at_half_resolution(images, sigma):
        return gaussian_blur(F.pad(images, padding), sigma)
    small = F.avg_pool2d(images, 2) if pooled is None else pooled
    small = gaussian_blur(F.pad(small, padding), _half_resolution_sigma(sigma))
    return F.interpolate(small, scale_factor=2.0, mode="bilinear", align_corners=False)


def _median3(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    return torch.maximum(torch.minimum(x, y), torch.minimum(torch.maximum(x, y), z))


def median_of(values: Sequence[torch.Tensor]) -> torch.Tensor:
    """Elementwise median of 1, 3 or 5 same-shaped tensors (min/max networks; see ``median_over_references``)."""
    if len(values) == 1:
        return values[0]
    if len(values) == 3:
        return _median3(*values)
    if len(values) == 5:
        a, b, c, d, e = values
        low_of_high = torch.minimum(torch.maximum(a, b), torch.maximum(c, d))  # not the largest of a..d
        high_of_low = torch.maximum(torch.minimum(a, b), torch.minimum(c, d))  # not the smallest of a..d
        return _median3(e, high_of_low, low_of_high)
    raise ValueError(f"median_of takes 1, 3 or 5 tensors, got {len(values)}; use median_over_references for others")


def median_over_references(values: torch.Tensor) -> torch.Tensor:
    """Per-pixel median over dim 1 of (B, N, ...) -> (B, ...); an even N gives the mean of the two middle values.

    N = 3 and 5 (the shipped default) use min/max networks (the median of 5 is the median of the fifth value and the
    two middle candidates of the first four): elementwise, 30x faster than a sort in torch eager, and exported to
    ONNX as Min/Max nodes. Other N sort."""
    count = values.shape[1]
    if count in (1, 3, 5):
        return median_of(values.unbind(1))
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


def blend_with_reference_detail(references: torch.Tensor, reference_masks: torch.Tensor, generated: torch.Tensor,
                                blend_logits: torch.Tensor, detail_sigma: float,
                                half_references: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """``blend_references``, then ``add_reference_detail`` when ``detail_sigma`` > 0: the same (image, weights) up to
    float rounding, written as fewer and larger ops for the exported frame graph (``FrameGenerator`` traces it for
    ONNX; eager runs the two reference functions, which tests/models_def/test_composite_fused.py compares with this).

    Shapes as ``blend_references``; reference_masks must be in [0, 1] already (``FrameGenerator`` clamps its inputs
    once). ``half_references``: (B, 3N, H/2, W/2), the references' 2x2 mean, when the caller has pooled it already
    (``FrameGenerator`` pools the network's input from it). What differs from the reference functions, and why
    (onnxruntime, 5 references at 256^2):
    * each reference is taken on its own (one Split of the references, one of the masks, one of the upsampled logits):
      its penalised logit, exp and weighted RGB are 1- and 3-channel maps, where the reference functions Mul and
      ReduceSum a (B, N, 3, H, W) tensor (about 2x slower in onnxruntime than the sum of N products), ReduceMax and
      ReduceSum over N + 1 channels and Split the details again for the median;
    * the penalty's constant -30 is applied to the low-resolution logits before their upsampling (bilinear keeps a
      constant);
    * the softmax's normalisation is applied once, to the blended RGB (3 channels) and to the references' share of
      the blend (1), not to the N + 1 weights (the weights returned are unused by the exported graph and pruned);
    * the references' low band is blurred and upsampled in a block of 16 channels (``blocked_low_band``), from the
      2x2 mean the caller may have pooled already.
    -> (image (B, 3, H, W), clamped to [-1, 1] when the detail is added; weights (B, N + 1, H, W))."""
    batch, count, _, height, width = references.shape
    check_shape("reference_masks", reference_masks, (batch, count, 1, height, width))
    check_shape("blend_logits", blend_logits, (batch, count + 1, "h", "w"))
    check_shape("generated", generated, (batch, 3, blend_logits.shape[2], blend_logits.shape[3]))

    def upsampled(low: torch.Tensor) -> torch.Tensor:
        if low.shape[2:] == (height, width):
            return low
        return F.interpolate(low, size=(height, width), mode="bilinear", align_corners=False)

    # blend_references: softmax over [reference logits + penalty * (mask - 1), generated logit], one reference at a
    # time: N products, sums and maxima of 1-channel maps cost less than a Mul, a ReduceMax and a ReduceSum over N
    each_reference, each_mask = references.unbind(1), reference_masks.unbind(1)  # N x (B, 3 | 1, H, W)
    each_logit = upsampled(blend_logits[:, :count] - INVALID_LOGIT_PENALTY).split(1, dim=1)  # N x (B, 1, H, W)
    each_logit = [logit + INVALID_LOGIT_PENALTY * mask for logit, mask in zip(each_logit, each_mask)]
    generated_logit, generated = upsampled(blend_logits[:, count:]), upsampled(generated)  # (B, 1 | 3, H, W)
    top = generated_logit
    for logit in each_logit:
        top = torch.maximum(top, logit)
    each_exp = [(logit - top).exp() for logit in each_logit]
    generated_exp = (generated_logit - top).exp()
    reference_total, blended = each_exp[0], generated_exp * generated
    for exp in each_exp[1:]:
        reference_total = reference_total + exp
    normaliser = 1.0 / (reference_total + generated_exp)  # (B, 1, H, W)
    weights = torch.cat([*each_exp, generated_exp], dim=1) * normaliser  # (B, N + 1, H, W); unused by the graph
    for reference, exp in zip(each_reference, each_exp):
        blended = blended + exp * reference
    image = blended * normaliser  # (B, 3, H, W)
    if detail_sigma <= 0:
        return image, weights
    # add_reference_detail: low band of the blend + (1 - generated weight) * median of the references' masked detail
    each_low = blocked_low_band(references.flatten(1, 2), detail_sigma, half_references).split(3, dim=1)  # >= N
    details = [(reference - reference_low) * mask
               for reference, reference_low, mask in zip(each_reference, each_low, each_mask)]
    median = median_of(details) if count in (1, 3, 5) else median_over_references(torch.stack(details, dim=1))
    reference_share = reference_total * normaliser  # 1 - the generated image's weight
    return (low_band(image, detail_sigma) + reference_share * median).clamp(-1.0, 1.0), weights
