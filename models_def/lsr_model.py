"""The per-frame generator (one module per ablation variant, thesis Table 4.2) and the full ``LSRModel``.

Two graphs with tensor-only signatures, so that each exports to ONNX on its own:
* ``SubjectEncoder`` (models_def.encoder): K shots -> (layout_latent, style_latent), once per subject;
* ``FrameGenerator``: target landmark image + latents -> RGB (and the layout), once per frame.
``LSRModel`` holds both (E, G^l, G^s); the ``Discriminator`` is separate.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from models_def.blocks import channel_softmax
from models_def.composite import (
    add_reference_detail,
    blend_references,
    blend_with_reference_detail,
    shift_references,
)
from models_def.config import NUM_SEG_CLASSES, ModelConfig
from models_def.encoder import SubjectEncoder
from models_def.generator import SpadeGenerator
from models_def.layout import build_baseline_generator, build_layout_predictor
from models_def.serialization import PretrainedMixin
from models_def.shapes import check_shape


class FrameOutputs(NamedTuple):
    """Everything one frame produces. Absent parts are None (depending on the variant and the request)."""

    image: torch.Tensor
    """(B, 3, H, W) in [-1, 1]."""
    layout: torch.Tensor | None
    """SPADE's layout input (B, C_l, H, W): softmax or raw G^l output, or the oracle segmentation."""
    layout_logits: torch.Tensor | None
    """(B, C_l, H, W) raw G^l output, for the segmentation cross-entropy of eq. 4.2."""
    aux_rgb: torch.Tensor | None
    """(B, 3, H, W) in [-1, 1], G^l's auxiliary reconstruction R_t (eq. 4.1); only when requested."""
    blend_weights: torch.Tensor | None = None
    """warp_guided: (B, N + 1, H_ref, W_ref) per-pixel weights of the N warped references and the generated image."""
    generated: torch.Tensor | None = None
    """warp_guided: (B, 3, H, W) in [-1, 1], G^s's own image before the blend."""
    blend_logits: torch.Tensor | None = None
    """warp_guided: (B, N + 1, H, W), G^s's logits of the blend's softmax (the references', then its image's)."""


class FrameGenerator(nn.Module):
    """Per-frame synthesis for the configured variant.

    forward(landmark_image: (B, C_lm, H, W) in [-1, 1], layout_latent: (B, D), style_latent: (B, D),
            oracle_segmentation: (B, 19, H, W) one-hot, only for variant 'oracle_seg',
            references: (B, N, 3, H', W') in [-1, 1] and reference_masks: (B, N, 1, H', W') in [0, 1], only for
            variant 'warp_guided' (the nearest shots warped onto the target; H' >= H: the blend runs at H'))
            -> image (B, 3, H', W') (H' = H without references).
    Inputs outside their range ([-1, 1]; [0, 1] for the segmentation) are clamped.
    Variant 'baseline' and 'spade_landmarks' ignore layout_latent (their encoder still produces it).
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self.layout_predictor = build_layout_predictor(config) if config.uses_layout_predictor else None
        self.image_generator = SpadeGenerator(config) if config.variant != "baseline" else None
        self.baseline_generator = build_baseline_generator(config) if config.variant == "baseline" else None

    def forward(
        self,
        landmark_image: torch.Tensor,
        layout_latent: torch.Tensor,
        style_latent: torch.Tensor,
        oracle_segmentation: torch.Tensor | None = None,
        references: torch.Tensor | None = None,
        reference_masks: torch.Tensor | None = None,
    ) -> torch.Tensor:
        return self.synthesize(
            landmark_image, layout_latent, style_latent, oracle_segmentation,
            references=references, reference_masks=reference_masks,
        ).image

    def predict_layout(
        self, landmark_image: torch.Tensor, layout_latent: torch.Tensor, with_aux_rgb: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """G^l alone (stage-1 pre-training, eq. 4.1): -> (layout_logits (B, C_l, H, W), aux_rgb or None)."""
        if self.layout_predictor is None:
            raise ValueError(f"variant {self.config.variant!r} has no layout predictor G^l")
        self._check_inputs(landmark_image, layout_latent, layout_latent)
        return self.layout_predictor(landmark_image.clamp(-1.0, 1.0), layout_latent, with_aux_rgb)

    def synthesize(
        self,
        landmark_image: torch.Tensor,
        layout_latent: torch.Tensor,
        style_latent: torch.Tensor,
        oracle_segmentation: torch.Tensor | None = None,
        with_aux_rgb: bool = False,
        references: torch.Tensor | None = None,
        reference_masks: torch.Tensor | None = None,
    ) -> FrameOutputs:
        """All outputs of one frame (see ``FrameOutputs``). ``with_aux_rgb`` runs G^l's RGB head (stage 1 only)."""
        batch = self._check_inputs(landmark_image, layout_latent, style_latent)
        # Clamp to the input contract: out-of-range values would overflow float16 activations.
        landmark_image = landmark_image.clamp(-1.0, 1.0)
        variant = self.config.variant
        if (variant == "oracle_seg") != (oracle_segmentation is not None):
            raise ValueError(
                "pass oracle_segmentation (B, 19, H, W) exactly when variant is 'oracle_seg' "
                f"(variant is {variant!r})"
            )
        if with_aux_rgb and self.layout_predictor is None:
            raise ValueError(f"variant {variant!r} has no layout predictor, so no auxiliary RGB head")

        if self.baseline_generator is not None:  # Table 4.2 'Baseline': AdaIN UNet straight to RGB
            rgb, _ = self.baseline_generator(landmark_image, style_latent)
            return FrameOutputs(torch.tanh(rgb), None, None, None)

        layout = layout_logits = aux_rgb = None
        if self.layout_predictor is not None:  # thesis eq. 4.3: y^l = G^l(x_t, z^l)
            layout_logits, aux_rgb = self.layout_predictor(landmark_image, layout_latent, with_aux_rgb)
            layout = channel_softmax(layout_logits) if self.config.layout_activation == "softmax" else layout_logits
        elif oracle_segmentation is not None:  # Table 4.2 upper bound: the oracle segmentation replaces G^l
            size = self.config.resolution
            check_shape("oracle_segmentation", oracle_segmentation, (batch, NUM_SEG_CLASSES, size, size))
            layout = oracle_segmentation.clamp(0.0, 1.0)
        # §4.6: each SPADE block sees the layout concatenated with the landmark image.
        condition = landmark_image if layout is None else torch.cat([layout, landmark_image], dim=1)
        if not self.config.uses_references:
            image = self.image_generator(condition, style_latent)  # eq. 4.3: I_t = G^s(y^l, z^s)
            return FrameOutputs(image, layout, layout_logits, aux_rgb)
        # warp_guided (§4.5.6): G^s also sees the warped shots and predicts how to blend them with its image.
        references, reference_masks = self._check_references(references, reference_masks, batch)
        # The exported graph takes the composite written for onnxruntime (same math up to float rounding, see
        # blend_with_reference_detail); eager keeps the reference functions, whose frames are recorded bit for bit.
        exporting = torch.onnx.is_in_onnx_export()
        size = self.config.resolution
        small_references = references.flatten(1, 2)  # (B, 3N, H', W')
        small_masks = reference_masks.flatten(1, 2)  # (B, N, H', W')
        half_references = None  # (B, 3N, H'/2, W'/2): pooled once for the network's input and the detail's low band
        if references.shape[-1] % size == 0 and references.shape[-1] > size:  # integer factor (ONNX-friendly)
            factor = references.shape[-1] // size
            small_masks = F.avg_pool2d(small_masks, factor)
            if exporting and factor % 2 == 0:  # a mean of 2x2 means is the factor x factor mean
                half_references = F.avg_pool2d(small_references, 2)
                small_references = F.avg_pool2d(half_references, factor // 2) if factor > 2 else half_references
            else:
                small_references = F.avg_pool2d(small_references, factor)
        elif references.shape[-1] != size:
            small_references = F.interpolate(small_references, size=(size, size), mode="area")
            small_masks = F.interpolate(small_masks, size=(size, size), mode="area")
        output = self.image_generator(torch.cat([condition, small_references, small_masks], dim=1), style_latent)
        count = self.config.warp_references
        generated, blend_logits = output[:, :3], output[:, 3 : 4 + count]  # (B, 3, H, W), (B, N + 1, H, W)
        if self.config.reference_flow > 0:  # residual flow per reference (B, 2N, H, W), applied at the blend side
            references, reference_masks = shift_references(references, reference_masks, output[:, 4 + count :],
                                                           self.config.reference_flow)
            half_references = None  # the moved references pool anew
        sigma = self.config.reference_detail * references.shape[-1]  # 0: no detail step
        if exporting:
            image, weights = blend_with_reference_detail(references, reference_masks, generated, blend_logits, sigma,
                                                         half_references)
            return FrameOutputs(image, layout, layout_logits, aux_rgb, weights, generated, blend_logits)
        image, weights = blend_references(references, reference_masks, generated, blend_logits)
        if sigma > 0:  # the references' consensus detail on the blend's low band
            image = add_reference_detail(image, references, reference_masks, weights[:, count:], sigma)
        return FrameOutputs(image, layout, layout_logits, aux_rgb, weights, generated, blend_logits)

    def _check_references(
        self, references: torch.Tensor | None, reference_masks: torch.Tensor | None, batch: int
    ) -> tuple[torch.Tensor, torch.Tensor]:
        if references is None or reference_masks is None:
            raise ValueError(
                f"variant 'warp_guided' needs references (B, {self.config.warp_references}, 3, H, W) and "
                "reference_masks (B, N, 1, H, W): the nearest shots warped onto the target (landmarks.warp.tps.warp_references)"
            )
        count = self.config.warp_references
        dims = check_shape("references", references, (batch, count, 3, "H", "W"))
        if dims["H"] != dims["W"] or dims["H"] < self.config.resolution:
            raise ValueError(f"references must be square and at least {self.config.resolution} pixels, got {tuple(references.shape)}")
        check_shape("reference_masks", reference_masks, (batch, count, 1, dims["H"], dims["W"]))
        return references.clamp(-1.0, 1.0), reference_masks.clamp(0.0, 1.0)

    def _check_inputs(
        self, landmark_image: torch.Tensor, layout_latent: torch.Tensor, style_latent: torch.Tensor
    ) -> int:
        size, dim = self.config.resolution, self.config.latent_dim
        batch = check_shape("landmark_image", landmark_image, ("B", self.config.landmark_channels, size, size))["B"]
        check_shape("layout_latent", layout_latent, (batch, dim))
        check_shape("style_latent", style_latent, (batch, dim))
        return batch


class LSROutputs(NamedTuple):
    frame: FrameOutputs
    layout_latent: torch.Tensor
    """(B, D) z^l averaged over the K shots."""
    style_latent: torch.Tensor
    """(B, D) z^s averaged over the K shots."""


class LSRModel(PretrainedMixin, nn.Module):
    """E = {E^l, E^s}, G^l and G^s of one variant. ``save_pretrained`` / ``from_pretrained`` via safetensors.

    forward(shots: (B, K, 3, H, W) in [-1, 1], shot_landmark_images: (B, K, C_lm, H, W) in [-1, 1],
            landmark_image: (B, C_lm, H, W) target landmarks, oracle_segmentation: (B, 19, H, W) or None,
            with_aux_rgb=False, references / reference_masks (warp_guided, see FrameGenerator)) -> LSROutputs
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self.subject_encoder = SubjectEncoder(config)
        self.frame_generator = FrameGenerator(config)

    def forward(
        self,
        shots: torch.Tensor,
        shot_landmark_images: torch.Tensor,
        landmark_image: torch.Tensor,
        oracle_segmentation: torch.Tensor | None = None,
        with_aux_rgb: bool = False,
        references: torch.Tensor | None = None,
        reference_masks: torch.Tensor | None = None,
    ) -> LSROutputs:
        layout_latent, style_latent = self.subject_encoder(shots, shot_landmark_images)
        frame = self.frame_generator.synthesize(
            landmark_image, layout_latent, style_latent, oracle_segmentation, with_aux_rgb, references, reference_masks
        )
        return LSROutputs(frame, layout_latent, style_latent)
