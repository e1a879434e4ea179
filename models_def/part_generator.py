"""A part generator: redraws one face part (the mouth) in its own window from the target's part landmarks.

The frame generator blends warped shots; where the shots' mouths disagree or none shows the target's mouth, the
blend hedges (lips stretched over where the cavity should be, two sets of teeth). This network sees the
window of that synthesis (``landmarks.parts.part_window``: the mouth's square, level with the eyes, at the part's own
resolution) with the open mouth blanked out (``PartGeneratorConfig.hole``) and the target's lips as two masks (the
outer-lip polygon, the open mouth inside the inner lips), and returns the window redrawn: a residual over that
input, so the skin and lips the blend got right pass through and the inside of the mouth is drawn. An interior
generator (``PartGeneratorConfig.interior``) changes the open mouth alone.

forward(window: (B, 3, P, P) in [-1, 1], masks: (B, 2, P, P) in [0, 1]) -> (B, 3, P, P) in [-1, 1].

A UNet of plain convolutions (no normalisation: one frame at a time, ONNX-friendly), P divisible by 8.
Trained by ``lsr.train.part_training`` on the frame generator's own outputs for held-out frames of the training clips.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from models_def.config import ModelConfigError

CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"
MOUTH_FOLDER = "mouth"
"""A model folder's mouth generator, when it has one: ``<weights>/mouth/`` (config.json + model.safetensors)."""


@dataclasses.dataclass(frozen=True)
class PartGeneratorConfig:
    """Sizes of a part generator. ``part`` names its window (``landmarks.parts.part_window``), ``size`` its side."""

    part: str = "mouth"
    size: int = 80
    widths: tuple[int, ...] = (16, 32, 48, 64)
    mask_channels: int = 2
    hole: int = 2
    """The window is blanked where the last mask (the open mouth) is, grown by this many pixels, before the network
    sees it: what the blend put there (stretched lips, another shot's teeth) is not kept; the network draws it.
    -1: nothing is blanked."""
    interior: bool = False
    """The network draws only the open mouth (grown by ``hole``, feathered by a pixel): the rest of the window,
    lips included, is the synthesis', unchanged. Needs ``hole`` >= 0."""

    def __post_init__(self) -> None:
        if self.interior and self.hole < 0:
            raise ModelConfigError("an interior generator needs hole >= 0 (the region it draws)")
        levels = len(self.widths)
        if levels < 2 or any(w < 1 for w in self.widths):
            raise ModelConfigError(f"widths must be two or more positive channel counts, got {self.widths}")
        if self.size % (2 ** (levels - 1)):
            raise ModelConfigError(f"size must be divisible by {2 ** (levels - 1)} for {levels} levels, got {self.size}")

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "widths": list(self.widths)}

    @classmethod
    def from_dict(cls, values: dict) -> PartGeneratorConfig:
        known = {field.name for field in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known - {"_class_name"})
        if unknown:
            raise ModelConfigError(f"unknown part generator config fields {unknown}")
        kept = {key: value for key, value in values.items() if key in known}
        if "widths" in kept:
            kept["widths"] = tuple(int(w) for w in kept["widths"])
        return cls(**kept)


def _conv(in_channels: int, out_channels: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_channels, out_channels, 3, stride=stride, padding=1)


class PartGenerator(nn.Module):
    """See the module docstring."""

    def __init__(self, config: PartGeneratorConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or PartGeneratorConfig()
        widths = config.widths
        self.stem = _conv(3 + config.mask_channels, widths[0])
        self.down = nn.ModuleList()
        self.encode = nn.ModuleList()
        for previous, width in zip(widths[:-1], widths[1:]):
            self.down.append(_conv(previous, width, stride=2))
            self.encode.append(_conv(width, width))
        self.bottom = _conv(widths[-1], widths[-1])
        self.decode = nn.ModuleList(_conv(deeper + width, width) for deeper, width in zip(widths[:0:-1], widths[-2::-1]))
        self.refine = _conv(widths[0], widths[0])
        self.out = nn.Conv2d(widths[0], 3, 3, padding=1)
        nn.init.zeros_(self.out.weight)  # starts as the identity: the blend passes through
        nn.init.zeros_(self.out.bias)

    def forward(self, window: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
        size = self.config.size
        if window.shape[1:] != (3, size, size) or masks.shape[1:] != (self.config.mask_channels, size, size):
            raise ValueError(f"expected window (B, 3, {size}, {size}) and masks (B, {self.config.mask_channels}, "
                             f"{size}, {size}), got {tuple(window.shape)} and {tuple(masks.shape)}")
        window, masks = window.clamp(-1.0, 1.0), masks.clamp(0.0, 1.0)
        synthesis, hole = window, None
        if self.config.hole >= 0:  # blank the open mouth: drawn, not kept from the blend
            reach = self.config.hole
            hole = F.max_pool2d(masks[:, -1:], 2 * reach + 1, stride=1, padding=reach) if reach else masks[:, -1:]
            window = window * (1.0 - hole)
        x = F.leaky_relu(self.stem(torch.cat([window, masks], dim=1)), 0.2)
        skips = [x]
        for down, encode in zip(self.down, self.encode):
            x = F.leaky_relu(encode(F.leaky_relu(down(x), 0.2)), 0.2)
            skips.append(x)
        x = F.leaky_relu(self.bottom(x), 0.2)
        for decode, skip in zip(self.decode, skips[-2::-1]):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = F.leaky_relu(decode(torch.cat([x, skip], dim=1)), 0.2)
        x = F.leaky_relu(self.refine(x), 0.2)
        drawn = (window + self.out(x)).clamp(-1.0, 1.0)
        if not self.config.interior or hole is None:
            return drawn
        inside = F.avg_pool2d(hole, 3, stride=1, padding=1, count_include_pad=False) * hole  # 0 outside the hole
        return synthesis + inside * (drawn - synthesis)

    def save_pretrained(self, folder: str | os.PathLike) -> Path:
        from safetensors.torch import save_file

        from models_def.serialization import _atomic_write

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        tensors = {name: tensor.detach().contiguous().cpu() for name, tensor in self.state_dict().items()}
        _atomic_write(folder / WEIGHTS_NAME, lambda temp: save_file(tensors, temp, metadata={"format": "pt"}))
        text = json.dumps({"_class_name": type(self).__name__, **self.config.to_dict()}, indent=2, sort_keys=True)
        _atomic_write(folder / CONFIG_NAME, lambda temp: Path(temp).write_text(text + "\n"))
        return folder

    @classmethod
    def from_pretrained(cls, folder: str | os.PathLike) -> PartGenerator:
        from safetensors import SafetensorError
        from safetensors.torch import load_file

        folder = Path(folder)
        try:
            values = json.loads((folder / CONFIG_NAME).read_text())
        except (OSError, ValueError) as exc:
            raise ModelConfigError(f"{folder / CONFIG_NAME}: cannot read a part generator config ({exc})") from exc
        if values.get("_class_name") != cls.__name__:
            raise ModelConfigError(f"{folder} holds a {values.get('_class_name')!r}, not a {cls.__name__}")
        model = cls(PartGeneratorConfig.from_dict(values))
        try:
            model.load_state_dict(load_file(str(folder / WEIGHTS_NAME)))
        except (OSError, SafetensorError, RuntimeError) as exc:
            raise ModelConfigError(f"{folder / WEIGHTS_NAME}: does not match its config ({exc})") from exc
        return model.eval()


def load_mouth_generator(weights: str | os.PathLike) -> PartGenerator | None:
    """The mouth generator of model folder ``weights`` (``MOUTH_FOLDER``), or None when it has none."""
    folder = Path(weights) / MOUTH_FOLDER
    return PartGenerator.from_pretrained(folder) if (folder / CONFIG_NAME).is_file() else None


class PartDiscriminator(nn.Module):
    """A patch discriminator for a part generator's training (not shipped in the runtime): (window (B, 3, P, P) in
    [-1, 1], masks (B, 2, P, P)) -> (B, 1, P / 8, P / 8) logits, each judging a patch of the window with its lips."""

    def __init__(self, config: PartGeneratorConfig | None = None, width: int = 32) -> None:
        super().__init__()
        self.config = config = config or PartGeneratorConfig()
        channels = [3 + config.mask_channels, width, 2 * width, 4 * width]
        self.layers = nn.ModuleList(nn.Conv2d(a, b, 4, stride=2, padding=1) for a, b in zip(channels[:-1], channels[1:]))
        self.head = nn.Conv2d(channels[-1], 1, 3, padding=1)

    def forward(self, window: torch.Tensor, masks: torch.Tensor, features: bool = False):
        """Logits; with ``features``, (logits, [each layer's activations]) for a feature-matching loss."""
        x = torch.cat([window, masks], dim=1)
        layers = []
        for layer in self.layers:
            x = F.leaky_relu(layer(x), 0.2)
            layers.append(x)
        logits = self.head(x)
        return (logits, layers) if features else logits
