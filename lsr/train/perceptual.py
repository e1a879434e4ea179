"""Optional VGG perceptual loss (thesis §4.3.3: VGG19 [79] and VGGFace [81] perceptual terms).

No weights can be downloaded by this project, so the loss exists only when the user points at a
weights file. The feature stack is built here in plain torch with torchvision's layer indices, so a
torchvision ``vgg19(...).state_dict()`` (keys ``features.N.weight`` / ``features.N.bias``, ``.pth`` or
``.safetensors``) loads as is; ``classifier.*`` keys are ignored. VGG16-shaped state dicts (13 convs,
e.g. a VGGFace conversion with torchvision key names) are recognised by their conv count.
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lsr.errors import WeightsError

# torchvision's VGG layer plans: channel counts, "M" = 2x2 max pool.
VGG_PLANS: dict[str, list[int | str]] = {
    "vgg16": [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M"],
    "vgg19": [64, 64, "M", 128, 128, "M", 256, 256, 256, 256, "M", 512, 512, 512, 512, "M", 512, 512, 512, 512, "M"],
}
# relu1_1, relu2_1, relu3_1, relu4_1, relu5_1 as indices into `features`, with pix2pixHD's weights.
PERCEPTUAL_LAYERS: dict[str, tuple[int, ...]] = {"vgg16": (1, 6, 11, 18, 25), "vgg19": (1, 6, 11, 20, 29)}
PERCEPTUAL_WEIGHTS = (1 / 32, 1 / 16, 1 / 8, 1 / 4, 1.0)
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

WEIGHTS_HELP = (
    "A VGG19 state dict with torchvision key names works, e.g. on a machine with internet: "
    "python -c \"import torch, torchvision; torch.save(torchvision.models.vgg19(weights='IMAGENET1K_V1')"
    ".state_dict(), 'vgg19.pth')\" then copy vgg19.pth here and pass --train.losses.vgg-weights vgg19.pth; "
    "or leave --train.losses.vgg-weights unset to train with L1 + SSIM + discriminator feature matching."
)


def build_vgg_features(arch: str) -> nn.Sequential:
    """The ``features`` part of torchvision's VGG (conv 3x3 + ReLU, max pools), indices preserved."""
    if arch not in VGG_PLANS:
        raise ValueError(f"unknown VGG arch {arch!r}; choose one of {sorted(VGG_PLANS)}")
    layers: list[nn.Module] = []
    in_channels = 3
    for item in VGG_PLANS[arch]:
        if item == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(in_channels, int(item), kernel_size=3, padding=1), nn.ReLU(inplace=False)]
            in_channels = int(item)
    return nn.Sequential(*layers)


def read_state_dict(path: Path, *, what: str = "VGG weights", help_text: str = WEIGHTS_HELP) -> dict[str, Tensor]:
    """A flat tensor dict from ``.safetensors`` or a torch ``.pth``/``.pt`` file (weights only).

    what / help_text: the backbone named in errors and where to get its weights (one reader for every backbone).
    """
    path = Path(path)
    if not path.is_file():
        raise WeightsError(f"{what} file not found: {path}. {help_text}")
    try:
        if path.suffix == ".safetensors":
            from safetensors.torch import load_file

            state = load_file(str(path))
        else:
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # any reader failure means "not a usable weights file"
        raise WeightsError(f"could not read {what} {path}: {exc}. {help_text}") from exc
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise WeightsError(f"{path} does not hold a state dict (got {type(state).__name__}). {help_text}")
    return state


def load_vgg_features(path: Path) -> tuple[nn.Sequential, str]:
    """Build a VGG feature stack matching the state dict in ``path`` and load it (frozen, eval mode)."""
    state = read_state_dict(path)
    features = {k[len("features."):]: v for k, v in state.items() if k.startswith("features.")}
    conv_count = sum(1 for k in features if k.endswith(".weight"))
    arch = {13: "vgg16", 16: "vgg19"}.get(conv_count)
    if arch is None:
        raise WeightsError(
            f"{path}: expected torchvision VGG keys 'features.N.weight' for 13 (VGG16) or 16 (VGG19) convs, "
            f"found {conv_count}. {WEIGHTS_HELP}"
        )
    net = build_vgg_features(arch)
    try:
        net.load_state_dict(features, strict=True)
    except RuntimeError as exc:
        raise WeightsError(f"{path}: state dict does not match torchvision's {arch} layout: {exc}") from exc
    net.eval().requires_grad_(False)
    return net, arch


class VGGPerceptualLoss(nn.Module):
    """Weighted L1 between VGG activations (relu1_1 .. relu5_1) of fake and real images.

    Inputs: ``fake``, ``real`` (B, 3, H, W) float in [-1, 1]. Output: scalar.
    """

    def __init__(self, weights_path: Path) -> None:
        super().__init__()
        self.features, self.arch = load_vgg_features(weights_path)
        self.layer_ids = PERCEPTUAL_LAYERS[self.arch]
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def train(self, mode: bool = True) -> VGGPerceptualLoss:
        super().train(mode)
        self.features.eval()  # a frozen loss network never switches to training mode
        return self

    def _activations(self, images: Tensor) -> list[Tensor]:
        x = ((images + 1) / 2 - self.mean) / self.std
        out = []
        for index, layer in enumerate(self.features):
            x = layer(x)
            if index in self.layer_ids:
                out.append(x)
            if index >= self.layer_ids[-1]:
                break
        return out

    def forward(self, fake: Tensor, real: Tensor) -> Tensor:
        if fake.shape != real.shape or fake.ndim != 4 or fake.shape[1] != 3:
            raise ValueError(f"fake and real must both be (B, 3, H, W); got {tuple(fake.shape)} and {tuple(real.shape)}")
        with torch.no_grad():
            real_acts = self._activations(real)
        fake_acts = self._activations(fake)
        terms = [w * F.l1_loss(f, r) for w, f, r in zip(PERCEPTUAL_WEIGHTS, fake_acts, real_acts, strict=True)]
        return torch.stack(terms).sum()
