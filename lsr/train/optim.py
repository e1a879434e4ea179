"""Optimisers, the learning-rate schedule and the EMA of the generators (thesis §4.6).

Adam with beta1 = 0, beta2 = 0.999 and lr 1e-3 for every network; the lr decays linearly to
1/100 of its value over the final window of steps ("during the last epoch").
"""

from __future__ import annotations

import copy

import torch
from torch import nn


def make_adam(parameters, lr: float, betas: tuple[float, float], eps: float = 1e-8) -> torch.optim.Adam:
    return torch.optim.Adam(list(parameters), lr=lr, betas=betas, eps=eps)


def lr_factor(step: int, total_steps: int, decay_steps: int, final_factor: float = 0.01) -> float:
    """Multiplier on the base lr at ``step`` (0-based): 1 until the last ``decay_steps``, then linear to ``final_factor``."""
    decay_start = total_steps - decay_steps
    if decay_steps <= 0 or step < decay_start:
        return 1.0
    progress = min(1.0, (step - decay_start + 1) / decay_steps)
    return 1.0 + (final_factor - 1.0) * progress


def set_lr(optimizer: torch.optim.Optimizer, lr: float) -> None:
    for group in optimizer.param_groups:
        group["lr"] = lr


class EMA:
    """Exponential moving average of a module's parameters (buffers copied), used for eval and export.

    ``decay`` is per step; ``update`` after every optimiser step. The averaged copy lives in
    ``self.module`` (eval mode, no grads).
    """

    def __init__(self, module: nn.Module, decay: float = 0.999) -> None:
        if not 0.0 <= decay < 1.0:
            raise ValueError(f"EMA decay must be in [0, 1), got {decay}")
        self.decay = decay
        self.module = copy.deepcopy(module).eval().requires_grad_(False)

    def decay_at(self, num_updates: int | None) -> float:
        """The decay, ramped up as (1 + n) / (10 + n) over the first updates so short runs export trained weights."""
        if num_updates is None:
            return self.decay
        return min(self.decay, (1.0 + num_updates) / (10.0 + num_updates))

    @torch.no_grad()
    def update(self, module: nn.Module, num_updates: int | None = None) -> None:
        decay = self.decay_at(num_updates)
        ema_params = dict(self.module.named_parameters())
        for name, param in module.named_parameters():
            ema_params[name].lerp_(param.detach(), 1.0 - decay)
        ema_buffers = dict(self.module.named_buffers())
        for name, buffer in module.named_buffers():
            ema_buffers[name].copy_(buffer)

    def state_dict(self) -> dict[str, torch.Tensor]:
        return self.module.state_dict()

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.module.load_state_dict(state)
