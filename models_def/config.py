"""``ModelConfig``: the typed, validated description of one LSR model (written as config.json beside the weights).

Every network in ``models_def`` is built from this dataclass only. Sizes default to the thesis (§4.6);
cheaper presets (``models_def.presets``) change the width multiplier, the resolution and the number of
layout channels, never the method.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

# Number of CelebAMask-HQ classes used for segmentation pre-training and the oracle (thesis §4.3.2). It must
# equal len(lsr.data.classes.SEG_CLASSES); models_def may not import lsr, so the number is repeated here.
NUM_SEG_CLASSES = 19

Variant = Literal["baseline", "spade_landmarks", "learned_seg", "latent_layout", "oracle_seg", "warp_guided"]
VARIANTS: tuple[str, ...] = ("baseline", "spade_landmarks", "learned_seg", "latent_layout", "oracle_seg", "warp_guided")
# Variants whose per-frame path runs the layout predictor G^l (the others have no layout latent to use).
LAYOUT_PREDICTOR_VARIANTS: tuple[str, ...] = ("learned_seg", "latent_layout", "warp_guided")
# Fields added after models were first saved, with the value that keeps an older config.json's behaviour.
LATER_FIELDS: dict[str, object] = {"warp_references": 3, "reference_flow": 0.0, "reference_detail": 0.0, "crop_scale": 2}


class ModelConfigError(ValueError):
    """A model config is invalid, or a saved model folder does not match its config."""


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """Sizes and switches of the LSR networks. Channel counts are thesis values before ``width`` scaling."""

    variant: Variant = "latent_layout"
    """Ablation variant (thesis Table 4.2): baseline | spade_landmarks | learned_seg | latent_layout | oracle_seg;
    or warp_guided: latent_layout whose G^s also sees the nearest shots TPS-warped to the target and blends them
    with its own output (thesis §4.5.6, "borrow from the warping-based approaches")."""
    resolution: int = 256
    """Square image resolution (power of two)."""
    width: float = 1.0
    """Multiplier on every channel count below (1.0 = thesis sizes)."""
    channel_multiple: int = 16
    """Scaled channel counts are rounded to a multiple of this (multiples of 16 run fastest on CPU)."""
    landmark_channels: int = 3
    """Channels of the rasterised landmark image (3 = RGB contour drawing)."""
    layout_channels: int = NUM_SEG_CLASSES
    """C_l: channels of the layout map predicted by G^l (19 for segmentation pre-training)."""
    layout_activation: Literal["softmax", "none"] = "softmax"
    """How G^l's logits become the SPADE condition: softmax over C_l (a soft segmentation) or raw logits."""
    latent_dim: int = 512
    """Size of the layout latent z^l and the style latent z^s."""
    share_encoder_trunk: bool = True
    """Two-headed encoder E = {E^l, E^s} (§4.3.1) on one ResNet trunk (halves subject-encoding cost) or two."""
    encoder_base_channels: int = 32
    encoder_downsamplings: int = 5
    max_channels: int = 512
    """Cap on every network's channel count (before width scaling)."""
    layout_base_channels: int = 32
    layout_levels: int = 5
    """Resolutions in the layout UNet (levels - 1 blur-pool downsamplings): 32, 64, 128, 256, 512 maps."""
    aux_rgb_head: bool = True
    """G^l also predicts an RGB reconstruction R_t (eq. 4.1, stage-1 regulariser); skipped per frame."""
    generator_last_channels: int = 32
    """Feature maps at the last SPADE generator layer (thesis: 32; original SPADE: 64)."""
    spade_hidden_channels: int = 64
    """Hidden maps of every SPADE norm (thesis: 64; original SPADE: 128)."""
    generator_upsamplings: int = 5
    """The style tensor starts at resolution / 2**generator_upsamplings (SPADE 'normal': 5)."""
    spade_shared_input_modulation: bool = False
    """In blocks with a learned shortcut, the main and shortcut paths share one SPADE of the block input."""
    discriminator_base_channels: int = 32
    discriminator_conditioned: bool = False
    """Discriminator sees the landmark image concatenated to the RGB image."""
    mbstd_group_size: int = 4
    norm_eps: float = 1e-5
    warp_references: int = 3
    """warp_guided only: how many of the nearest shots, TPS-warped to the target, G^s sees and blends."""
    reference_flow: float = 0.0
    """warp_guided only: > 0 lets G^s also predict a residual flow per reference that corrects what the landmark TPS
    got wrong, at most this fraction of the crop side (tanh-bounded); 0 = the warped shots are blended as they are."""
    reference_detail: float = 0.0
    """warp_guided only: > 0 replaces the blend's fine detail with the per-pixel median of the references' detail
    (``models_def.composite.add_reference_detail``), split at a Gaussian of this fraction of the crop side (3/256 at
    256^2: 0.0117); 0 = the blend as it is. A fixed operation on the output: it can be switched on for trained weights."""
    crop_scale: int = 2
    """warp_guided only: the crop side (where the shots are warped and blended, and the output's side) over the
    network's resolution: 2 = a 128^2 network blends and outputs at 256^2, 4 = a 64^2 one. An inference setting:
    training runs at the network's resolution, the blend at any side >= it."""

    def __post_init__(self) -> None:
        def fail(message: str) -> None:
            raise ModelConfigError(f"invalid ModelConfig: {message}")

        if self.variant not in VARIANTS:
            fail(f"variant must be one of {', '.join(VARIANTS)}; got {self.variant!r}")
        if self.layout_activation not in ("softmax", "none"):
            fail(f"layout_activation must be 'softmax' or 'none'; got {self.layout_activation!r}")
        for name in (
            "resolution", "channel_multiple", "landmark_channels", "layout_channels", "latent_dim",
            "encoder_base_channels", "encoder_downsamplings", "max_channels", "layout_base_channels",
            "layout_levels", "generator_last_channels", "spade_hidden_channels", "generator_upsamplings",
            "discriminator_base_channels", "mbstd_group_size", "warp_references",
        ):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                fail(f"{name} must be a positive integer; got {value!r}")
        if not (isinstance(self.width, (int, float)) and math.isfinite(self.width) and self.width > 0):
            fail(f"width must be a positive finite number; got {self.width!r}")
        if not self.norm_eps > 0:
            fail(f"norm_eps must be > 0; got {self.norm_eps!r}")
        if not (isinstance(self.reference_flow, (int, float)) and 0 <= self.reference_flow <= 0.25):
            fail(f"reference_flow must be in [0, 0.25] (a fraction of the crop side); got {self.reference_flow!r}")
        if not (isinstance(self.reference_detail, (int, float)) and 0 <= self.reference_detail <= 0.1):
            fail(f"reference_detail must be in [0, 0.1] (a fraction of the crop side); got {self.reference_detail!r}")
        if self.crop_scale not in (1, 2, 4, 8):
            fail(f"crop_scale must be 1, 2, 4 or 8; got {self.crop_scale!r}")
        if self.resolution & (self.resolution - 1):
            fail(f"resolution must be a power of two (e.g. 64, 128, 256); got {self.resolution}")
        # Every blur-pool needs an input of at least 2 pixels; the generator starts at >= 1 pixel; the
        # discriminator downsamples to 4x4.
        deepest = max(self.encoder_downsamplings, self.layout_levels - 1, self.generator_upsamplings)
        if self.resolution < max(2**deepest, 8):
            fail(
                f"resolution {self.resolution} is too small for {deepest} downsamplings; use a resolution >= "
                f"{max(2**deepest, 8)} or fewer encoder_downsamplings / layout_levels / generator_upsamplings"
            )
        if self.variant in ("learned_seg", "oracle_seg") and self.layout_channels != NUM_SEG_CLASSES:
            fail(
                f"variant {self.variant!r} works on {NUM_SEG_CLASSES}-class segmentations; set "
                f"layout_channels={NUM_SEG_CLASSES} (got {self.layout_channels})"
            )
        if self.variant == "learned_seg" and self.layout_activation != "softmax":
            fail("variant 'learned_seg' feeds a predicted segmentation to SPADE; set layout_activation='softmax'")

    # ---- derived sizes -------------------------------------------------------------------------------------
    def scaled(self, channels: int) -> int:
        """A thesis channel count after the width multiplier, rounded to ``channel_multiple`` (>= 1 multiple)."""
        multiple = self.channel_multiple
        return max(multiple, int(round(channels * self.width / multiple)) * multiple)

    def capped(self, channels: int) -> int:
        return self.scaled(min(channels, self.max_channels))

    @property
    def uses_layout_predictor(self) -> bool:
        return self.variant in LAYOUT_PREDICTOR_VARIANTS

    @property
    def layout_kind(self) -> str:
        """What the frame generator's layout output is (thesis Table 4.2): 'latent' (a learned layout to show as
        PCA colours), 'segmentation' (class scores) or 'none' (no layout predictor)."""
        if self.variant in ("latent_layout", "warp_guided"):
            return "latent"
        if self.variant in ("learned_seg", "oracle_seg"):
            return "segmentation"
        return "none"

    @property
    def uses_references(self) -> bool:
        """The frame generator takes warped shots (variant warp_guided)."""
        return self.variant == "warp_guided"

    @property
    def spade_condition_channels(self) -> int:
        """Channels of the SPADE condition map: layout (predicted or oracle) + landmark image (§4.6)
        [+ per warped reference its RGB and validity mask, warp_guided]."""
        if self.variant == "spade_landmarks":
            return self.landmark_channels
        references = 4 * self.warp_references if self.uses_references else 0
        return self.layout_channels + self.landmark_channels + references

    @property
    def generator_output_channels(self) -> int:
        """RGB [+ one blend logit per warped reference and one for the generated image, warp_guided]
        [+ an (x, y) flow per reference, reference_flow > 0]."""
        if not self.uses_references:
            return 3
        return 3 + self.warp_references + 1 + (2 * self.warp_references if self.reference_flow > 0 else 0)

    @property
    def encoder_input_channels(self) -> int:
        """RGB shot concatenated with its landmark image (§4.6, following FSTH [112])."""
        return 3 + self.landmark_channels

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict) -> ModelConfig:
        """Build from a config.json dict; unknown or missing keys are an error (no silent defaults)."""
        names = {field.name for field in dataclasses.fields(cls)}
        values = {**{k: v for k, v in LATER_FIELDS.items() if k not in values}, **values}
        unknown, missing = sorted(set(values) - names), sorted(names - set(values))
        if unknown or missing:
            raise ModelConfigError(
                f"config keys do not match ModelConfig: unknown {unknown}, missing {missing}; the folder was saved "
                "by a different version of models_def; re-save it or edit config.json to the current fields"
            )
        return cls(**values)

    def replace(self, **changes) -> ModelConfig:
        return dataclasses.replace(self, **changes)
