"""Named model sizes. Each preset is a set of ``ModelConfig`` overrides: width, resolution, layout channels.

* ``paper``: the thesis sizes (§4.6) at 256^2.
* ``small``: half width at 256^2.
* ``fast``: the cheapest per-frame path that keeps the method (see ``lsr bench models`` for its ms/frame).
* ``tiny``: a few tens of thousands of parameters at 64^2, for tests and CI.
"""

from __future__ import annotations

from models_def.config import ModelConfig, ModelConfigError

PRESETS: dict[str, dict] = {
    "paper": {},
    "small": {"width": 0.5},
    # ~7.9 GFLOP per 256^2 frame (paper: ~102): narrow full-resolution layers (16 maps, SPADE hidden 16) where
    # the FLOPs are, every channel count a multiple of 16, one SPADE of the block input for both paths.
    "fast": {
        "width": 0.5,
        "layout_base_channels": 16,
        "generator_last_channels": 16,
        "spade_hidden_channels": 32,
        "spade_shared_input_modulation": True,
    },
    # The shipped default (lsr/weights/default): sized to train on a 2-core CPU in under 1.5 hours at 128^2
    # (MODEL_CARD.md). Its error against a trained paper-width model is not measured yet: that needs a GPU.
    "compact": {
        "resolution": 128,
        "width": 0.25,
        "channel_multiple": 8,
        "latent_dim": 64,
        "max_channels": 256,
    },
    "tiny": {
        "resolution": 64,
        "width": 0.125,
        "channel_multiple": 4,
        "latent_dim": 16,
        "max_channels": 64,
    },
}
PRESET_NAMES: tuple[str, ...] = tuple(PRESETS)


def preset_config(name: str, **overrides) -> ModelConfig:
    """ModelConfig of preset ``name`` with ``overrides`` (any ModelConfig field, e.g. variant='oracle_seg')."""
    if name not in PRESETS:
        raise ModelConfigError(f"unknown model preset {name!r}; choose one of {', '.join(PRESET_NAMES)}")
    return ModelConfig(**{**PRESETS[name], **overrides})
