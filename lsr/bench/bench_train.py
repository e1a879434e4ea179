"""``lsr bench train``: training steps/s per preset and stage on this machine (a markdown table).

Times the real generator + discriminator steps of ``lsr.train.steps`` on random episode tensors
(data loading excluded), median over the timed steps after one warm-up step.
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from typing import TYPE_CHECKING

import torch

from lsr.train.optim import make_adam
from lsr.train.steps import Batch, LossWeights, StagePlan, discriminator_step, generator_step, set_stage_trainable
from models_def import Discriminator, LSRModel, preset_config

if TYPE_CHECKING:
    from lsr.config import BenchTrainConfig


def random_batch(batch: int, k: int, size: int, generator: torch.Generator, device: torch.device) -> Batch:
    def unit(*shape: int) -> torch.Tensor:
        return (torch.rand(*shape, generator=generator) * 2 - 1).to(device)

    return Batch(
        shots=unit(batch, k, 3, size, size),
        shot_landmark_images=unit(batch, k, 3, size, size),
        target=unit(batch, 3, size, size),
        target_landmark_image=unit(batch, 3, size, size),
        target_segmentation=torch.randint(0, 19, (batch, size, size), generator=generator).to(device),
    )


def time_steps(preset: str, stage: int, resolution: int, batch_size: int, k: int, steps: int, device: torch.device) -> float:
    """Median seconds per training step (G step, plus D step from stage 2 on)."""
    torch.manual_seed(0)
    config = preset_config(preset, resolution=resolution)
    model, discriminator = LSRModel(config).to(device), Discriminator(config).to(device)
    plan = StagePlan(stage, cross_entropy=stage != 3)
    set_stage_trainable(model, discriminator, plan)
    g_opt = make_adam(model.parameters(), 1e-3, (0.0, 0.999))
    d_opt = make_adam(discriminator.parameters(), 1e-3, (0.0, 0.999))
    weights = LossWeights()
    batch = random_batch(batch_size, k, resolution, torch.Generator().manual_seed(0), device)
    durations = []
    for index in range(steps + 1):
        if device.type == "cuda":
            torch.cuda.synchronize()
        started = time.perf_counter()
        result = generator_step(model, discriminator, g_opt, batch, plan, weights)
        if plan.full_pipeline:
            discriminator_step(discriminator, d_opt, batch.target, result.fake, weights, index)
        if device.type == "cuda":
            torch.cuda.synchronize()
        if index > 0:  # the first step pays for allocation and lazy initialisation
            durations.append(time.perf_counter() - started)
    return statistics.median(durations)


def run_bench_train(cfg: BenchTrainConfig) -> None:
    from lsr.devices import resolve_device

    device = resolve_device(cfg.device)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs, "
          f"torch {torch.__version__}, {torch.get_num_threads()} threads, device {device}")
    print(f"batch {cfg.batch_size} episodes, K = {cfg.k}, {cfg.resolution}x{cfg.resolution}, fp32, "
          f"median of {cfg.steps} steps after 1 warm-up\n")
    print("| preset | stage | s/step | steps/s | episodes/s |")
    print("|---|---|---|---|---|")
    for preset in cfg.presets:
        for stage in (1, 3):
            seconds = time_steps(preset, stage, cfg.resolution, cfg.batch_size, cfg.k, cfg.steps, device)
            name = "1 layout pretrain" if stage == 1 else "2-3 full (G+D)"
            print(f"| {preset} | {name} | {seconds:.3f} | {1 / seconds:.2f} | {cfg.batch_size / seconds:.2f} |", flush=True)
