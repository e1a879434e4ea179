"""Full training checkpoints: atomic, finite-only, the last k kept, resume-exact.

A checkpoint is one ``torch.save`` dict holding everything a resumed run needs to continue
bit-for-bit: networks, EMA, both optimisers, grad scaler, step/stage, data position, the RNG
states of torch/numpy/python/cuda, and the config (rosinality keeps G, D, G_ema and both
optimisers; stylegan3's snapshots that drop optimiser state are what we avoid).
"""

from __future__ import annotations

import os
import random
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lsr.errors import LsrError

CHECKPOINT_PATTERN = re.compile(r"^step_(\d{9})\.pt$")
DISCRIMINATOR_NAME = "discriminator.safetensors"  # D beside exported weights, for subject fine-tuning (§4.3.5)


class CheckpointError(LsrError):
    """A checkpoint is missing, unreadable or would hold non-finite weights."""


def checkpoint_name(step: int) -> str:
    return f"step_{step:09d}.pt"


def capture_rng_state() -> dict[str, Any]:
    """Every RNG a training step can draw from."""
    state: dict[str, Any] = {
        "torch": torch.get_rng_state(),
        "numpy": np.random.get_state(),
        "python": random.getstate(),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def restore_rng_state(state: Mapping[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def nonfinite_entries(state_dict: Mapping[str, Any]) -> list[str]:
    """Names of floating tensors with NaN/inf in a (possibly nested) state dict."""
    bad: list[str] = []

    def visit(prefix: str, value: Any) -> None:
        if isinstance(value, torch.Tensor):
            if value.is_floating_point() and not bool(torch.isfinite(value).all()):
                bad.append(prefix)
        elif isinstance(value, Mapping):
            for key, item in value.items():
                visit(f"{prefix}.{key}" if prefix else str(key), item)
        elif isinstance(value, (list, tuple)):
            for i, item in enumerate(value):
                visit(f"{prefix}[{i}]", item)

    visit("", state_dict)
    return bad


def atomic_torch_save(obj: Any, path: Path) -> None:
    """``torch.save`` to a temp file in the same folder, fsync, then ``os.replace``: never a partial file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as handle:
            torch.save(obj, handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def list_checkpoints(folder: Path) -> list[Path]:
    """Complete checkpoints in ``folder``, oldest first (temp files never match the pattern)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := CHECKPOINT_PATTERN.match(p.name))]
    return [p for _, p in sorted(found)]


def latest_checkpoint(folder: Path) -> Path | None:
    paths = list_checkpoints(folder)
    return paths[-1] if paths else None


def save_checkpoint(state: dict[str, Any], folder: Path, step: int, keep_last: int = 3) -> Path:
    """Write ``state`` as ``folder/step_NNNNNNNNN.pt`` atomically and prune to the newest ``keep_last``.

    Refuses (CheckpointError) when the network or EMA weights hold NaN/inf, so the newest
    checkpoint on disk is always a good one to fall back to.
    """
    weights = {key: state[key] for key in ("nets", "ema") if key in state}
    bad = nonfinite_entries(weights)
    if bad:
        raise CheckpointError(f"refusing to save a checkpoint with non-finite weights ({', '.join(bad[:5])})")
    path = Path(folder) / checkpoint_name(step)
    atomic_torch_save(state, path)
    for old in list_checkpoints(folder)[:-keep_last] if keep_last > 0 else []:
        old.unlink(missing_ok=True)
    return path


def load_checkpoint(path: Path) -> dict[str, Any]:
    """Load a checkpoint written by :func:`save_checkpoint` onto the CPU."""
    path = Path(path)
    if path.is_dir():
        found = latest_checkpoint(path)
        if found is None:
            raise CheckpointError(f"no checkpoint (step_*.pt) in {path}; start without --resume or point at a file")
        path = found
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}; start without --resume or point at a step_*.pt file")
    try:
        # Our own files hold numpy/python RNG states, which are not tensor-only.
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # a truncated or foreign file
        raise CheckpointError(f"could not read checkpoint {path}: {exc}; delete it to resume from the one before") from exc
