"""The warp-guided variant (thesis §4.5.6): its composite, its inputs, the warm start and its ONNX graph."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from models_def import LSRModel, ModelConfig, preset_config
from models_def.composite import blend_references


def _inputs(config: ModelConfig, crop: int, seed: int = 0):
    generator = torch.Generator().manual_seed(seed)
    size, count = config.resolution, config.warp_references
    landmark_image = torch.rand(2, 3, size, size, generator=generator) * 2 - 1
    latent = torch.randn(2, config.latent_dim, generator=generator)
    references = torch.rand(2, count, 3, crop, crop, generator=generator) * 2 - 1
    masks = (torch.rand(2, count, 1, crop, crop, generator=generator) > 0.2).float()
    return landmark_image, latent, references, masks


def test_blend_picks_the_reference_its_logit_favours():
    references = torch.stack([torch.full((3, 8, 8), -0.5), torch.full((3, 8, 8), 0.5)])[None]  # (1, 2, 3, 8, 8)
    masks = torch.ones(1, 2, 1, 8, 8)
    generated = torch.zeros(1, 3, 8, 8)
    logits = torch.tensor([0.0, 40.0, 0.0]).view(1, 3, 1, 1).expand(1, 3, 8, 8)
    image, weights = blend_references(references, masks, generated, logits)
    torch.testing.assert_close(image, references[:, 1], atol=1e-6, rtol=0)
    torch.testing.assert_close(weights.sum(dim=1), torch.ones(1, 8, 8))


def test_invalid_reference_pixels_get_no_weight():
    references = torch.ones(1, 1, 3, 4, 4)
    masks = torch.zeros(1, 1, 1, 4, 4)  # the warp left the shot everywhere
    generated = -torch.ones(1, 3, 4, 4)
    image, weights = blend_references(references, masks, generated, torch.zeros(1, 2, 4, 4))
    assert weights[:, 0].max() < 1e-12
    torch.testing.assert_close(image, generated)


def test_low_resolution_logits_are_upsampled_to_the_references():
    references = torch.rand(1, 2, 3, 16, 16)
    image, weights = blend_references(references, torch.ones(1, 2, 1, 16, 16), torch.zeros(1, 3, 8, 8), torch.zeros(1, 3, 8, 8))
    assert image.shape == (1, 3, 16, 16) and weights.shape == (1, 3, 16, 16)
    torch.testing.assert_close(image, references.sum(dim=1) / 3)  # uniform weights


def test_blend_gradcheck():
    generator = torch.Generator().manual_seed(0)
    args = [torch.rand(1, 2, 3, 4, 4, generator=generator, dtype=torch.float64), torch.ones(1, 2, 1, 4, 4, dtype=torch.float64),
            torch.rand(1, 3, 2, 2, generator=generator, dtype=torch.float64), torch.rand(1, 3, 2, 2, generator=generator, dtype=torch.float64)]
    for index in (0, 2, 3):
        args[index].requires_grad_(True)
    assert torch.autograd.gradcheck(lambda *a: blend_references(*a)[0], args)


@pytest.mark.parametrize("crop_factor", [1, 2])
def test_frame_generator_shapes_and_weights(crop_factor):
    config = preset_config("tiny", variant="warp_guided")
    model = LSRModel(config).eval()
    crop = config.resolution * crop_factor
    landmark_image, latent, references, masks = _inputs(config, crop)
    with torch.no_grad():
        outputs = model.frame_generator.synthesize(landmark_image, latent, latent, references=references, reference_masks=masks)
    assert outputs.image.shape == (2, 3, crop, crop) and outputs.generated.shape == (2, 3, config.resolution, config.resolution)
    assert outputs.blend_weights.shape == (2, config.warp_references + 1, crop, crop)
    assert outputs.layout.shape[1] == config.layout_channels and torch.isfinite(outputs.image).all()
    assert outputs.image.min() >= -1 - 1e-5 and outputs.image.max() <= 1 + 1e-5


def test_references_are_required_and_checked():
    config = preset_config("tiny", variant="warp_guided")
    model = LSRModel(config)
    landmark_image, latent, references, masks = _inputs(config, config.resolution)
    with pytest.raises(ValueError, match="needs references"):
        model.frame_generator(landmark_image, latent, latent)
    with pytest.raises(ValueError, match="references"):
        model.frame_generator(landmark_image, latent, latent, references=references[:, :1], reference_masks=masks)


def test_configs_saved_before_warp_references_existed_still_load():
    values = preset_config("tiny").to_dict()
    del values["warp_references"]
    assert ModelConfig.from_dict(values) == preset_config("tiny")


def test_warm_start_keeps_the_old_generator_and_starts_with_a_uniform_blend(tmp_path):
    from lsr.train.warm_start import warm_start
    from models_def import Discriminator

    torch.manual_seed(0)
    old = LSRModel(preset_config("tiny")).save_pretrained(tmp_path / "old")
    config = preset_config("tiny", variant="warp_guided")
    model, discriminator = LSRModel(config).eval(), Discriminator(config)
    widened = warm_start(model, discriminator, old)
    assert any("to_rgb" in name for name in widened) and any("projection" in name for name in widened)
    base = LSRModel.from_pretrained(old).eval()
    landmark_image, latent, references, masks = _inputs(config, config.resolution * 2)
    with torch.no_grad():
        expected = base.frame_generator(landmark_image, latent, latent)
        outputs = model.frame_generator.synthesize(landmark_image, latent, latent, references=references, reference_masks=masks)
    torch.testing.assert_close(outputs.generated, expected, atol=1e-4, rtol=0)
    valid = masks[:, :, 0].sum(dim=1) == config.warp_references  # where every reference is valid: all weights equal
    torch.testing.assert_close(outputs.blend_weights.permute(0, 2, 3, 1)[valid], torch.full((int(valid.sum()), 4), 0.25),
                               atol=1e-5, rtol=0)


def test_warm_start_with_more_references_keeps_each_old_reference_and_starts_the_new_ones_silent(tmp_path):
    from lsr.train.warm_start import NEW_REFERENCE_LOGIT_OFFSET, warm_start
    from models_def import Discriminator

    torch.manual_seed(0)
    old_config = preset_config("tiny", variant="warp_guided", warp_references=2)
    old = LSRModel(old_config)
    with torch.no_grad():  # an old blend head that does not start uniform, so a wrong channel map shows
        old.frame_generator.image_generator.to_rgb.bias.copy_(torch.tensor([0.0, 0.0, 0.0, 1.5, -0.5, 0.7]))
    folder = old.save_pretrained(tmp_path / "old")
    config = preset_config("tiny", variant="warp_guided", warp_references=4)
    model = LSRModel(config).eval()
    warm_start(model, Discriminator(config), folder)
    base = LSRModel.from_pretrained(folder).eval()
    landmark_image, latent, references, masks = _inputs(config, config.resolution * 2)
    masks = torch.ones_like(masks)
    with torch.no_grad():
        expected = base.frame_generator.synthesize(landmark_image, latent, latent, references=references[:, :2],
                                                   reference_masks=masks[:, :2])
        outputs = model.frame_generator.synthesize(landmark_image, latent, latent, references=references,
                                                   reference_masks=masks)
    # the new references' inputs start at zero: G^s's image is the old one
    torch.testing.assert_close(outputs.generated, expected.generated, atol=1e-4, rtol=0)
    # old references and the generated image keep their logits; new ones copy the last old one's, lowered
    old_weights, new_weights = expected.blend_weights, outputs.blend_weights  # (B, 3, H, W), (B, 5, H, W)
    ratio = torch.exp(torch.tensor(NEW_REFERENCE_LOGIT_OFFSET))
    torch.testing.assert_close(new_weights[:, 2] / new_weights[:, 1], torch.full_like(new_weights[:, 1], ratio), atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(new_weights[:, 3] / new_weights[:, 1], torch.full_like(new_weights[:, 1], ratio), atol=1e-4, rtol=1e-4)
    kept = new_weights[:, [0, 1, 4]]
    torch.testing.assert_close(kept / kept.sum(dim=1, keepdim=True), old_weights, atol=1e-4, rtol=1e-4)


def test_zero_reference_flow_is_the_identity_and_a_known_flow_shifts_by_a_pixel():
    from models_def.composite import FLOW_GAIN, shift_references

    generator = torch.Generator().manual_seed(0)
    references = torch.rand(2, 3, 3, 8, 8, generator=generator)
    masks = (torch.rand(2, 3, 1, 8, 8, generator=generator) > 0.3).float()
    same, same_masks = shift_references(references, masks, torch.zeros(2, 6, 4, 4), max_shift=0.1)
    torch.testing.assert_close(same, references, atol=1e-6, rtol=0)
    torch.testing.assert_close(same_masks, masks, atol=1e-6, rtol=0)
    # x offset of one pixel (2 / 8 grid units) on every reference: tanh(f) * 2 * 0.25 = 0.25
    flow = torch.zeros(2, 6, 8, 8)
    flow[:, 0::2] = float(np.arctanh(0.5)) / FLOW_GAIN
    moved, moved_masks = shift_references(references, masks, flow, max_shift=0.25)
    torch.testing.assert_close(moved[..., :-1], references[..., 1:], atol=1e-5, rtol=0)
    torch.testing.assert_close(moved[..., -1], references[..., -1], atol=1e-5, rtol=0)  # border: replicated
    torch.testing.assert_close(moved_masks[..., :-1], masks[..., 1:], atol=1e-5, rtol=0)


def test_warm_start_into_a_flow_model_keeps_the_old_output(tmp_path):
    from lsr.train.warm_start import warm_start
    from models_def import Discriminator

    torch.manual_seed(0)
    folder = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path / "old")
    config = preset_config("tiny", variant="warp_guided", reference_flow=0.05)
    model = LSRModel(config).eval()
    assert model.frame_generator.image_generator.to_rgb.bias.shape[0] == 3 + config.warp_references + 1 + 2 * config.warp_references
    warm_start(model, Discriminator(config), folder)
    base = LSRModel.from_pretrained(folder).eval()
    landmark_image, latent, references, masks = _inputs(config, config.resolution * 2)
    with torch.no_grad():
        expected = base.frame_generator.synthesize(landmark_image, latent, latent, references=references, reference_masks=masks)
        outputs = model.frame_generator.synthesize(landmark_image, latent, latent, references=references, reference_masks=masks)
    torch.testing.assert_close(outputs.image, expected.image, atol=1e-5, rtol=0)


def test_warm_start_rejects_another_preset(tmp_path):
    from lsr.errors import WeightsError
    from lsr.train.warm_start import warm_start
    from models_def import Discriminator

    old = LSRModel(preset_config("tiny", width=0.25)).save_pretrained(tmp_path / "old")
    config = preset_config("tiny", variant="warp_guided")
    with pytest.raises(WeightsError, match="init-from"):
        warm_start(LSRModel(config), Discriminator(config), old)


def test_gaussian_blur_matches_opencv_and_keeps_a_constant():
    import cv2

    from models_def.composite import gaussian_blur

    image = np.random.default_rng(0).random((3, 32, 32)).astype(np.float32)
    ours = gaussian_blur(torch.from_numpy(image)[None], 2.0)[0].numpy()
    theirs = np.stack([cv2.GaussianBlur(c, (13, 13), 2.0, borderType=cv2.BORDER_REFLECT_101) for c in image])
    assert np.abs(ours - theirs).max() < 1e-5
    torch.testing.assert_close(gaussian_blur(torch.full((1, 2, 9, 9), 0.3), 3.0), torch.full((1, 2, 9, 9), 0.3))


@pytest.mark.parametrize("count", [1, 2, 3, 4, 5, 6])
def test_median_over_references_is_the_median(count):
    from models_def.composite import median_over_references

    generator = torch.Generator().manual_seed(count)
    values = torch.randn(2, count, 3, 5, 7, generator=generator)
    values[0, :, 0] = torch.randint(0, 3, (count, 5, 7), generator=generator).float()  # ties
    expected = values.quantile(0.5, dim=1)  # the mean of the two middle values for an even count
    torch.testing.assert_close(median_over_references(values), expected, atol=1e-6, rtol=0)


def test_low_band_is_the_gaussian_blur_made_at_half_resolution():
    import cv2

    from models_def.composite import HALF_RESOLUTION_MIN_SIGMA, gaussian_blur, low_band

    rng = np.random.default_rng(0)
    # a face-like image: smooth shading plus texture at every scale
    noise = rng.random((3, 64, 64)).astype(np.float32)
    image = torch.from_numpy(np.stack([cv2.GaussianBlur(c, (0, 0), 1.0) + 0.3 * c for c in noise]))[None]
    exact, half = gaussian_blur(image, 3.0), low_band(image, 3.0)
    inner = (slice(None), slice(None), slice(8, -8), slice(8, -8))  # the borders' padding differs
    assert ((half - exact)[inner] ** 2).mean() < 1e-3 * ((image - exact)[inner] ** 2).mean()
    torch.testing.assert_close(low_band(torch.full((1, 2, 16, 16), 0.3), 3.0), torch.full((1, 2, 16, 16), 0.3))
    # below the threshold and on odd sides: the exact blur
    small_sigma = HALF_RESOLUTION_MIN_SIGMA / 2
    torch.testing.assert_close(low_band(image, small_sigma), gaussian_blur(image, small_sigma), atol=0, rtol=0)
    odd = image[..., :63, :63]
    torch.testing.assert_close(low_band(odd, 3.0), gaussian_blur(odd, 3.0), atol=0, rtol=0)


def test_reference_detail_keeps_what_most_references_agree_on():
    from models_def.composite import add_reference_detail
    from models_def.composite import low_band as gaussian_blur  # the split the detail uses

    generator = torch.Generator().manual_seed(0)
    shared = torch.rand(1, 3, 24, 24, generator=generator) * 2 - 1
    outlier = torch.rand(1, 3, 24, 24, generator=generator) * 2 - 1
    references = torch.stack([shared, shared, outlier], dim=1)  # (1, 3, 3, 24, 24)
    masks, no_generated = torch.ones(1, 3, 1, 24, 24), torch.zeros(1, 1, 24, 24)
    blurry = gaussian_blur(shared, 2.0)  # the blend's low band is right, its detail is gone
    image = add_reference_detail(blurry, references, masks, no_generated, 2.0)
    # low band of the blurry blend (~ blurry) + the two agreeing references' detail = the shared image
    expected = (gaussian_blur(blurry, 2.0) + shared - gaussian_blur(shared, 2.0)).clamp(-1, 1)
    torch.testing.assert_close(image, expected, atol=1e-5, rtol=0)
    assert (image - shared).abs().mean() < (blurry - shared).abs().mean()  # sharper and closer than the blend
    # where G^s's own image is used, no reference detail is added; invalid reference pixels add none either
    only_generated = add_reference_detail(blurry, references, masks, torch.ones(1, 1, 24, 24), 2.0)
    torch.testing.assert_close(only_generated, gaussian_blur(blurry, 2.0), atol=1e-6, rtol=0)
    nothing_valid = add_reference_detail(blurry, references, torch.zeros(1, 3, 1, 24, 24), no_generated, 2.0)
    torch.testing.assert_close(nothing_valid, gaussian_blur(blurry, 2.0), atol=1e-6, rtol=0)


def test_reference_detail_is_off_by_default_and_checked():
    assert preset_config("tiny", variant="warp_guided").reference_detail == 0.0
    with pytest.raises(ValueError, match="reference_detail"):
        preset_config("tiny", variant="warp_guided", reference_detail=0.5)


@pytest.mark.parametrize("reference_flow, reference_detail", [(0.0, 0.0), (0.05, 0.0), (0.0, 0.02)],
                         ids=["blend", "blend+flow", "blend+detail"])
def test_onnx_frame_graph_matches_torch(tmp_path, reference_flow, reference_detail):
    pytest.importorskip("onnxruntime")
    from deploy.runtime import OnnxBackend
    from lsr.export.bundle import export_graphs

    torch.manual_seed(0)
    config = preset_config("tiny", variant="warp_guided", reference_flow=reference_flow, reference_detail=reference_detail)
    model = LSRModel(config).eval()
    if reference_flow:  # a flow head that moves the references (a zero-initialised one would test nothing)
        with torch.no_grad():
            model.frame_generator.image_generator.to_rgb.bias[-2 * config.warp_references :].uniform_(-0.1, 0.1)
    export_graphs(model, tmp_path)
    backend = OnnxBackend(tmp_path, threads=1)
    assert backend.warp_references == config.warp_references and backend.crop_size == 2 * config.resolution
    landmark_image, latent, references, masks = _inputs(config, backend.crop_size, seed=1)
    with torch.no_grad():
        expected = model.frame_generator.synthesize(landmark_image, latent, latent, references=references, reference_masks=masks)
    image, layout = backend.synthesize(landmark_image.numpy(), latent.numpy(), latent.numpy(), True,
                                       references.numpy(), masks.numpy())
    # with a reference flow, the network's raw flow outputs (which differ between the runtimes by float rounding, as
    # the image does) are amplified by FLOW_GAIN and move the sampling points: up to 7e-4 here. The blend-only
    # graph (the shipped default) keeps 1e-4.
    tolerance = 1e-3 if reference_flow else 1e-4
    assert np.abs(image - expected.image.numpy()).max() <= tolerance
    assert np.abs(layout - expected.layout.numpy()).max() <= 1e-4


@pytest.mark.parametrize("scale", [0.5, 2.0], ids=["down", "up"])
def test_warm_start_at_another_resolution_resamples_the_start_grid(tmp_path, scale):
    """--resolution with --init-from: every conv is copied, G^s's learned start grid (style_to_input) is
    area-averaged down or repeated up, and D (whose depth follows the resolution) starts fresh."""
    import torch.nn.functional as F

    from lsr.train.warm_start import warm_start
    from models_def import Discriminator

    torch.manual_seed(0)
    old_config = preset_config("tiny", variant="warp_guided")
    old = LSRModel(old_config)
    folder = old.save_pretrained(tmp_path / "old")
    config = preset_config("tiny", variant="warp_guided", resolution=int(old_config.resolution * scale))
    model, discriminator = LSRModel(config), Discriminator(config)
    fresh_discriminator = {k: v.clone() for k, v in discriminator.state_dict().items()}
    resampled = warm_start(model, discriminator, folder)
    assert sorted(resampled) == ["frame_generator.image_generator.style_to_input.bias",
                                 "frame_generator.image_generator.style_to_input.weight"]
    old_generator, generator = old.frame_generator.image_generator, model.frame_generator.image_generator
    latent = torch.randn(3, config.latent_dim)
    channels = generator.start_channels
    with torch.no_grad():
        before = old_generator.style_to_input(latent).view(3, channels, old_generator.start_size, old_generator.start_size)
        after = generator.style_to_input(latent).view(3, channels, generator.start_size, generator.start_size)
    expected = F.avg_pool2d(before, 2) if scale < 1 else F.interpolate(before, scale_factor=2, mode="nearest")
    torch.testing.assert_close(after, expected, atol=1e-5, rtol=0)
    for name, value in model.state_dict().items():  # the rest: copied as is
        if "style_to_input" not in name:
            torch.testing.assert_close(value, old.state_dict()[name], atol=0, rtol=0)
    for name, value in discriminator.state_dict().items():
        torch.testing.assert_close(value, fresh_discriminator[name], atol=0, rtol=0)


def test_crop_scale_sets_the_crop_side_of_every_runtime_and_is_checked(tmp_path):
    import json

    from lsr.core.engine import default_crop_size
    from lsr.export.bundle import bundle_metadata
    from lsr.pipeline import TorchBackend

    config = preset_config("tiny", variant="warp_guided", crop_scale=4)
    assert default_crop_size(TorchBackend(LSRModel(config))) == 4 * config.resolution
    assert bundle_metadata(config)["crop_size"] == str(4 * config.resolution)  # what the ONNX runtime crops at
    with pytest.raises(ValueError, match="crop_scale"):
        preset_config("tiny", variant="warp_guided", crop_scale=3)
    # a model saved before the field blends at twice its resolution, as it did
    folder = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path / "old")
    saved = json.loads((folder / "config.json").read_text())
    saved.pop("crop_scale")
    (folder / "config.json").write_text(json.dumps(saved))
    assert LSRModel.from_pretrained(folder).config.crop_scale == 2
