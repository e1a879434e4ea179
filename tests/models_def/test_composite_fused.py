"""The exported frame graph's math (issue 65) against the reference math it replaces, within float tolerance.

``FrameGenerator`` traces ``blend_with_reference_detail``, ``blocked_low_band``, one InstanceNormalization per norm
and ``modulate`` for ONNX, and runs ``blend_references`` + ``add_reference_detail`` and the decomposed norms in eager
(their frames are recorded bit for bit). These tests pin that both compute the same images: the functions on random
inputs in float64 (the math) and float32 (the rounding), and the whole module with the export path switched on.
"""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from models_def import LSRModel, preset_config
from models_def.composite import (
    CHANNEL_BLOCK,
    HALF_RESOLUTION_MIN_SIGMA,
    add_reference_detail,
    blend_references,
    blend_with_reference_detail,
    blocked_low_band,
    low_band,
    median_of,
    median_over_references,
)

TOLERANCE = {torch.float64: 1e-10, torch.float32: 2e-5}


def _composite_inputs(count: int, side: int, logit_side: int, dtype: torch.dtype, *, soft_masks: bool, spread: float,
                      seed: int = 0):
    generator = torch.Generator().manual_seed(seed)
    references = (torch.rand(2, count, 3, side, side, generator=generator, dtype=dtype) * 2 - 1)
    masks = torch.rand(2, count, 1, side, side, generator=generator, dtype=dtype)
    masks = masks if soft_masks else (masks > 0.2).to(dtype)
    generated = torch.rand(2, 3, logit_side, logit_side, generator=generator, dtype=dtype) * 2 - 1
    logits = torch.randn(2, count + 1, logit_side, logit_side, generator=generator, dtype=dtype) * spread
    return references, masks, generated, logits


def _reference(references, masks, generated, logits, sigma):
    image, weights = blend_references(references, masks, generated, logits)
    if sigma > 0:
        image = add_reference_detail(image, references, masks, weights[:, references.shape[1]:], sigma)
    return image, weights


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
@pytest.mark.parametrize(
    ("count", "side", "logit_side", "sigma", "soft_masks"),
    [
        (5, 32, 8, 3.0, False),  # the shipped default's shape: 4x upsampled logits, 5 references, half-res low band
        (5, 32, 16, 3.0, True),  # soft masks, 2x logits
        (3, 24, 24, 2.5, False),  # logits at the blend's side (no upsampling)
        (2, 16, 8, 3.0, True),  # an even count: the median sorts
        (1, 16, 8, 2.0, False),
        (5, 32, 8, HALF_RESOLUTION_MIN_SIGMA / 2, True),  # narrow split: the exact full-resolution blur
        (3, 15, 15, 3.0, False),  # an odd side: the exact blur
        (5, 32, 8, 0.0, True),  # no detail: the blend alone
    ],
)
def test_fused_composite_matches_the_reference_functions(dtype, count, side, logit_side, sigma, soft_masks):
    inputs = _composite_inputs(count, side, logit_side, dtype, soft_masks=soft_masks, spread=3.0)
    expected_image, expected_weights = _reference(*inputs, sigma)
    image, weights = blend_with_reference_detail(*inputs, sigma)
    tolerance = TOLERANCE[dtype]
    torch.testing.assert_close(image, expected_image, atol=tolerance, rtol=0)
    torch.testing.assert_close(weights, expected_weights, atol=tolerance, rtol=0)


@pytest.mark.parametrize("spread", [40.0, 200.0], ids=["wide", "extreme"])
def test_fused_composite_keeps_the_reference_on_far_apart_logits(spread):
    """The reference takes the max over the penalised N + 1 logits; the fused one shifts the penalty's constant to the
    low-resolution logits. Both must stay finite and agree where one candidate dominates by far."""
    inputs = _composite_inputs(5, 32, 8, torch.float32, soft_masks=False, spread=spread, seed=3)
    expected_image, expected_weights = _reference(*inputs, 3.0)
    image, weights = blend_with_reference_detail(*inputs, 3.0)
    assert torch.isfinite(image).all() and torch.isfinite(weights).all()
    torch.testing.assert_close(image, expected_image, atol=1e-4, rtol=0)
    torch.testing.assert_close(weights, expected_weights, atol=1e-5, rtol=0)


def test_fused_composite_reuses_pooled_references():
    references, masks, generated, logits = _composite_inputs(5, 32, 8, torch.float64, soft_masks=False, spread=3.0)
    half = F.avg_pool2d(references.flatten(1, 2), 2)
    pooled, _ = blend_with_reference_detail(references, masks, generated, logits, 3.0, half)
    torch.testing.assert_close(pooled, blend_with_reference_detail(references, masks, generated, logits, 3.0)[0],
                               atol=1e-12, rtol=0)
    # the pooled references are what the half-resolution branch reads: other ones change the detail
    wrong, _ = blend_with_reference_detail(references, masks, generated, logits, 3.0, half.flip(-1))
    assert (wrong - pooled).abs().max() > 1e-3


def test_fused_composite_checks_shapes():
    references, masks, generated, logits = _composite_inputs(3, 16, 8, torch.float32, soft_masks=False, spread=1.0)
    with pytest.raises(ValueError, match="blend_logits"):
        blend_with_reference_detail(references, masks, generated, logits[:, :3], 2.0)
    with pytest.raises(ValueError, match="reference_masks"):
        blend_with_reference_detail(references, masks[:, :2], generated, logits, 2.0)


@pytest.mark.parametrize(("channels", "side", "sigma"),
                         [(15, 32, 3.0), (3, 32, 3.0), (16, 32, 3.0), (15, 32, 1.0), (5, 17, 3.0)])
def test_blocked_low_band_is_the_low_band_padded_to_a_channel_block(channels, side, sigma):
    images = torch.rand(2, channels, side, side, generator=torch.Generator().manual_seed(channels), dtype=torch.float64)
    blocked = blocked_low_band(images, sigma)
    assert blocked.shape[1] % CHANNEL_BLOCK == 0 and blocked.shape[1] >= channels
    torch.testing.assert_close(blocked[:, :channels], low_band(images, sigma), atol=1e-12, rtol=0)
    assert not blocked[:, channels:].any()  # the padding stays zero
    if side % 2 == 0:
        with_pooled = blocked_low_band(images, sigma, F.avg_pool2d(images, 2))
        torch.testing.assert_close(with_pooled, blocked, atol=1e-12, rtol=0)


@pytest.mark.parametrize("count", [1, 3, 5])
def test_median_of_a_list_is_the_median_over_references(count):
    values = torch.randn(2, count, 3, 4, 5, generator=torch.Generator().manual_seed(count))
    torch.testing.assert_close(median_of(values.unbind(1)), median_over_references(values), atol=0, rtol=0)
    torch.testing.assert_close(median_of(values.unbind(1)), values.quantile(0.5, dim=1), atol=1e-6, rtol=0)


def test_median_of_rejects_other_counts():
    with pytest.raises(ValueError, match="1, 3 or 5"):
        median_of([torch.zeros(2)] * 4)


def _export_path(monkeypatch) -> None:
    """What ``torch.onnx.export`` switches on while it traces (``torch.onnx.is_in_onnx_export``), in eager."""
    monkeypatch.setattr(torch.onnx, "is_in_onnx_export", lambda: True)


@pytest.mark.parametrize(
    ("crop_scale", "reference_detail", "reference_flow"),
    [(4, 0.0117, 0.0), (2, 0.0117, 0.0), (4, 0.0, 0.0), (2, 0.02, 0.05)],
    ids=["default-like", "crop-2x", "no-detail", "flow+detail"],
)
def test_frame_generator_export_path_matches_eager(monkeypatch, crop_scale, reference_detail, reference_flow):
    """The whole per-frame module, as traced for ONNX (fused composite, pooled-once references, InstanceNormalization,
    modulate) against eager, on a warp-guided model shaped like the shipped one (5 references, crop 4x)."""
    torch.manual_seed(0)
    config = preset_config("tiny", variant="warp_guided", warp_references=5, crop_scale=crop_scale,
                           reference_detail=reference_detail, reference_flow=reference_flow)
    model = LSRModel(config).eval()
    with torch.no_grad():  # logits that differ between references (zero-initialised heads would test a uniform blend)
        model.frame_generator.image_generator.to_rgb.bias[3:].uniform_(-1.0, 1.0)
    generator = torch.Generator().manual_seed(1)
    size, crop = config.resolution, config.resolution * crop_scale
    landmark_image = torch.rand(2, 3, size, size, generator=generator) * 2 - 1
    latent = torch.randn(2, config.latent_dim, generator=generator)
    references = torch.rand(2, 5, 3, crop, crop, generator=generator) * 2 - 1
    masks = (torch.rand(2, 5, 1, crop, crop, generator=generator) > 0.1).float()
    with torch.no_grad():
        expected = model.frame_generator.synthesize(landmark_image, latent, latent, references=references,
                                                    reference_masks=masks)
        _export_path(monkeypatch)
        traced = model.frame_generator.synthesize(landmark_image, latent, latent, references=references,
                                                  reference_masks=masks)
    torch.testing.assert_close(traced.layout, expected.layout, atol=1e-5, rtol=0)
    torch.testing.assert_close(traced.generated, expected.generated, atol=1e-5, rtol=0)
    # a flow head's raw outputs, rounded differently, are amplified by FLOW_GAIN into the sampling points (as in the
    # ONNX parity test of test_warp_guided.py)
    torch.testing.assert_close(traced.image, expected.image, atol=1e-3 if reference_flow else 2e-5, rtol=0)


@pytest.mark.parametrize("offset", [0.0, 100.0])
def test_norms_export_path_matches_eager(monkeypatch, offset):
    from models_def.norms import SPADE, AdaIN, SpadeConditionProjection

    torch.manual_seed(0)
    x = torch.randn(2, 16, 8, 8) * 2 + offset
    latent, condition = torch.randn(2, 32), torch.randn(2, 5, 8, 8)
    adain, spade, projection = AdaIN(16, 32).eval(), SPADE(16, 24).eval(), SpadeConditionProjection(5, 24).eval()
    with torch.no_grad():
        adain.to_gamma_beta.weight.normal_()
        expected = adain(x, latent), spade(x, projection(condition))
        _export_path(monkeypatch)
        traced = adain(x, latent), spade(x, projection(condition))
    for have, want in zip(traced, expected):
        torch.testing.assert_close(have, want, atol=1e-4 if offset else 1e-5, rtol=0)
