"""Losses: values on known inputs, gradients, edge cases; optional VGG loading."""

from __future__ import annotations

import pytest
import torch

from lsr.errors import WeightsError
from lsr.train import losses
from lsr.train.perceptual import VGGPerceptualLoss, build_vgg_features, load_vgg_features


def _images(seed: int, batch: int = 2, size: int = 16) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(batch, 3, size, size, generator=generator) * 2 - 1


def test_l1_and_ssim_are_zero_on_identical_images_and_positive_otherwise():
    real, fake = _images(0), _images(1)
    assert losses.l1_loss(real, real).item() == 0.0
    assert losses.ssim_loss(real, real).item() == pytest.approx(0.0, abs=1e-4)
    assert losses.l1_loss(fake, real).item() == pytest.approx((fake - real).abs().mean().item())
    assert 0.0 < losses.ssim_loss(fake, real).item() <= 1.0


def test_l2_prefers_the_mean_where_l1_accepts_any_point_between():
    """Two equally likely targets: L2 is lowest at their mean (what PSNR rewards), L1 is flat between them."""
    low, high = torch.full((1, 3, 4, 4), -0.5), torch.full((1, 3, 4, 4), 0.5)
    middle, near_low = torch.zeros(1, 3, 4, 4), torch.full((1, 3, 4, 4), -0.4)

    def both(loss, guess):
        return (loss(guess, low) + loss(guess, high)).item()

    assert both(losses.l2_loss, middle) < both(losses.l2_loss, near_low)
    assert both(losses.l1_loss, middle) == pytest.approx(both(losses.l1_loss, near_low))
    assert losses.l2_loss(low, low).item() == 0.0


def test_feature_matching_detaches_real_features():
    real = [torch.randn(2, 4, 8, 8, requires_grad=True), torch.randn(2, 8, 4, 4, requires_grad=True)]
    fake = [torch.randn(2, 4, 8, 8, requires_grad=True), torch.randn(2, 8, 4, 4, requires_grad=True)]
    loss = losses.feature_matching_loss(fake, real)
    loss.backward()
    assert real[0].grad is None and fake[0].grad is not None
    with pytest.raises(ValueError):
        losses.feature_matching_loss(fake, real[:1])


def test_cross_entropy_matches_torch_and_handles_all_ignored():
    logits = torch.randn(2, 19, 8, 8, requires_grad=True)
    target = torch.randint(0, 19, (2, 8, 8))
    expected = torch.nn.functional.cross_entropy(logits, target)
    assert losses.layout_cross_entropy(logits, target).item() == pytest.approx(expected.item(), rel=1e-6)
    ignored = torch.full((2, 8, 8), -1)
    value = losses.layout_cross_entropy(logits, ignored)
    assert value.item() == 0.0 and torch.isfinite(value)
    # a layout at another resolution is resized to the map
    assert torch.isfinite(losses.layout_cross_entropy(torch.randn(2, 19, 4, 4), target))


def test_adversarial_losses_and_r1():
    logits = torch.tensor([0.0, 0.0])
    log2 = torch.log(torch.tensor(2.0)).item()
    assert losses.d_logistic_loss(logits, logits).item() == pytest.approx(2 * log2)
    assert losses.g_nonsaturating_loss(logits).item() == pytest.approx(log2)
    # D(x) = sum(w * x) has gradient w everywhere, so R1 = ||w||^2.
    weight = torch.randn(3, 4, 4)
    images = torch.randn(5, 3, 4, 4, requires_grad=True)
    penalty = losses.r1_penalty((images * weight).sum(dim=(1, 2, 3)), images)
    assert penalty.item() == pytest.approx(weight.pow(2).sum().item(), rel=1e-5)


def test_latent_l2():
    layout, style = torch.ones(2, 8), torch.full((2, 8), 2.0)
    assert losses.latent_l2(layout, style).item() == pytest.approx(5.0)
    assert losses.latent_l2(None, style).item() == pytest.approx(4.0)
    with pytest.raises(ValueError):
        losses.latent_l2(None, None)


def test_vgg_weights_missing_raises_weights_error(tmp_path):
    with pytest.raises(WeightsError, match="vgg19"):
        VGGPerceptualLoss(tmp_path / "absent.pth")


def test_vgg_loads_a_self_made_torchvision_style_state_dict(tmp_path):
    reference = build_vgg_features("vgg19")
    state = {f"features.{k}": v for k, v in reference.state_dict().items()}
    state["classifier.0.weight"] = torch.zeros(2, 2)  # ignored, as in a full torchvision checkpoint
    torch.save(state, tmp_path / "vgg19.pth")
    net, arch = load_vgg_features(tmp_path / "vgg19.pth")
    assert arch == "vgg19"
    assert torch.equal(net[28].weight, reference[28].weight)
    from safetensors.torch import save_file

    vgg16 = {f"features.{k}": v.contiguous() for k, v in build_vgg_features("vgg16").state_dict().items()}
    save_file(vgg16, str(tmp_path / "vggface.safetensors"))
    loss_fn = VGGPerceptualLoss(tmp_path / "vggface.safetensors")
    assert loss_fn.arch == "vgg16"
    real, fake = _images(0, size=32), _images(1, size=32).requires_grad_(True)
    value = loss_fn(fake, real)
    value.backward()
    assert value.item() > 0 and fake.grad is not None
    assert loss_fn(real, real).item() == pytest.approx(0.0, abs=1e-6)


def test_vgg_rejects_a_wrong_state_dict(tmp_path):
    torch.save({"features.0.weight": torch.zeros(64, 3, 3, 3)}, tmp_path / "bad.pth")
    with pytest.raises(WeightsError, match="features.N.weight"):
        load_vgg_features(tmp_path / "bad.pth")
    (tmp_path / "junk.pth").write_bytes(b"not a torch file")
    with pytest.raises(WeightsError, match="could not read"):
        load_vgg_features(tmp_path / "junk.pth")


def test_mouth_mask_covers_the_lips_and_the_mouth_term_sees_only_them():
    landmarks = torch.full((1, 68, 2), 10.0)
    lips = torch.linspace(0, 1, 20)
    landmarks[0, 48:68, 0] = 34 + 12 * lips  # a mouth 12 px wide, 6 px tall, centred at (40, 44)
    landmarks[0, 48:68, 1] = 41 + 6 * (lips * 7 % 1)
    mask = losses.mouth_mask(landmarks, 64)
    assert mask.shape == (1, 1, 64, 64) and 0.0 <= float(mask.min()) and float(mask.max()) <= 1.0
    assert mask[0, 0, 44, 40] == 1.0 and mask[0, 0, 44, 34] == 1.0  # the lips and their corners
    assert mask[0, 0, 10, 10] == 0.0 and mask[0, 0, 60, 40] == 0.0  # the eyes' points, the chin's bottom
    real = _images(0, batch=1, size=64)
    outside = real + 0.5 * (mask == 0)  # changed where the mask is 0 only
    assert losses.masked_l1_loss(outside, real, mask).item() == pytest.approx(0.0, abs=1e-6)
    inside = real + 0.5 * mask
    assert losses.masked_l1_loss(inside, real, mask).item() > 0.3
