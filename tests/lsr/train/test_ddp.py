"""Data parallelism: a 2-process gloo step equals the 1-process step on the same global batch."""

from __future__ import annotations

import os
import sys

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from lsr.train.distributed import DistContext
from lsr.train.steps import Batch, LossWeights, StagePlan, discriminator_step, generator_step, set_stage_trainable
from models_def import Discriminator, LSRModel, preset_config

from .conftest import DrawnEpisodes

pytestmark = pytest.mark.slow

GLOBAL_BATCH = 4


def _one_step(rank: int, world: int) -> dict[str, torch.Tensor]:
    """Build identical nets, take one G and one D step (stage 2, with R1) on this rank's slice."""
    torch.manual_seed(0)
    # mbstd over groups of 1: D then sees each sample alone, so the per-rank batch split changes nothing.
    config = preset_config("tiny", mbstd_group_size=1)
    model, discriminator = LSRModel(config), Discriminator(config)
    plan = StagePlan(2, cross_entropy=True)
    set_stage_trainable(model, discriminator, plan)
    # SGD: the update is the averaged gradient itself (Adam's first step is ~lr * sign(grad), which turns
    # float-rounding noise on near-zero gradients into lr-sized differences).
    g_opt = torch.optim.SGD(model.parameters(), lr=0.1)
    d_opt = torch.optim.SGD(discriminator.parameters(), lr=0.1)
    dataset = DrawnEpisodes(episodes=GLOBAL_BATCH)
    per_rank = GLOBAL_BATCH // world
    items = [dataset[i] for i in range(rank * per_rank, (rank + 1) * per_rank)]
    batch = Batch.from_dict(torch.utils.data.default_collate(items), torch.device("cpu"))
    context = DistContext(rank, world)
    weights = LossWeights(r1_every=1)
    result = generator_step(model, discriminator, g_opt, batch, plan, weights, context=context)
    d_result = discriminator_step(discriminator, d_opt, batch.target, result.fake, weights, 0, context=context)
    assert result.finite and d_result.finite
    return {**{f"g.{k}": v.clone() for k, v in model.state_dict().items()},
            **{f"d.{k}": v.clone() for k, v in discriminator.state_dict().items()}}


def _worker(rank: int, world: int, store_path: str, out_path: str) -> None:
    torch.set_num_threads(1)
    store = dist.FileStore(store_path, world)
    dist.init_process_group("gloo", store=store, rank=rank, world_size=world)
    try:
        state = _one_step(rank, world)
        if rank == 0:
            torch.save(state, out_path)
        dist.barrier()  # no rank tears gloo down while the other is still inside a collective
    finally:
        dist.destroy_process_group()
    # Leave without the interpreter's teardown: gloo's threads, destroyed during it, sometimes abort
    # ("terminate called without an active exception", SIGABRT; seen once in CI) after the work is done.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def test_two_process_gloo_step_matches_one_process(tmp_path):
    torch.set_num_threads(1)
    single = _one_step(0, 1)
    out_path = str(tmp_path / "ddp_state.pt")
    mp.start_processes(_worker, args=(2, str(tmp_path / "store"), out_path), nprocs=2, join=True, start_method="spawn")
    parallel = torch.load(out_path, weights_only=True)
    torch.manual_seed(0)
    initial = LSRModel(preset_config("tiny", mbstd_group_size=1)).state_dict()
    assert set(parallel) == set(single)
    for name, tensor in single.items():
        torch.testing.assert_close(parallel[name], tensor, rtol=1e-4, atol=1e-6, msg=name)
    moved = [n for n, t in initial.items() if not torch.equal(single[f"g.{n}"], t)]
    assert len(moved) > len(initial) // 2  # the step really updated the generator
