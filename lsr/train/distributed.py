"""Data-parallel helpers: process-group setup from torchrun's environment, gradient averaging, sharding.

Why gradients are all-reduced by hand instead of wrapping modules in ``DistributedDataParallel``:
the set of trainable modules changes per stage (§4.3.2-4.3.4), the lazy R1 penalty needs a double
backward through D (which DDP's reducer does not support), and several modules take part in one
loss. Averaging the gradients of every trainable parameter over ranks after ``backward`` is exactly
what DDP computes (all losses are batch means, so the mean of per-rank gradients with per-rank batch
B / N equals the gradient on the global batch B) without those restrictions. InstanceNorm everywhere
means there are no batch statistics to synchronise.
"""

from __future__ import annotations

import dataclasses
import datetime
import os
from collections.abc import Iterable, Iterator

import numpy as np
import torch
import torch.distributed as dist

from lsr.errors import ConfigError


@dataclasses.dataclass(frozen=True)
class DistContext:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1


def init_from_env(device_type: str) -> DistContext:
    """Join the process group torchrun describes (RANK, WORLD_SIZE, ...); a no-op for a single process.

    Backend: nccl on GPU, gloo on CPU.
    """
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    if world_size <= 1:
        return DistContext()
    if not dist.is_initialized():
        backend = "nccl" if device_type == "cuda" else "gloo"
        dist.init_process_group(backend=backend, timeout=datetime.timedelta(minutes=30))
    return DistContext(dist.get_rank(), dist.get_world_size(), int(os.environ.get("LOCAL_RANK", "0")))


def current_context() -> DistContext:
    if dist.is_available() and dist.is_initialized():
        return DistContext(dist.get_rank(), dist.get_world_size(), int(os.environ.get("LOCAL_RANK", "0")))
    return DistContext()


def average_gradients(parameters: Iterable[torch.nn.Parameter], context: DistContext) -> None:
    """All-reduce (mean) the gradients of ``parameters`` over ranks in one flat buffer.

    Parameters without a gradient on this rank contribute zeros, so every rank calls the collective
    with the same buffer size (the trainable set is the same on every rank).
    """
    if not context.enabled:
        return
    params = [p for p in parameters if p.requires_grad]
    if not params:
        return
    grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in params]
    flat = torch.cat([g.reshape(-1) for g in grads])
    dist.all_reduce(flat, op=dist.ReduceOp.SUM)
    flat /= context.world_size
    offset = 0
    for param in params:
        count = param.numel()
        param.grad = flat[offset : offset + count].view_as(param).clone()
        offset += count


def all_true(flag: bool, context: DistContext, device: torch.device) -> bool:
    """True only when ``flag`` holds on every rank (keeps the NaN guard's skip decision in lockstep)."""
    if not context.enabled:
        return flag
    value = torch.tensor([1.0 if flag else 0.0], device=device)
    dist.all_reduce(value, op=dist.ReduceOp.MIN)
    return bool(value.item() > 0.5)


def mean_over_ranks(values: dict[str, float], context: DistContext, device: torch.device) -> dict[str, float]:
    """Average logged scalars over ranks (same keys on every rank)."""
    if not context.enabled or not values:
        return values
    keys = sorted(values)
    tensor = torch.tensor([values[k] for k in keys], dtype=torch.float64, device=device)
    dist.all_reduce(tensor, op=dist.ReduceOp.SUM)
    tensor /= context.world_size
    return dict(zip(keys, tensor.tolist(), strict=True))


class ShardedBatchSampler(torch.utils.data.Sampler[list[int]]):
    """Deterministic global batches, each split into contiguous per-rank slices; resumable mid-epoch.

    Epoch ``e`` shuffles ``range(num_items)`` with ``seed + e``. Global batch ``b`` is
    ``perm[b*G : (b+1)*G]`` (G = global batch); rank ``r`` takes its ``G / world`` slice. So one process
    with batch G sees exactly the items N processes see together. The epoch is endless in the sense
    that the permutation is re-drawn per epoch; ``start_batch`` skips already-consumed batches on resume.
    """

    def __init__(
        self,
        num_items: int,
        global_batch: int,
        context: DistContext,
        seed: int,
        epoch: int = 0,
        start_batch: int = 0,
    ) -> None:
        if global_batch % context.world_size:
            raise ConfigError(
                f"--batch-size {global_batch} must be divisible by the number of processes {context.world_size}"
            )
        if num_items < global_batch:
            raise ConfigError(f"the dataset has {num_items} episodes, fewer than --batch-size {global_batch}")
        self.num_items, self.global_batch, self.context = num_items, global_batch, context
        self.seed, self.epoch, self.start_batch = seed, epoch, start_batch
        self.local_batch = global_batch // context.world_size

    def batches_per_epoch(self) -> int:
        return self.num_items // self.global_batch  # the ragged tail is dropped: every step sees a full batch

    def __len__(self) -> int:
        return self.batches_per_epoch() - self.start_batch

    def __iter__(self) -> Iterator[list[int]]:
        order = np.random.default_rng(self.seed + self.epoch).permutation(self.num_items)
        lo = self.context.rank * self.local_batch
        for batch in range(self.start_batch, self.batches_per_epoch()):
            start = batch * self.global_batch
            yield order[start + lo : start + lo + self.local_batch].tolist()
