"""``lsr train --init-from WEIGHTS``: start a run from a trained model folder instead of random weights.

Parameters of the same shape are copied. Layers that the new model widens (the warp-guided generator's SPADE
condition projections, which also see the warped references, and its last conv, which also predicts the blend
logits) keep the old weights on the old channels and start the new channels at zero, so the warm-started
model first behaves like the old one on its old inputs (for the new logits: a uniform blend). A warp-guided model
warm-started with more references (``--warp-references``) keeps each old reference's and mask's channels, and
the new references start silent (see ``_reference_slots``). Equalised-LR
convs scale their weights by 1/sqrt(fan_in) at run time, so widened inputs are rescaled to keep the old output.

A model of another resolution (``--resolution``; every layer is convolutional but two) is warm-started too: G^s's
learned start grid (``style_to_input``, resolution / 2^upsamplings cells a side) is resampled to the new grid
(area-averaged down, repeated up), and D, whose depth follows the resolution, starts fresh.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from lsr.errors import WeightsError
from models_def import Discriminator, LSRModel, ModelConfig


def _widened(name: str, old: torch.Tensor, new: torch.Tensor) -> torch.Tensor:
    """``old`` placed in the leading slice of a zero tensor shaped like ``new`` (input channels, output rows)."""
    if old.dim() != new.dim() or any(o > n for o, n in zip(old.shape, new.shape)):
        raise WeightsError(f"--init-from: {name} has shape {tuple(old.shape)}, the new model needs {tuple(new.shape)}; "
                           "only added input or output channels can be warm-started (same preset and resolution)")
    result = torch.zeros_like(new)
    result[tuple(slice(0, size) for size in old.shape)] = old
    if old.dim() == 4 and old.shape[1] != new.shape[1]:  # EqualConv2d: keep weight / sqrt(fan_in) unchanged
        result *= math.sqrt(new.shape[1] / old.shape[1])
    return result


# A new reference's blend logit starts as the farthest old reference's, this much lower: it gets a little weight
# (e^-2 of that reference's) and a gradient, and the warm-started blend is almost the old one.
NEW_REFERENCE_LOGIT_OFFSET = -2.0


def _reference_slots(old: ModelConfig, new: ModelConfig) -> tuple[list[int | None], list[int | None]]:
    """Where each new SPADE-condition channel and each new generator output channel comes from in the old model.

    Condition: layout + landmark image, then 3 RGB channels per reference, then 1 mask per reference; output: RGB,
    one blend logit per reference, then the generated image's logit. Returns, per new channel, the old channel
    index, or None for a new reference's input (starts at zero). A new reference's output logit copies the last
    old reference's (its bias lowered by NEW_REFERENCE_LOGIT_OFFSET, see ``_remap_references``)."""
    base = old.layout_channels + old.landmark_channels
    old_count, new_count = old.warp_references, new.warp_references
    condition: list[int | None] = list(range(base))
    condition += [base + c if c < 3 * old_count else None for c in range(3 * new_count)]
    condition += [base + 3 * old_count + r if r < old_count else None for r in range(new_count)]
    output: list[int | None] = [0, 1, 2] + [3 + min(r, old_count - 1) for r in range(new_count)] + [3 + old_count]
    return condition, output


def _remap_references(name: str, old: torch.Tensor, new: torch.Tensor, old_config: ModelConfig,
                      new_config: ModelConfig) -> torch.Tensor | None:
    """A warp-guided parameter whose shape depends on the reference count, moved to the new count (None: not one)."""
    condition, output = _reference_slots(old_config, new_config)
    result = torch.zeros_like(new)
    if name.endswith("projection.conv.weight") and old.dim() == 4 and new.shape[1] == len(condition):
        for index, source in enumerate(condition):
            if source is not None:
                result[:, index] = old[:, source]
        return result * math.sqrt(new.shape[1] / old.shape[1])  # EqualConv2d: keep weight / sqrt(fan_in)
    if name.endswith("to_rgb.weight") or name.endswith("to_rgb.bias"):
        if new.shape[0] != len(output):
            return None
        for index, source in enumerate(output):
            result[index] = old[source]
        if name.endswith("bias"):
            for index in range(3 + old_config.warp_references, 3 + new_config.warp_references):
                result[index] += NEW_REFERENCE_LOGIT_OFFSET
        return result
    return None


def _resampled_start(name: str, old: torch.Tensor, new: torch.Tensor, channels: int) -> torch.Tensor | None:
    """G^s's ``style_to_input`` (rows: channels x side x side start cells) moved to the new model's start grid
    (None: not that parameter, or not a square grid change). Down: each new cell the mean of the old cells it
    covers; up: each old cell repeated over the new cells it covers."""
    if "style_to_input" not in name or old.shape[1:] != new.shape[1:]:
        return None
    old_side, new_side = math.isqrt(old.shape[0] // channels), math.isqrt(new.shape[0] // channels)
    if channels * old_side**2 != old.shape[0] or channels * new_side**2 != new.shape[0]:
        return None
    grid = old.reshape(channels, old_side, old_side, -1).permute(0, 3, 1, 2)  # (C, D or 1, side, side)
    if new_side < old_side:
        grid = torch.nn.functional.adaptive_avg_pool2d(grid, new_side)
    else:
        grid = torch.nn.functional.interpolate(grid, size=(new_side, new_side), mode="nearest")
    return grid.permute(0, 2, 3, 1).reshape(new.shape).contiguous()


def warm_start(model: LSRModel, discriminator: Discriminator, folder: str | Path) -> list[str]:
    """Load ``folder`` (config.json + model.safetensors [+ discriminator.safetensors]) into the new nets in place.

    Returns the names of the widened (or, at another resolution, resampled) parameters. Raises WeightsError on
    anything else that does not fit.
    """
    from lsr.train.finetune import load_discriminator

    folder = Path(folder)
    try:
        source = LSRModel.from_pretrained(folder)
    except (ValueError, OSError) as exc:
        raise WeightsError(f"--init-from {folder}: {exc}") from exc
    old_state, new_state = source.state_dict(), model.state_dict()
    missing = sorted(set(new_state) - set(old_state))
    if missing:
        raise WeightsError(f"--init-from {folder}: the new model has parameters the old one lacks ({', '.join(missing[:3])}); "
                           "warm-start from a model of the same preset")
    recount = (source.config.uses_references and model.config.uses_references
               and source.config.warp_references != model.config.warp_references)
    resized = source.config.resolution != model.config.resolution
    generator = model.frame_generator.image_generator
    widened, merged = [], {}
    for name, new in new_state.items():
        old = old_state[name]
        if old.shape == new.shape:
            merged[name] = old
            continue
        remapped = _remap_references(name, old, new, source.config, model.config) if recount else None
        if remapped is None and resized and generator is not None:
            remapped = _resampled_start(name, old, new, generator.start_channels)
        merged[name] = remapped if remapped is not None else _widened(name, old, new)
        widened.append(name)
    model.load_state_dict(merged)
    if resized:  # D's depth follows the resolution: it starts fresh
        return widened
    old_discriminator, found = load_discriminator(folder, source)
    if found:
        discriminator.load_state_dict(old_discriminator.state_dict())
    return widened
