"""Generator and discriminator steps shared by ``lsr train`` (three stages) and ``lsr finetune``.

One training step = generator forward/backward/update, then a discriminator update on the same
(detached) fake, with lazy R1. Non-finite losses or gradients skip the update (the caller's guard
counts them). Data parallelism averages gradients over ranks before the finite check and the update.

Stages (thesis §4.3.2-4.3.4):
  1 ``layout_pretrain``  E^l + G^l only: X-ent(y^l, S_t) + lambda_R * L_R(R_t, I_t)       (eq. 4.2)
  2 ``full``             the full pipeline, eq. 4.4, with X-ent still on                   (eq. 4.3, 4.4)
  3 ``latent``           eq. 4.4 only: G^l is free to learn its own layout                 (§4.3.4)
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator, Mapping

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lsr.config import LossConfig
from lsr.data.episodes import SEGMENTATION_IGNORE_INDEX
from lsr.train import losses
from lsr.train.distributed import DistContext, all_true, average_gradients
from lsr.train.guard import all_finite
from models_def import NUM_SEG_CLASSES, Discriminator, LSRModel

IGNORE_INDEX = SEGMENTATION_IGNORE_INDEX  # -1: pixels without an (oracle) class
STAGE_NAMES = {1: "layout_pretrain", 2: "full", 3: "latent"}


@dataclasses.dataclass(frozen=True)
class StagePlan:
    """What one stage trains and supervises."""

    stage: int
    cross_entropy: bool
    """X-ent between G^l's layout and the segmentation (eq. 4.2) is part of the loss."""

    @property
    def name(self) -> str:
        return STAGE_NAMES[self.stage]

    @property
    def full_pipeline(self) -> bool:
        return self.stage != 1


def stages_for_variant(variant: str) -> list[StagePlan]:
    """The stages a variant runs (Table 4.2): only layout-predicting variants pre-train G^l and use X-ent."""
    if variant in ("latent_layout", "warp_guided"):
        return [StagePlan(1, True), StagePlan(2, True), StagePlan(3, False)]
    if variant == "learned_seg":  # the predicted layout stays a segmentation: X-ent on in every stage
        return [StagePlan(1, True), StagePlan(2, True), StagePlan(3, True)]
    # baseline, spade_landmarks, oracle_seg: no G^l, so no pre-training and no X-ent
    return [StagePlan(2, False), StagePlan(3, False)]


@dataclasses.dataclass
class Batch:
    """One batch on the training device. S = resolution, C_lm = landmark channels.

    shots: (B, K, 3, S, S) in [-1, 1]; shot_landmark_images: (B, K, C_lm, S, S) in [-1, 1];
    target: (B, 3, S, S) in [-1, 1]; target_landmark_image: (B, C_lm, S, S);
    target_segmentation: (B, S, S) int64 class ids, ``IGNORE_INDEX`` where unknown, or None;
    references: (B, N, 3, S, S) in [-1, 1] and reference_masks: (B, N, 1, S, S), warp_guided only;
    target_landmarks: (B, 68, 2) pixels (the mouth term), where the dataset gives them.
    """

    shots: Tensor
    shot_landmark_images: Tensor
    target: Tensor
    target_landmark_image: Tensor
    target_segmentation: Tensor | None = None
    references: Tensor | None = None
    reference_masks: Tensor | None = None
    target_landmarks: Tensor | None = None

    @classmethod
    def from_dict(cls, raw: Mapping[str, Tensor], device: torch.device) -> Batch:
        missing = [k for k in ("shots", "shot_landmark_images", "target", "target_landmark_image") if k not in raw]
        if missing:
            raise KeyError(f"batch is missing {missing}; expected the keys of lsr.data.episodes")
        segmentation = raw.get("target_segmentation")
        return cls(
            shots=raw["shots"].to(device, torch.float32),
            shot_landmark_images=raw["shot_landmark_images"].to(device, torch.float32),
            target=raw["target"].to(device, torch.float32),
            target_landmark_image=raw["target_landmark_image"].to(device, torch.float32),
            target_segmentation=None if segmentation is None else segmentation.to(device, torch.int64),
            references=_optional(raw, "references", device),
            reference_masks=_optional(raw, "reference_masks", device),
            target_landmarks=_optional(raw, "target_landmarks", device),
        )

    def oracle_one_hot(self) -> Tensor:
        """(B, 19, S, S) one-hot of the target segmentation (ignored pixels all-zero), for 'oracle_seg'."""
        if self.target_segmentation is None:
            raise ValueError("variant 'oracle_seg' needs target_segmentation in every batch (a dataset with segmentation/)")
        seg = self.target_segmentation
        one_hot = F.one_hot(seg.clamp(0, NUM_SEG_CLASSES - 1), NUM_SEG_CLASSES).permute(0, 3, 1, 2).float()
        return one_hot * (seg != IGNORE_INDEX).unsqueeze(1).float()


# The loss weights are the CLI's dataclass itself: one set of defaults for train, finetune and benches.
LossWeights = LossConfig


# ---- which parameters train in which stage -------------------------------------------------------------


def generator_trainable_modules(model: LSRModel, plan: StagePlan) -> list[nn.Module]:
    """Modules of the generator side that receive gradients in ``plan``'s stage."""
    encoder = model.subject_encoder.encoder
    generator = model.frame_generator
    uses_layout_latent = generator.layout_predictor is not None
    modules: list[nn.Module] = [encoder.layout_trunk]  # the trunk (shared or E^l's own)
    if uses_layout_latent:
        modules.append(encoder.layout_head)
    if not plan.full_pipeline:  # stage 1: E^l + G^l (with its aux RGB head) only, eq. 4.1
        return modules + [generator.layout_predictor]
    modules.append(encoder.style_head)
    if encoder.style_trunk is not None:
        modules.append(encoder.style_trunk)
    if not uses_layout_latent and encoder.style_trunk is not None:
        modules.remove(encoder.layout_trunk)  # separate E^l trunk feeds nothing in these variants
    for name in ("layout_predictor", "image_generator", "baseline_generator"):
        module = getattr(generator, name)
        if module is not None:
            modules.append(module)
    return modules


def set_stage_trainable(model: LSRModel, discriminator: Discriminator, plan: StagePlan) -> None:
    """Freeze everything, then unfreeze the stage's modules (the aux RGB head only trains in stage 1)."""
    model.requires_grad_(False)
    for module in generator_trainable_modules(model, plan):
        module.requires_grad_(True)
    aux_head = getattr(model.frame_generator.layout_predictor, "to_aux_rgb", None)
    if aux_head is not None and plan.full_pipeline:
        aux_head.requires_grad_(False)
    discriminator.requires_grad_(plan.full_pipeline)


def trainable_parameters(module: nn.Module) -> list[nn.Parameter]:
    return [p for p in module.parameters() if p.requires_grad]


@contextlib.contextmanager
def frozen(module: nn.Module) -> Iterator[None]:
    """Temporarily stop gradients into ``module`` (D during the generator step), restoring the flags after."""
    flags = [p.requires_grad for p in module.parameters()]
    module.requires_grad_(False)
    try:
        yield
    finally:
        for param, flag in zip(module.parameters(), flags, strict=True):
            param.requires_grad_(flag)


# ---- discriminator features for feature matching -----------------------------------------------------


def discriminator_with_features(discriminator: Discriminator, image: Tensor) -> tuple[Tensor, list[Tensor]]:
    """D's logits (B,) and the outputs of each of its residual blocks (the feature-matching targets).

    Forward hooks read the intermediate activations of a normal forward, so D needs no special API.
    """
    features: list[Tensor] = []
    handles = [block.register_forward_hook(lambda _m, _i, out: features.append(out)) for block in discriminator.blocks]
    try:
        logits = discriminator(image)
    finally:
        for handle in handles:
            handle.remove()
    return logits, features


# ---- the two steps -------------------------------------------------------------------------------------


@dataclasses.dataclass
class StepResult:
    finite: bool
    """False when the loss or a gradient was non-finite (on any rank) and the update was skipped."""
    scalars: dict[str, float]
    fake: Tensor | None = None
    layout: Tensor | None = None
    """The layout SPADE saw (or G^l's logits in stage 1), for previews."""


def reconstruction_loss(fake: Tensor, real: Tensor, weights: LossWeights, perceptual: nn.Module | None,
                        landmarks: Tensor | None = None) -> tuple[Tensor, dict[str, Tensor]]:
    """L_rec of eq. 4.4: L1 + SSIM (+ L2 when weighted, + VGG perceptual when weights were given, + L1 around the
    mouth when weighted and the target's ``landmarks`` (B, 68, 2) are given)."""
    terms = {"l1": losses.l1_loss(fake, real)}
    if weights.mouth > 0 and landmarks is not None:
        terms["mouth"] = losses.masked_l1_loss(fake, real, losses.mouth_mask(landmarks, fake.shape[-1]))
    if weights.l2 > 0:
        terms["l2"] = losses.l2_loss(fake, real)
    if weights.ssim > 0:
        terms["ssim"] = losses.ssim_loss(fake, real)
    if perceptual is not None and weights.vgg > 0:
        terms["vgg"] = perceptual(fake, real)
    total = (weights.l1 * terms["l1"] + weights.l2 * terms.get("l2", 0.0) + weights.ssim * terms.get("ssim", 0.0)
             + weights.vgg * terms.get("vgg", 0.0) + weights.mouth * terms.get("mouth", 0.0))
    return total, terms


def _autocast(device: torch.device, bf16: bool):
    if bf16 and device.type == "cuda":
        return torch.autocast("cuda", dtype=torch.bfloat16)
    return contextlib.nullcontext()


def _grad_norm(parameters: list[nn.Parameter]) -> float:
    grads = [p.grad.detach().float().norm() for p in parameters if p.grad is not None]
    return float(torch.stack(grads).norm()) if grads else 0.0


def generator_step(
    model: LSRModel,
    discriminator: Discriminator,
    optimizer: torch.optim.Optimizer,
    batch: Batch,
    plan: StagePlan,
    weights: LossWeights,
    *,
    context: DistContext = DistContext(),
    perceptual: nn.Module | None = None,
    latents: tuple[Tensor, Tensor] | None = None,
    bf16: bool = False,
    loss_hook=None,
) -> StepResult:
    """One generator update for ``plan``'s stage. ``latents`` = fixed (z^l, z^s) for fine-tuning (§4.3.5).

    ``loss_hook(total) -> total`` lets tests inject faults into the loss (e.g. a NaN).
    """
    device = batch.target.device
    params = trainable_parameters(model)
    optimizer.zero_grad(set_to_none=True)
    scalars: dict[str, float] = {}
    with _autocast(device, bf16):
        if latents is None:
            layout_latent, style_latent = model.subject_encoder(batch.shots, batch.shot_landmark_images)
        else:
            layout_latent, style_latent = latents
        generator = model.frame_generator
        if not plan.full_pipeline:  # stage 1, eqs. 4.1-4.2
            with_aux = generator.layout_predictor.to_aux_rgb is not None
            layout_logits, aux_rgb = generator.predict_layout(batch.target_landmark_image, layout_latent, with_aux)
            cross_entropy = losses.layout_cross_entropy(layout_logits.float(), _segmentation(batch), IGNORE_INDEX)
            total = weights.cross_entropy * cross_entropy
            scalars["cross_entropy"] = cross_entropy.item()
            if aux_rgb is not None:
                aux_loss, aux_terms = reconstruction_loss(aux_rgb.float(), batch.target, weights, perceptual)
                total = total + weights.aux_rgb * aux_loss
                scalars.update({f"aux_{k}": v.item() for k, v in aux_terms.items()})
            fake, layout = aux_rgb, layout_logits
        else:  # stages 2-3, eqs. 4.3-4.4
            oracle = batch.oracle_one_hot() if model.config.variant == "oracle_seg" else None
            frame = generator.synthesize(batch.target_landmark_image, layout_latent, style_latent, oracle,
                                         references=batch.references, reference_masks=batch.reference_masks)
            fake, layout = frame.image.float(), frame.layout
            total, rec_terms = reconstruction_loss(fake, batch.target, weights, perceptual, batch.target_landmarks)
            scalars.update({k: v.item() for k, v in rec_terms.items()})
            with frozen(discriminator):
                fake_logits, fake_features = discriminator_with_features(discriminator, fake)
                with torch.no_grad():
                    _, real_features = discriminator_with_features(discriminator, batch.target)
            adversarial = losses.g_nonsaturating_loss(fake_logits.float())
            total = total + weights.adversarial * adversarial
            scalars["g_adversarial"] = adversarial.item()
            if weights.feature_matching > 0:
                matching = losses.feature_matching_loss([f.float() for f in fake_features], [f.float() for f in real_features])
                total = total + weights.feature_matching * matching
                scalars["feature_matching"] = matching.item()
            uses_layout_latent = generator.layout_predictor is not None
            if latents is None and weights.latent_l2 > 0:  # eq. 4.4 lambda_L2 term (fixed latents in fine-tuning)
                latent_l2 = losses.latent_l2(layout_latent.float() if uses_layout_latent else None, style_latent.float())
                total = total + weights.latent_l2 * latent_l2
                scalars["latent_l2"] = latent_l2.item()
            if plan.cross_entropy and frame.layout_logits is not None:
                cross_entropy = losses.layout_cross_entropy(frame.layout_logits.float(), _segmentation(batch), IGNORE_INDEX)
                total = total + weights.cross_entropy * cross_entropy
                scalars["cross_entropy"] = cross_entropy.item()
    if loss_hook is not None:
        total = loss_hook(total)
    scalars["g_total"] = total.item()
    finite_loss = bool(torch.isfinite(total.detach()))
    if finite_loss:
        total.backward()
    average_gradients(params, context)
    finite = all_true(finite_loss and all_finite(None, params), context, device)
    scalars["g_grad_norm"] = _grad_norm(params) if finite else float("nan")
    if finite:
        optimizer.step()
    optimizer.zero_grad(set_to_none=True)
    return StepResult(finite, scalars, fake.detach() if fake is not None else None, None if layout is None else layout.detach())


def discriminator_step(
    discriminator: Discriminator,
    optimizer: torch.optim.Optimizer,
    real: Tensor,
    fake: Tensor,
    weights: LossWeights,
    d_step_index: int,
    *,
    context: DistContext = DistContext(),
    bf16: bool = False,
) -> StepResult:
    """One D update: logistic loss on real vs. the detached fake, + lazy R1 every ``r1_every`` D steps.

    Lazy R1 (StyleGAN2): the penalty gamma/2 * E||grad D(x)||^2 is applied every N steps and scaled by N.
    """
    params = trainable_parameters(discriminator)
    optimizer.zero_grad(set_to_none=True)
    apply_r1 = weights.r1_gamma > 0 and d_step_index % weights.r1_every == 0
    real = real.detach().requires_grad_(apply_r1)
    with _autocast(real.device, bf16):
        real_logits = discriminator(real).float()
        fake_logits = discriminator(fake.detach()).float()
    loss = losses.d_logistic_loss(real_logits, fake_logits)
    scalars = {"d_logistic": loss.item(), "d_real": real_logits.mean().item(), "d_fake": fake_logits.mean().item()}
    if apply_r1:
        penalty = losses.r1_penalty(real_logits, real)
        loss = loss + weights.r1_gamma / 2 * penalty * weights.r1_every
        scalars["r1"] = penalty.item()
    finite_loss = bool(torch.isfinite(loss.detach()))
    if finite_loss:
        loss.backward()
    average_gradients(params, context)
    finite = all_true(finite_loss and all_finite(None, params), context, real.device)
    scalars["d_grad_norm"] = _grad_norm(params) if finite else float("nan")
    if finite:
        optimizer.step()
    optimizer.zero_grad(set_to_none=True)
    return StepResult(finite, scalars)


def _optional(raw: Mapping[str, Tensor], key: str, device: torch.device) -> Tensor | None:
    return raw[key].to(device, torch.float32) if key in raw else None


def _segmentation(batch: Batch) -> Tensor:
    if batch.target_segmentation is None:
        raise ValueError("segmentation supervision (X-ent, eq. 4.2) needs target_segmentation in every batch")
    return batch.target_segmentation
