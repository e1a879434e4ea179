"""LPIPS (Zhang et al. 2018, "The Unreasonable Effectiveness of Deep Features as a Perceptual Metric"),
AlexNet variant v0.1 as the thesis reports it (Table 4.4, §4.4 "Metrics").

No weights can be downloaded by this project, so LPIPS exists only when the user passes one weights
file (``--lpips-weights``, ``.pth`` read with ``weights_only=True`` or ``.safetensors``) holding

  * the AlexNet ``features`` convolutions, under either key scheme (both are accepted, see
    ``canonical_key``):
      - the ``lpips`` package's  ``net.slice{s}.{i}.weight`` / ``.bias`` (s = 1..5, i = torchvision index),
      - torchvision's            ``features.{i}.weight`` / ``.bias``, i in 0, 3, 6, 8, 10;
  * the five linear heads ``lin{l}.model.1.weight`` of shape (1, C_l, 1, 1), C = 64, 192, 384, 256, 256
    (the ``lpips`` package's ``weights/v0.1/alex.pth``).

Other keys (``scaling_layer.*``, ``classifier.*``) are ignored. See ``WEIGHTS_HELP`` for how to make
such a file on a machine with internet.

Computation (as the official package): inputs in [-1, 1] -> scaling layer ((x - shift) / scale) ->
AlexNet taps after the 5 ReLUs -> unit-normalise over channels -> squared difference -> 1x1 linear
head -> spatial mean -> sum over the 5 layers.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from lsr.errors import ConfigError, WeightsError

# torchvision alexnet().features: (index, in, out, kernel, stride, padding) of the 5 convs.
ALEXNET_CONVS = ((0, 3, 64, 11, 4, 2), (3, 64, 192, 5, 1, 2), (6, 192, 384, 3, 1, 1), (8, 384, 256, 3, 1, 1), (10, 256, 256, 3, 1, 1))
MAX_POOL_INDICES = (2, 5)  # the third pool (index 12) lies after the last tap and is not built
TAP_INDICES = (1, 4, 7, 9, 11)  # the ReLUs after each conv
TAP_CHANNELS = (64, 192, 384, 256, 256)
# lpips package's AlexNet slices: slice s holds these torchvision indices.
LPIPS_SLICES = {1: range(0, 2), 2: range(2, 5), 3: range(5, 8), 4: range(8, 10), 5: range(10, 12)}
SCALING_SHIFT = (-0.030, -0.088, -0.188)  # lpips ScalingLayer: ImageNet statistics in [-1, 1] units
SCALING_SCALE = (0.458, 0.448, 0.450)
NORMALISE_EPS = 1e-10  # lpips.normalize_tensor
MIN_SIDE = 32  # smaller images vanish in AlexNet's stride-4 conv and two pools

WEIGHTS_HELP = (
    "LPIPS needs one file with AlexNet features + LPIPS v0.1 heads. On a machine with internet and "
    "`pip install lpips torchvision`: python -c \"import torch, lpips; "
    "torch.save(lpips.LPIPS(net='alex', version='0.1').state_dict(), 'lpips_alex.pth')\" "
    "(or merge by hand: python -c \"import torch, torchvision, lpips, os; "
    "d = {k: v for k, v in torchvision.models.alexnet(weights='IMAGENET1K_V1').state_dict().items() if k.startswith('features.')}; "
    "d.update(torch.load(os.path.join(os.path.dirname(lpips.__file__), 'weights/v0.1/alex.pth'))); "
    "torch.save(d, 'lpips_alex.pth')\"), copy lpips_alex.pth here and pass --lpips-weights lpips_alex.pth; "
    "or leave --lpips-weights unset (the report then says LPIPS was not computed)."
)

_LPIPS_NET_KEY = re.compile(r"^net\.slice([1-5])\.(\d+)\.(weight|bias)$")


def build_alexnet_features() -> nn.Sequential:
    """torchvision's ``alexnet().features`` up to the last ReLU (indices 0..11 preserved)."""
    layers: dict[int, nn.Module] = {}
    for index, in_channels, out_channels, kernel, stride, padding in ALEXNET_CONVS:
        layers[index] = nn.Conv2d(in_channels, out_channels, kernel_size=kernel, stride=stride, padding=padding)
        layers[index + 1] = nn.ReLU(inplace=False)
    for index in MAX_POOL_INDICES:
        layers[index] = nn.MaxPool2d(kernel_size=3, stride=2)
    return nn.Sequential(*(layers[i] for i in range(len(layers))))


def canonical_key(key: str) -> str | None:
    """Map a weights-file key to this module's key, or None for keys LPIPS does not use.

    ``net.slice{s}.{i}.{w|b}`` (lpips package) and ``features.{i}.{w|b}`` (torchvision) -> ``features.{i}.{w|b}``;
    ``lin{l}.model.1.weight`` -> ``heads.{l}.weight``. A ``net.slice`` index outside its slice is kept
    unmapped (returned as is) so that loading reports it.
    """
    match = _LPIPS_NET_KEY.match(key)
    if match:
        slice_number, index, kind = int(match[1]), int(match[2]), match[3]
        return f"features.{index}.{kind}" if index in LPIPS_SLICES[slice_number] else key
    if key.startswith("features."):
        return key
    head = re.match(r"^lin([0-4])\.model\.1\.weight$", key)
    if head:
        return f"heads.{head[1]}.weight"
    if key.startswith(("net.", "lin")):
        return key  # looks like LPIPS but is not a known key: reported as unexpected
    return None  # scaling_layer.*, classifier.*, ...


class Lpips(nn.Module):
    """LPIPS distance. forward(first, second): (B, 3, H, W) float in [-1, 1], H, W >= 32 -> (B,) float.

    Built with random weights; ``load_lpips`` fills it from a file. Always frozen, eval mode.
    """

    def __init__(self) -> None:
        super().__init__()
        self.features = build_alexnet_features()
        self.heads = nn.ModuleList(nn.Conv2d(c, 1, kernel_size=1, bias=False) for c in TAP_CHANNELS)
        self.register_buffer("shift", torch.tensor(SCALING_SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(SCALING_SCALE).view(1, 3, 1, 1), persistent=False)
        self.eval().requires_grad_(False)

    def train(self, mode: bool = True) -> Lpips:
        return super().train(False)  # a metric never switches to training mode

    def _taps(self, images: Tensor) -> list[Tensor]:
        x = (images - self.shift) / self.scale
        taps = []
        for index, layer in enumerate(self.features):
            x = layer(x)
            if index in TAP_INDICES:
                # unit length over channels (lpips.normalize_tensor)
                taps.append(x / (torch.sqrt(torch.sum(x**2, dim=1, keepdim=True)) + NORMALISE_EPS))
        return taps

    def forward(self, first: Tensor, second: Tensor) -> Tensor:
        if first.shape != second.shape or first.ndim != 4 or first.shape[1] != 3:
            raise ValueError(f"first and second must both be (B, 3, H, W); got {tuple(first.shape)} and {tuple(second.shape)}")
        if min(first.shape[-2:]) < MIN_SIDE:
            raise ValueError(f"LPIPS needs images of at least {MIN_SIDE}x{MIN_SIDE}, got {tuple(first.shape[-2:])}")
        distance = first.new_zeros(first.shape[0])
        for head, tap_first, tap_second in zip(self.heads, self._taps(first), self._taps(second), strict=True):
            distance = distance + head((tap_first - tap_second) ** 2).mean(dim=(1, 2, 3))  # spatial mean of (B, 1, h, w)
        return distance


def load_lpips(path: Path, device: str = "cpu") -> Lpips:
    """An ``Lpips`` with the weights in ``path`` (see the module docstring for the accepted keys).

    WeightsError (with ``WEIGHTS_HELP``) when the file is missing or unreadable, when keys are
    missing or unexpected, or when shapes do not match.
    """
    from lsr.train.perceptual import read_state_dict  # one reader of .pth / .safetensors for every backbone

    path = Path(path)
    state = read_state_dict(path, what="LPIPS weights", help_text=WEIGHTS_HELP)
    model = Lpips()
    expected = {key: value.shape for key, value in model.state_dict().items()}
    mapped: dict[str, Tensor] = {}
    unexpected = []
    for key, value in state.items():
        target = canonical_key(key)
        if target is None:
            continue
        if target not in expected:
            unexpected.append(key)
        elif target in mapped:
            raise WeightsError(f"{path}: {target} is given twice (lpips and torchvision key names mixed?). {WEIGHTS_HELP}")
        else:
            mapped[target] = value
    missing = sorted(set(expected) - set(mapped))
    wrong_shape = [f"{k}: {tuple(v.shape)} (expected {tuple(expected[k])})" for k, v in mapped.items()
                   if not isinstance(v, Tensor) or v.shape != expected[k]]
    if missing or unexpected or wrong_shape:
        problems = []
        if missing:
            problems.append(f"missing {missing}")
        if unexpected:
            problems.append(f"unexpected {sorted(unexpected)}")
        if wrong_shape:
            problems.append(f"wrong shapes {wrong_shape}")
        raise WeightsError(f"{path} is not an LPIPS AlexNet weights file: {'; '.join(problems)}. {WEIGHTS_HELP}")
    model.load_state_dict({k: v.to(torch.float32) for k, v in mapped.items()}, strict=True)
    return model.to(device)


def uint8_to_tensor(images: np.ndarray, device: str | torch.device = "cpu") -> Tensor:
    """(N, H, W, 3) uint8 RGB -> (N, 3, H, W) float32 in [-1, 1] (the range LPIPS was trained on)."""
    return torch.from_numpy(np.ascontiguousarray(images)).to(device).permute(0, 3, 1, 2).to(torch.float32) / 127.5 - 1.0


def lpips_distance(model: Lpips, outputs: np.ndarray, targets: np.ndarray, batch_size: int = 16) -> np.ndarray:
    """Per-frame LPIPS. outputs, targets: (N, H, W, 3) uint8 RGB, H, W >= 32 -> (N,) float64 (0 = identical)."""
    if outputs.shape != targets.shape or outputs.ndim != 4 or outputs.shape[-1] != 3:
        raise ConfigError(f"LPIPS images must both be (N, H, W, 3), got {outputs.shape} and {targets.shape}")
    if outputs.dtype != np.uint8 or targets.dtype != np.uint8:
        raise ConfigError(f"LPIPS images must be uint8 RGB, got {outputs.dtype} and {targets.dtype}")
    if min(outputs.shape[1:3]) < MIN_SIDE:
        raise ConfigError(f"LPIPS needs images of at least {MIN_SIDE}x{MIN_SIDE} pixels, got {outputs.shape[1:3]}")
    device = model.shift.device
    values = []
    with torch.no_grad():
        for start in range(0, len(outputs), batch_size):
            chunk = slice(start, start + batch_size)
            values.append(model(uint8_to_tensor(outputs[chunk], device), uint8_to_tensor(targets[chunk], device)).double().cpu())
    return torch.cat(values).numpy() if values else np.zeros(0)
