"""NaN/inf guard: skip bad steps, recover from a run of them, stop with a clear error if that fails.

Policy (all counts configurable):
* a step whose loss or gradients are non-finite is skipped (no optimiser update) and counted;
* ``max_consecutive`` skipped steps in a row ask the trainer to restore the last good checkpoint and
  halve the learning rate (a "recovery");
* more than ``max_recoveries`` recoveries raise :class:`TrainingDivergedError`.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch
from torch import Tensor

from lsr.errors import LsrError


class TrainingDivergedError(LsrError):
    """Training keeps producing NaN/inf even after restoring a checkpoint and lowering the lr."""


def all_finite(loss: Tensor | None, parameters: Iterable[torch.nn.Parameter]) -> bool:
    """True when ``loss`` and every existing gradient of ``parameters`` are finite (one sync)."""
    checks = [] if loss is None else [torch.isfinite(loss.detach()).all()]
    checks += [torch.isfinite(p.grad).all() for p in parameters if p.grad is not None]
    return bool(torch.stack(checks).all()) if checks else True


class NonFiniteGuard:
    """Counts skipped steps and decides when to recover or give up. Holds no tensors."""

    def __init__(self, max_consecutive: int = 5, max_recoveries: int = 2) -> None:
        if max_consecutive < 1 or max_recoveries < 0:
            raise ValueError("max_consecutive must be >= 1 and max_recoveries >= 0")
        self.max_consecutive = max_consecutive
        self.max_recoveries = max_recoveries
        self.skipped_total = 0
        self.consecutive = 0
        self.recoveries = 0

    def record(self, finite: bool) -> bool:
        """Record one step's outcome; returns True when the trainer must recover now."""
        if finite:
            self.consecutive = 0
            return False
        self.skipped_total += 1
        self.consecutive += 1
        return self.consecutive >= self.max_consecutive

    def start_recovery(self, step: int) -> None:
        """Call before restoring a checkpoint; raises once the recovery budget is spent."""
        if self.recoveries >= self.max_recoveries:
            raise TrainingDivergedError(
                f"training diverged at step {step}: {self.consecutive} non-finite steps in a row after "
                f"{self.recoveries} checkpoint restores with halved learning rates "
                f"({self.skipped_total} skipped in total). Lower --train.optim.lr, enable fp32 "
                f"(--train.precision fp32), check the data for broken frames, or resume from an earlier checkpoint."
            )
        self.recoveries += 1
        self.consecutive = 0

    def state_dict(self) -> dict[str, int]:
        return {"skipped_total": self.skipped_total, "consecutive": self.consecutive, "recoveries": self.recoveries}

    def load_state_dict(self, state: dict[str, int]) -> None:
        self.skipped_total = int(state["skipped_total"])
        self.consecutive = int(state["consecutive"])
        self.recoveries = int(state["recoveries"])
