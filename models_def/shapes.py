"""Shape contracts checked at public entry points (``check_shape``), with messages that say what was expected."""

from __future__ import annotations

from collections.abc import Sequence

import torch


def check_shape(name: str, tensor: torch.Tensor, expected: Sequence[int | str]) -> dict[str, int]:
    """Check ``tensor.shape`` against ``expected``: ints must match, equal letters must bind to equal sizes.

    Returns the letter bindings, e.g. ``{"B": 2, "K": 4}``. Raises ValueError (a caller error) on mismatch.
    """
    if not isinstance(tensor, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor of shape {_spec(expected)}; got {type(tensor).__name__}")
    shape = tuple(tensor.shape)
    if len(shape) != len(expected):
        raise ValueError(f"{name} must have shape {_spec(expected)} ({len(expected)} dims); got {shape}")
    bound: dict[str, int] = {}
    for axis, (size, want) in enumerate(zip(shape, expected)):
        if isinstance(want, str):
            want = bound.setdefault(want, int(size))
        if int(size) != int(want):
            raise ValueError(f"{name} must have shape {_spec(expected)}; got {shape} (axis {axis} is {size}, want {want})")
    if not tensor.is_floating_point():
        raise ValueError(f"{name} must be a floating-point tensor; got {tensor.dtype}")
    return bound


def _spec(expected: Sequence[int | str]) -> str:
    return "(" + ", ".join(str(size) for size in expected) + ")"
