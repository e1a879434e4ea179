"""The training loop: stages and freezing, overfitting, exact resume, NaN guard, exported weights."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from lsr.config import LossConfig, StagesConfig
from lsr.train import checkpoint as ckpt
from lsr.train.guard import TrainingDivergedError
from lsr.train.steps import Batch, StagePlan, stages_for_variant
from lsr.train.trainer import Trainer
from models_def import LSRModel

from .conftest import DrawnEpisodes, tiny_train_config

pytestmark = pytest.mark.slow


def _snapshot(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {name: p.detach().clone() for name, p in module.named_parameters()}


def _changed(before: dict[str, torch.Tensor], module: torch.nn.Module, prefix: str) -> bool:
    return any(not torch.equal(before[n], p) for n, p in module.named_parameters() if n.startswith(prefix))


def test_variants_run_the_documented_stages():
    assert [(p.stage, p.cross_entropy) for p in stages_for_variant("latent_layout")] == [(1, True), (2, True), (3, False)]
    assert all(p.cross_entropy for p in stages_for_variant("learned_seg"))
    for variant in ("baseline", "spade_landmarks", "oracle_seg"):
        assert [(p.stage, p.cross_entropy) for p in stages_for_variant(variant)] == [(2, False), (3, False)]


def test_each_stage_trains_the_right_parameters(tmp_path):
    trainer = Trainer(tiny_train_config(tmp_path), DrawnEpisodes())
    batches = trainer.batches_from(0)
    expectations = {
        # stage -> (prefixes that must change, prefixes that must not)
        1: (["subject_encoder.encoder.layout_head", "frame_generator.layout_predictor"],
            ["subject_encoder.encoder.style_head", "frame_generator.image_generator",
             "frame_generator.layout_predictor.to_aux_rgb" + "__never"]),
        2: (["subject_encoder.encoder.style_head", "frame_generator.image_generator", "frame_generator.layout_predictor.up_blocks"],
            ["frame_generator.layout_predictor.to_aux_rgb"]),
        3: (["frame_generator.image_generator", "frame_generator.layout_predictor.up_blocks"],
            ["frame_generator.layout_predictor.to_aux_rgb"]),
    }
    for stage, start in ((1, 0), (2, 2), (3, 4)):
        trainer.step = start
        assert trainer.plan_at(start).stage == stage
        model_before, disc_before = _snapshot(trainer.model), _snapshot(trainer.discriminator)
        finite, scalars, _ = trainer.train_step(next(batches))
        assert finite and all(math.isfinite(v) for v in scalars.values()), scalars
        must_change, must_not = expectations[stage]
        for prefix in must_change:
            assert _changed(model_before, trainer.model, prefix), (stage, prefix)
        for prefix in must_not:
            assert not _changed(model_before, trainer.model, prefix), (stage, prefix)
        assert _changed(disc_before, trainer.discriminator, "") == (stage != 1)
        assert ("cross_entropy" in scalars) == (stage in (1, 2))
    trainer.close()


@pytest.mark.parametrize("variant", ["baseline", "spade_landmarks", "oracle_seg", "learned_seg"])
def test_ablation_variants_train_with_finite_losses(tmp_path, variant):
    stages = StagesConfig(pretrain_epochs=1, full_epochs=0.5, latent_epochs=0.5, steps_per_epoch=2)
    trainer = Trainer(tiny_train_config(tmp_path, variant=variant, stages=stages), DrawnEpisodes(), keep_history=True)
    summary = trainer.run()
    trainer.close()
    assert summary["skipped_steps"] == 0
    assert all(math.isfinite(v) for row in trainer.history for v in row.values())
    assert any("cross_entropy" in row for row in trainer.history) == (variant == "learned_seg")
    assert len(trainer.history) == (4 if variant == "learned_seg" else 2)


def test_full_run_writes_checkpoints_weights_and_tensorboard(tmp_path):
    trainer = Trainer(tiny_train_config(tmp_path), DrawnEpisodes())
    summary = trainer.run()
    trainer.close()
    assert summary["steps"] == 6
    assert [p.name for p in ckpt.list_checkpoints(tmp_path / "checkpoints")][-1] == "step_000000006.pt"
    exported = LSRModel.from_pretrained(tmp_path / "weights")
    for name, tensor in exported.state_dict().items():
        assert torch.equal(tensor, trainer.ema.module.state_dict()[name])
    events = list((tmp_path / "tensorboard").glob("events.out.tfevents.*"))
    assert events
    from lsr.train.visualize import read_tensorboard_scalars

    scalars = read_tensorboard_scalars(tmp_path / "tensorboard")
    assert {"loss/l1", "loss/cross_entropy", "train/lr", "train/skipped_steps", "grad/g_grad_norm"} <= set(scalars)


def test_stop_at_step_exports_the_weights_of_that_step(tmp_path):
    from lsr.train.trainer import run_train

    cfg = dataclasses.replace(tiny_train_config(tmp_path), stop_at_step=3)
    cfg.validate()
    summary = run_train(cfg)
    assert summary["steps"] == 3 and (tmp_path / "weights" / "model.safetensors").is_file()


def test_tiny_model_overfits_one_identity(tmp_path):
    dataset = DrawnEpisodes(identities=1, episodes=4, k=2)
    stages = StagesConfig(pretrain_epochs=0, full_epochs=0, latent_epochs=40, steps_per_epoch=1)
    losses = LossConfig(ssim=0.0, adversarial=0.0, feature_matching=0.0, r1_every=4)
    cfg = tiny_train_config(tmp_path, stages=stages, losses=losses, image_every=0, batch_size=4)
    trainer = Trainer(cfg, dataset)
    fixed = Batch.from_dict(torch.utils.data.default_collate([dataset[i] for i in range(4)]), trainer.device)

    def l1_on_fixed_batch() -> float:
        with torch.no_grad():
            out = trainer.model(fixed.shots, fixed.shot_landmark_images, fixed.target_landmark_image)
        return (out.frame.image - fixed.target).abs().mean().item()

    initial = l1_on_fixed_batch()
    trainer.run()
    trainer.close()
    final = l1_on_fixed_batch()
    assert final < 0.6 * initial, (initial, final)


def test_resume_continues_exactly(tmp_path):
    stages = StagesConfig(pretrain_epochs=1, full_epochs=1, latent_epochs=1, steps_per_epoch=2)
    straight = Trainer(tiny_train_config(tmp_path / "straight", stages=stages, image_every=0), DrawnEpisodes())
    straight.run()
    straight.close()

    first = Trainer(tiny_train_config(tmp_path / "resumed", stages=stages, image_every=0, checkpoint_every=3), DrawnEpisodes())
    first.run(until_step=3)  # stop mid-stage 2 (after step 3's checkpoint), as if killed
    first.close()
    resumed_cfg = tiny_train_config(tmp_path / "resumed", stages=stages, image_every=0, resume=True)
    second = Trainer(resumed_cfg, DrawnEpisodes())
    assert second.run()["steps"] == 6
    second.close()

    for name, tensor in straight.model.state_dict().items():
        torch.testing.assert_close(second.model.state_dict()[name], tensor, rtol=1e-5, atol=1e-6, msg=name)
    for name, tensor in straight.discriminator.state_dict().items():
        torch.testing.assert_close(second.discriminator.state_dict()[name], tensor, rtol=1e-5, atol=1e-6, msg=name)
    for name, tensor in straight.ema.state_dict().items():
        torch.testing.assert_close(second.ema.state_dict()[name], tensor, rtol=1e-5, atol=1e-6, msg=name)
    assert second.d_steps == straight.d_steps


def test_nan_loss_is_skipped_and_counted(tmp_path):
    calls = {"n": 0}

    def poison_second_step(total: torch.Tensor) -> torch.Tensor:
        calls["n"] += 1
        return total * float("nan") if calls["n"] == 2 else total

    trainer = Trainer(tiny_train_config(tmp_path), DrawnEpisodes(), loss_hook=poison_second_step, keep_history=True)
    batches = trainer.batches_from(0)
    trainer.train_step(next(batches))
    before = _snapshot(trainer.model)
    finite, _, _ = trainer.train_step(next(batches))
    assert not finite
    assert trainer.guard.record(finite) is False and trainer.guard.skipped_total == 1
    assert not _changed(before, trainer.model, "")  # no optimiser update on the poisoned step
    assert all(torch.isfinite(p).all() for p in trainer.model.parameters())
    trainer.close()


def test_repeated_nan_restores_then_stops_with_a_clear_error(tmp_path):
    def always_nan(total: torch.Tensor) -> torch.Tensor:
        return total * float("nan")

    cfg = tiny_train_config(tmp_path, max_consecutive_nonfinite=2, max_recoveries=1, image_every=0)
    trainer = Trainer(cfg, DrawnEpisodes(), loss_hook=always_nan)
    with pytest.raises(TrainingDivergedError, match="diverged"):
        trainer.run()
    assert trainer.guard.recoveries == 1 and trainer.guard.skipped_total == 4
    assert trainer.lr_scale == 0.5  # halved by the one restore
    assert ckpt.load_checkpoint(tmp_path / "checkpoints")["step"] == 0
    assert all(torch.isfinite(p).all() for p in trainer.model.parameters())
    trainer.close()


def test_existing_checkpoints_need_resume(tmp_path):
    from lsr.errors import ConfigError

    trainer = Trainer(tiny_train_config(tmp_path, stages=StagesConfig(1, 0, 0, steps_per_epoch=1)), DrawnEpisodes())
    trainer.run()
    trainer.close()
    again = Trainer(tiny_train_config(tmp_path, stages=StagesConfig(1, 0, 0, steps_per_epoch=1)), DrawnEpisodes())
    with pytest.raises(ConfigError, match="--resume"):
        again.run()
    again.close()


@pytest.mark.parametrize("shots_from", ["video", "identity"])
def test_shots_from_picks_the_episode_pool(tmp_path, shots_from):
    """--shots-from video keeps an episode's shots in its target's video (FSTH episodes, the eval protocol)."""
    from lsr.data.synth import generate_dataset
    from lsr.train.data_source import episode_dataset
    from lsr.train.trainer import model_config_for

    root = tmp_path / "data"
    generate_dataset(root, identities=2, videos_per_identity=2, frames=4, size=64, seed=0, test_fraction=0.0, progress=False)
    cfg = tiny_train_config(tmp_path / "run", data=(root,), synthetic_identities=0, shots_from=shots_from)
    dataset = episode_dataset(cfg, model_config_for(cfg))
    assert dataset.shots_from == shots_from
    pool_sizes = {len(pool) for pool in dataset._pools.values()}
    assert pool_sizes == ({4} if shots_from == "video" else {8})


def test_several_data_roots_are_mixed(tmp_path):
    """--data A B: episodes of both prepared datasets in one index space (e.g. aligned and loosely framed crops)."""
    import tyro

    from lsr.config import TrainConfig
    from lsr.data.synth import generate_dataset
    from lsr.errors import ConfigError
    from lsr.train.data_source import MixedEpisodes, episode_dataset
    from lsr.train.trainer import model_config_for

    roots = [tmp_path / "a", tmp_path / "b"]
    for seed, (root, identities) in enumerate(zip(roots, (1, 2))):
        generate_dataset(root, identities=identities, videos_per_identity=1, frames=4, size=64, seed=seed,
                         test_fraction=0.0, progress=False)
    parsed = tyro.cli(TrainConfig, args=["--data", str(roots[0]), str(roots[1])])
    assert parsed.data == tuple(roots)
    cfg = tiny_train_config(tmp_path / "run", data=parsed.data, synthetic_identities=0)
    dataset = episode_dataset(cfg, model_config_for(cfg))
    assert isinstance(dataset, MixedEpisodes)
    alone = [len(episode_dataset(dataclasses.replace(cfg, data=(root,)), model_config_for(cfg))) for root in roots]
    assert len(dataset) == sum(alone) and alone[1] > alone[0] > 0
    with pytest.raises(ConfigError, match="is not a folder"):
        dataclasses.replace(cfg, data=(roots[0], tmp_path / "missing")).validate()


def test_expression_episodes_and_the_mouth_term_train_the_warp_guided_model(tmp_path):
    """--expression-episodes and --losses.mouth reach the dataset and the loss, and the losses stay finite."""
    stages = StagesConfig(pretrain_epochs=0, full_epochs=0, latent_epochs=1, steps_per_epoch=2)
    cfg = tiny_train_config(tmp_path, variant="warp_guided", stages=stages, expression_episodes=0.5,
                            losses=LossConfig(r1_every=2, mouth=2.0))
    trainer = Trainer(cfg, keep_history=True)
    assert trainer.dataset.expression_episodes == 0.5
    summary = trainer.run()
    trainer.close()
    assert summary["skipped_steps"] == 0
    assert all("mouth" in row and math.isfinite(row["mouth"]) for row in trainer.history)
    with pytest.raises(Exception, match="expression-episodes"):
        dataclasses.replace(cfg, expression_episodes=-0.1).validate()
