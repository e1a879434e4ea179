"""Training losses as small pure functions (thesis eq. 4.2 and 4.4).

Images are ``(B, 3, H, W)`` float in [-1, 1]; logits and features come straight from the
networks. Every function returns a scalar tensor (a mean over the batch) so that averaging
gradients over data-parallel ranks equals the gradient of the global-batch loss.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor


def l1_loss(fake: Tensor, real: Tensor) -> Tensor:
    """Mean absolute error; keeps colours faithful (thesis §4.3.3)."""
    return (fake - real).abs().mean()


def l2_loss(fake: Tensor, real: Tensor) -> Tensor:
    """Mean squared error: the loss PSNR measures (a mean of the plausible values, where L1 takes their median)."""
    return (fake - real).square().mean()


MOUTH_POINTS = slice(48, 68)  # iBUG-68 outer and inner lips


def mouth_mask(landmarks: Tensor, size: int, grow: float = 0.35) -> Tensor:
    """(B, 68, 2) pixel landmarks -> (B, 1, S, S) float mask: 1 inside an ellipse around the lips, grown by ``grow`` of
    the mouth's width on every side (the chin and cheeks a mouth moves), a one-pixel soft edge."""
    lips = landmarks[:, MOUTH_POINTS].float()
    low, high = lips.amin(1), lips.amax(1)  # (B, 2)
    centre = (low + high) / 2
    width = (high[:, 0] - low[:, 0]).clamp_min(1.0)
    semi = (high - low) / 2 + grow * width[:, None]  # (B, 2)
    axis = torch.arange(size, device=landmarks.device, dtype=torch.float32)
    dx = (axis[None, None, :] - centre[:, 0, None, None]) / semi[:, 0, None, None]
    dy = (axis[None, :, None] - centre[:, 1, None, None]) / semi[:, 1, None, None]
    radius = (dx.square() + dy.square()).sqrt()  # 1 on the ellipse
    edge = 1.0 / semi.amin(1).clamp_min(1.0)[:, None, None]  # one pixel, in radius units
    return ((1.0 - radius) / edge + 0.5).clamp(0.0, 1.0)[:, None]


def masked_l1_loss(fake: Tensor, real: Tensor, mask: Tensor) -> Tensor:
    """Mean absolute error inside ``mask`` (B, 1, H, W), per image, then over the batch (an empty mask gives 0)."""
    error = ((fake - real).abs() * mask).sum((1, 2, 3))
    area = mask.sum((1, 2, 3)) * fake.shape[1]
    return (error / area.clamp_min(1.0)).mean()


def ssim_loss(fake: Tensor, real: Tensor, window_size: int = 11) -> Tensor:
    """(1 - SSIM) / 2 on images mapped from [-1, 1] to [0, 1] (kornia's structural similarity)."""
    from kornia.losses import ssim_loss as kornia_ssim_loss

    return kornia_ssim_loss((fake + 1) / 2, (real + 1) / 2, window_size=window_size, max_val=1.0)


def feature_matching_loss(fake_features: Sequence[Tensor], real_features: Sequence[Tensor]) -> Tensor:
    """L1 between the discriminator's intermediate features of fake and real images.

    A perceptual signal that needs no downloaded weights (pix2pixHD feature matching);
    real features are targets, so they are detached.
    """
    if len(fake_features) != len(real_features) or not fake_features:
        raise ValueError(f"need matching non-empty feature lists, got {len(fake_features)} and {len(real_features)}")
    terms = [(fake - real.detach()).abs().mean() for fake, real in zip(fake_features, real_features, strict=True)]
    return torch.stack(terms).mean()


def layout_cross_entropy(layout_logits: Tensor, segmentation: Tensor, ignore_index: int = -1) -> Tensor:
    """X-ent between G^l's layout logits ``(B, C, H, W)`` and a class map ``(B, H, W)`` int64 (eq. 4.2).

    The layout is resized to the segmentation's size when they differ. A batch whose pixels are
    all ``ignore_index`` gives 0 (not NaN), so a missing oracle map never poisons a step.
    """
    if layout_logits.shape[-2:] != segmentation.shape[-2:]:
        layout_logits = F.interpolate(layout_logits, size=segmentation.shape[-2:], mode="bilinear", align_corners=False)
    valid = segmentation != ignore_index
    if not bool(valid.any()):
        return layout_logits.sum() * 0.0
    return F.cross_entropy(layout_logits, segmentation, ignore_index=ignore_index)


def d_logistic_loss(real_logits: Tensor, fake_logits: Tensor) -> Tensor:
    """Non-saturating logistic loss of the discriminator (thesis §4.3.3, [138])."""
    return F.softplus(-real_logits).mean() + F.softplus(fake_logits).mean()


def g_nonsaturating_loss(fake_logits: Tensor) -> Tensor:
    """Non-saturating generator loss: -log sigmoid(D(fake))."""
    return F.softplus(-fake_logits).mean()


def r1_penalty(real_logits: Tensor, real_images: Tensor) -> Tensor:
    """R1 gradient penalty ``E ||grad_x D(x)||^2`` on real images (Mescheder et al. [138]).

    ``real_images`` must have ``requires_grad=True`` and produced ``real_logits``.
    """
    (grad,) = torch.autograd.grad(real_logits.sum(), real_images, create_graph=True)
    return grad.pow(2).flatten(1).sum(1).mean()


def latent_l2(layout_latent: Tensor | None, style_latent: Tensor | None) -> Tensor:
    """``||z^l||^2 + ||z^s||^2`` of eq. 4.4, as a mean over latent entries and batch.

    The mean (not the sum) over entries keeps lambda_L2 independent of the latent width.
    """
    terms = [z.pow(2).mean() for z in (layout_latent, style_latent) if z is not None]
    if not terms:
        raise ValueError("latent_l2 needs at least one latent")
    return torch.stack(terms).sum()
