"""``lsr train``: the three-stage training loop (thesis §4.3.2-4.3.4, §4.6) with exact resume and DDP.

The loop is a fixed sequence of global steps; the stage, the learning rate and the data position are
all functions of the step, so a checkpoint holding (step, nets, EMA, optimisers, RNG states) resumes
exactly. Multi-process: ``torchrun --nproc_per_node=N -m lsr.cli train ...`` (see docs/TRAINING.md).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from lsr.devices import resolve_device
from lsr.train import checkpoint as ckpt
from lsr.train.distributed import DistContext, ShardedBatchSampler, init_from_env, mean_over_ranks
from lsr.train.guard import NonFiniteGuard
from lsr.train.optim import EMA, lr_factor, make_adam, set_lr
from lsr.train.steps import (
    Batch,
    StagePlan,
    StepResult,
    discriminator_step,
    generator_step,
    set_stage_trainable,
    stages_for_variant,
)
from models_def import Discriminator, LSRModel, ModelConfig, preset_config

if TYPE_CHECKING:
    from lsr.config import TrainConfig


def model_config_for(cfg: TrainConfig) -> ModelConfig:
    """The ModelConfig a TrainConfig asks for (preset + variant + optional resolution)."""
    overrides: dict[str, Any] = {"variant": cfg.variant}
    if cfg.resolution:
        overrides["resolution"] = cfg.resolution
    if cfg.warp_references:
        overrides["warp_references"] = cfg.warp_references
    if cfg.reference_flow:
        overrides["reference_flow"] = cfg.reference_flow
    if cfg.reference_detail:
        overrides["reference_detail"] = cfg.reference_detail
    if cfg.crop_scale:
        overrides["crop_scale"] = cfg.crop_scale
    return preset_config(cfg.preset, **overrides)


def config_to_dict(cfg) -> dict[str, Any]:
    """A plain, picklable dict of a (nested) dataclass config; paths become strings."""

    def plain(value: Any) -> Any:
        if isinstance(value, Path):
            return str(value)
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [plain(v) for v in value]
        return value

    return plain(dataclasses.asdict(cfg))


@dataclasses.dataclass
class StageSpan:
    plan: StagePlan
    start: int
    end: int
    """Steps [start, end) of the global step counter."""


class Trainer:
    """Builds nets, optimisers, EMA and data for a ``TrainConfig`` and runs the stages.

    ``dataset`` (optional) is any map-style dataset of episode dicts (see ``steps.Batch``); by default
    it is built from ``cfg.data`` or a synthetic dataset. ``loss_hook`` is passed to the generator
    step (tests inject NaNs with it). ``keep_history`` keeps every step's scalars in ``self.history``.
    """

    def __init__(
        self,
        cfg,
        dataset: torch.utils.data.Dataset | None = None,
        *,
        context: DistContext | None = None,
        loss_hook: Callable[[Tensor], Tensor] | None = None,
        keep_history: bool = False,
    ) -> None:
        self.cfg = cfg
        self.device = resolve_device(cfg.device)
        self.context = context if context is not None else init_from_env(self.device.type)
        if self.device.type == "cpu":  # share the cores between the processes of one machine
            torch.set_num_threads(cfg.threads or max(1, (os.cpu_count() or 1) // self.context.world_size))
        elif self.context.enabled:
            self.device = torch.device("cuda", self.context.local_rank)
            torch.cuda.set_device(self.device)
        self.bf16 = cfg.precision == "bf16" and self.device.type == "cuda"
        self.model_config = model_config_for(cfg)
        self.out = Path(cfg.out)
        self.checkpoint_dir = self.out / "checkpoints"
        self.loss_weights = cfg.losses
        self.loss_hook, self.keep_history = loss_hook, keep_history
        self.history: list[dict[str, float]] = []

        # Identical initial weights on every rank: same seed, built on the CPU before moving.
        torch.manual_seed(cfg.seed)
        self.model = LSRModel(self.model_config)
        self.discriminator = Discriminator(self.model_config)
        if cfg.init_from is not None:
            from lsr.train.warm_start import warm_start

            warm_start(self.model, self.discriminator, cfg.init_from)
        self.model.to(self.device).train()
        self.discriminator.to(self.device).train()
        self.ema = EMA(self.model, cfg.optim.ema_decay)
        betas = (cfg.optim.beta1, cfg.optim.beta2)
        self.g_optimizer = make_adam(self.model.parameters(), cfg.optim.lr, betas)
        self.d_optimizer = make_adam(self.discriminator.parameters(), cfg.optim.lr, betas)
        self.perceptual = None
        if cfg.losses.vgg_weights is not None:
            from lsr.train.perceptual import VGGPerceptualLoss

            self.perceptual = VGGPerceptualLoss(cfg.losses.vgg_weights).to(self.device)

        self.dataset = dataset if dataset is not None else build_dataset(cfg, self.model_config)
        probe = ShardedBatchSampler(len(self.dataset), cfg.batch_size, self.context, cfg.seed)
        self.batches_per_epoch = probe.batches_per_epoch()
        self.steps_per_epoch = cfg.stages.steps_per_epoch or self.batches_per_epoch
        self.spans = self._stage_spans()
        self.total_steps = self.spans[-1].end if self.spans else 0
        self.decay_steps = cfg.stages.lr_decay_steps or self.steps_per_epoch

        self.step = 0
        self.d_steps = 0
        self.lr_scale = 1.0
        self.guard = NonFiniteGuard(cfg.max_consecutive_nonfinite, cfg.max_recoveries)
        self.writer = None
        self._current_plan: StagePlan | None = None

    # ---- schedule ----------------------------------------------------------------------------------------
    def _stage_spans(self) -> list[StageSpan]:
        epochs = {1: self.cfg.stages.pretrain_epochs, 2: self.cfg.stages.full_epochs, 3: self.cfg.stages.latent_epochs}
        spans, start = [], 0
        for plan in stages_for_variant(self.model_config.variant):
            steps = int(round(epochs[plan.stage] * self.steps_per_epoch))
            if steps > 0:
                spans.append(StageSpan(plan, start, start + steps))
                start += steps
        return spans

    def plan_at(self, step: int) -> StagePlan:
        for span in self.spans:
            if span.start <= step < span.end:
                return span.plan
        return self.spans[-1].plan

    def lr_at(self, step: int) -> float:
        """Thesis §4.6: constant lr, then a linear decay by x1/100 over the final window; x lr_scale after recoveries."""
        return self.cfg.optim.lr * self.lr_scale * lr_factor(step, self.total_steps, self.decay_steps)

    # ---- data ----------------------------------------------------------------------------------------------
    def batches_from(self, step: int) -> Iterator[Batch]:
        """Endless batches starting at global ``step``: epoch and in-epoch position follow from the step."""
        epoch, index = divmod(step, self.batches_per_epoch)
        while True:
            sampler = ShardedBatchSampler(
                len(self.dataset), self.cfg.batch_size, self.context, self.cfg.seed, epoch=epoch, start_batch=index
            )
            if hasattr(self.dataset, "set_epoch"):
                self.dataset.set_epoch(epoch)
            loader = torch.utils.data.DataLoader(
                self.dataset,
                batch_sampler=sampler,
                num_workers=self.cfg.workers,
                pin_memory=self.device.type == "cuda",
            )
            for raw in loader:
                yield Batch.from_dict(raw, self.device)
            epoch, index = epoch + 1, 0

    # ---- checkpoints ------------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        epoch, batch = divmod(self.step, self.batches_per_epoch)
        return {
            "nets": {"model": self.model.state_dict(), "discriminator": self.discriminator.state_dict()},
            "ema": self.ema.state_dict(),
            "optimizers": {"generator": self.g_optimizer.state_dict(), "discriminator": self.d_optimizer.state_dict()},
            "grad_scaler": None,  # fp32 and bf16 need no loss scaling
            "step": self.step,
            "stage": self.plan_at(self.step).stage if self.spans else 0,
            "d_steps": self.d_steps,
            "lr_scale": self.lr_scale,
            "data_position": {"epoch": epoch, "batch": batch, "batches_per_epoch": self.batches_per_epoch},
            "guard": self.guard.state_dict(),
            "rng": ckpt.capture_rng_state(),
            "config": config_to_dict(self.cfg),
            "model_config": self.model_config.to_dict(),
        }

    def load_state_dict(self, state: dict[str, Any], restore_guard: bool = True) -> None:
        if state["model_config"] != self.model_config.to_dict():
            raise ckpt.CheckpointError(
                "the checkpoint was trained with a different model config (preset/variant/resolution); "
                "resume with the same flags or start a new --out folder"
            )
        if state["data_position"]["batches_per_epoch"] != self.batches_per_epoch:
            raise ckpt.CheckpointError(
                "the dataset size or --batch-size changed since the checkpoint; resume with the same data and batch size"
            )
        self.model.load_state_dict(state["nets"]["model"])
        self.discriminator.load_state_dict(state["nets"]["discriminator"])
        self.ema.load_state_dict(state["ema"])
        self.g_optimizer.load_state_dict(state["optimizers"]["generator"])
        self.d_optimizer.load_state_dict(state["optimizers"]["discriminator"])
        self.step, self.d_steps, self.lr_scale = int(state["step"]), int(state["d_steps"]), float(state["lr_scale"])
        if restore_guard:
            self.guard.load_state_dict(state["guard"])
        ckpt.restore_rng_state(state["rng"])
        self._current_plan = None

    def save(self) -> None:
        """Rank 0 writes the checkpoint; every rank waits so that a recovery can read it."""
        if self.context.is_main:
            ckpt.save_checkpoint(self.state_dict(), self.checkpoint_dir, self.step, self.cfg.keep_checkpoints)
        self._barrier()

    def export_weights(self, folder: Path | None = None) -> Path:
        """EMA generators (E, G^l, G^s) as safetensors + config.json for inference; never non-finite."""
        folder = Path(folder) if folder is not None else self.out / "weights"
        bad = ckpt.nonfinite_entries(self.ema.state_dict())
        if bad:
            raise ckpt.CheckpointError(f"not exporting: EMA weights are non-finite ({', '.join(bad[:5])})")
        if self.context.is_main:
            from safetensors.torch import save_file

            from landmarks.io.image_files import atomic_output

            self.ema.module.save_pretrained(folder)
            # D beside the generators so that `lsr finetune` can fine-tune it too (§4.3.5).
            d_state = {k: v.detach().contiguous().cpu() for k, v in self.discriminator.state_dict().items()}
            with atomic_output(folder / ckpt.DISCRIMINATOR_NAME) as temp:
                save_file(d_state, str(temp))
        return folder

    def _barrier(self) -> None:
        if self.context.enabled:
            torch.distributed.barrier()

    def _recover(self) -> None:
        """Restore the newest good checkpoint and halve the lr (NaN guard policy, see guard.py)."""
        self.guard.start_recovery(self.step)  # raises TrainingDivergedError when the budget is spent
        halved = self.lr_scale / 2
        state = ckpt.load_checkpoint(self.checkpoint_dir)
        self.load_state_dict(state, restore_guard=False)
        self.lr_scale = halved
        self._log_text(f"non-finite steps: restored step {self.step}, lr scale now {halved:g}")

    # ---- logging ------------------------------------------------------------------------------------------
    def _open_writer(self) -> None:
        if self.context.is_main and self.writer is None:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(self.out / "tensorboard"))

    def _log_text(self, text: str) -> None:
        if self.writer is not None:
            self.writer.add_text("events", text, self.step)

    def _log_scalars(self, scalars: dict[str, float], plan: StagePlan) -> None:
        if self.writer is None:
            return
        for name, value in scalars.items():
            if math.isfinite(value):
                self.writer.add_scalar(f"loss/{name}" if "norm" not in name else f"grad/{name}", value, self.step)
        self.writer.add_scalar("train/lr", self.lr_at(self.step - 1), self.step)
        self.writer.add_scalar("train/stage", plan.stage, self.step)
        self.writer.add_scalar("train/skipped_steps", self.guard.skipped_total, self.step)

    def _log_images(self, batch: Batch, result: StepResult, plan: StagePlan) -> None:
        if self.writer is None or result.fake is None:
            return
        from lsr.train.visualize import image_grid, layout_argmax_rgb, layout_pca_rgb

        def as_rgb(x: Tensor) -> Tensor:
            return x[:, :3] if x.shape[1] >= 3 else x.mean(1, keepdim=True).expand(-1, 3, -1, -1)

        rows = [batch.shots[:, 0], as_rgb(batch.target_landmark_image)]
        if result.layout is not None:
            rows.append(layout_pca_rgb(result.layout))
            if plan.cross_entropy and result.layout.shape[1] == 19:
                rows.append(layout_argmax_rgb(result.layout).to(result.layout.device))
        rows += [result.fake.clamp(-1, 1), batch.target]
        grid = image_grid([r.detach().float().cpu() for r in rows])
        self.writer.add_image(f"preview/{plan.name}", grid, self.step, dataformats="HWC")

    # ---- the loop -----------------------------------------------------------------------------------------
    def train_step(self, batch: Batch) -> tuple[bool, dict[str, float], StepResult]:
        plan = self.plan_at(self.step)
        if plan != self._current_plan:
            set_stage_trainable(self.model, self.discriminator, plan)
            self._current_plan = plan
        lr = self.lr_at(self.step)
        set_lr(self.g_optimizer, lr)
        set_lr(self.d_optimizer, lr)
        result = generator_step(
            self.model, self.discriminator, self.g_optimizer, batch, plan, self.loss_weights,
            context=self.context, perceptual=self.perceptual, bf16=self.bf16, loss_hook=self.loss_hook,
        )
        scalars = dict(result.scalars)
        finite = result.finite
        if finite:
            self.ema.update(self.model, self.step)
            if plan.full_pipeline and result.fake is not None:
                d_result = discriminator_step(
                    self.discriminator, self.d_optimizer, batch.target, result.fake, self.loss_weights, self.d_steps,
                    context=self.context, bf16=self.bf16,
                )
                self.d_steps += 1
                scalars.update(d_result.scalars)
                finite = d_result.finite
        self.step += 1
        return finite, scalars, result

    def run(self, until_step: int | None = None) -> dict[str, Any]:
        """Train to the end of the last stage (or stop early after ``until_step``); returns a summary dict.

        Stopping early does not change the schedule (stages, lr decay): a later ``--resume`` continues
        as if the run had never stopped.
        """
        if not self.spans:
            from lsr.errors import ConfigError

            raise ConfigError("every stage has a budget of 0 steps; raise --stages.*-epochs")
        if self.cfg.resume:
            self.load_state_dict(ckpt.load_checkpoint(self.checkpoint_dir))
        elif ckpt.latest_checkpoint(self.checkpoint_dir) is not None:
            from lsr.errors import ConfigError

            raise ConfigError(f"{self.checkpoint_dir} already holds checkpoints: pass --resume or use a new --out")
        else:
            self.save()  # step 0: a good checkpoint always exists for the NaN guard to fall back to
        self._open_writer()
        progress = None
        if self.cfg.progress and self.context.is_main:
            from tqdm import tqdm

            progress = tqdm(total=self.total_steps, initial=self.step, desc="train", unit="step", dynamic_ncols=True)
        stage_ends = {span.end for span in self.spans}
        batches = self.batches_from(self.step)
        last_scalars: dict[str, float] = {}
        try:
            stop = self.total_steps if until_step is None else min(until_step, self.total_steps)
            while self.step < stop:
                plan = self.plan_at(self.step)
                batch = next(batches)
                finite, scalars, result = self.train_step(batch)
                if self.keep_history:
                    self.history.append({"step": float(self.step), "finite": float(finite), **scalars})
                if self.guard.record(finite):
                    self._recover()
                    batches = self.batches_from(self.step)
                    if progress is not None:
                        progress.n = self.step
                        progress.refresh()
                    continue
                last_scalars = scalars
                if self.step % self.cfg.log_every == 0 or self.step == self.total_steps:
                    self._log_scalars(mean_over_ranks(scalars, self.context, self.device), plan)
                if self.cfg.image_every and self.step % self.cfg.image_every == 0:
                    self._log_images(batch, result, plan)
                if self.step % self.cfg.checkpoint_every == 0 or self.step in stage_ends:
                    self.save()
                if self.step in stage_ends:
                    self.export_weights()
                if progress is not None:
                    progress.update(1)
                    progress.set_postfix(stage=plan.name, g=f"{scalars.get('g_total', float('nan')):.3f}")
        finally:
            if progress is not None:
                progress.close()
            if self.writer is not None:
                self.writer.flush()
        weights = self.export_weights()
        return {
            "steps": self.step,
            "skipped_steps": self.guard.skipped_total,
            "recoveries": self.guard.recoveries,
            "weights": str(weights),
            "last_scalars": last_scalars,
        }

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None


def build_dataset(cfg: TrainConfig, model_config: ModelConfig) -> torch.utils.data.Dataset:
    """The episode dataset for a TrainConfig: ``cfg.data`` or a synthetic dataset generated under OUT/synthetic_data."""
    from lsr.train.data_source import episode_dataset

    return episode_dataset(cfg, model_config)


def run_train(cfg: TrainConfig) -> dict[str, Any]:
    """Entry point of ``lsr train`` (and of each torchrun process)."""
    trainer = Trainer(cfg)
    try:
        summary = trainer.run(until_step=cfg.stop_at_step or None)
    finally:
        trainer.close()
    if trainer.context.is_main:
        print(
            f"trained {summary['steps']} steps ({summary['skipped_steps']} skipped, {summary['recoveries']} restores); "
            f"inference weights: {summary['weights']}; checkpoints: {trainer.checkpoint_dir}; "
            f"tensorboard --logdir {trainer.out / 'tensorboard'}"
        )
    return summary
