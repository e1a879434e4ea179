"""``lsr train --init-from WEIGHTS``: start a run from a trained model folder instead of random weights.

Parameters of the same shape are copied. Layers that the new model widens (the warp-guided generator's SPADE
condition projections, which also see the warped references, and its last conv, which also predicts the blend
logits) keep the old weights on the old channels and start the new channels at zero, so the warm-started
model first behaves like the old one on its old inputs (for the new logits: a uniform blend). Equalised-LR
convs scale their weights by 1/sqrt(fan_in) at run time, so widened inputs are rescaled to keep the old output.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from lsr.errors import WeightsError
from models_def import Discriminator, LSRModel


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


def warm_start(model: LSRModel, discriminator: Discriminator, folder: str | Path) -> list[str]:
    """Load ``folder`` (config.json + model.safetensors [+ discriminator.safetensors]) into the new nets in place.

    Returns the names of the widened parameters. Raises WeightsError on anything else that does not fit.
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
    widened, merged = [], {}
    for name, new in new_state.items():
        old = old_state[name]
        if old.shape == new.shape:
            merged[name] = old
        else:
            merged[name] = _widened(name, old, new)
            widened.append(name)
    model.load_state_dict(merged)
    old_discriminator, found = load_discriminator(folder, source)
    if found:
        discriminator.load_state_dict(old_discriminator.state_dict())
    return widened
