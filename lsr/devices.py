"""The one device resolver of the CLI (``--device auto|cpu|cuda``)."""

from __future__ import annotations

import torch

from lsr.errors import ConfigError


def resolve_device(name: str | torch.device) -> torch.device:
    """'auto' -> cuda when a GPU is visible, else cpu; 'cuda' without a GPU is a ConfigError naming the fix."""
    if isinstance(name, torch.device):
        return name
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError("--device cuda was asked for but no CUDA GPU is visible; use --device cpu or auto")
    return torch.device(name)
