"""Where ``lsr train`` gets its episodes: a prepared dataset (``--data``), a procedural one, or both mixed.

The procedural dataset (``--synthetic-identities N``) is rendered once by ``lsr.data.synth`` into
``OUT/synthetic_data`` with exact segmentation maps, so every variant (including X-ent supervision and
``oracle_seg``) can train without real data. Given both, episodes come from both (``MixedEpisodes``): real
clips close the domain gap, synthetic heads keep exact ground truth.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import torch

from lsr.errors import DatasetError
from models_def import ModelConfig

if TYPE_CHECKING:
    from lsr.config import TrainConfig

SYNTHETIC_VIDEOS_PER_IDENTITY = 2
SYNTHETIC_FRAMES_PER_VIDEO = 16
SEGMENTATION_VARIANTS = ("latent_layout", "learned_seg", "oracle_seg", "warp_guided")


class MixedEpisodes(torch.utils.data.ConcatDataset):
    """Episodes of several ``EpisodeDataset``s in one index space; ``set_epoch`` reaches each of them."""

    def set_epoch(self, epoch: int) -> None:
        for dataset in self.datasets:
            dataset.set_epoch(epoch)


def synthetic_root(cfg: TrainConfig, model_config: ModelConfig) -> Path:
    """Render the procedural dataset on rank 0 once (other ranks wait); returns its root."""
    from lsr.data.format import MANIFEST_NAME

    root = Path(cfg.out) / "synthetic_data"
    is_main = not (torch.distributed.is_available() and torch.distributed.is_initialized()) or torch.distributed.get_rank() == 0
    if is_main and not (root / MANIFEST_NAME).is_file():
        from lsr.data.synth.generate import generate_dataset

        generate_dataset(
            root,
            identities=cfg.synthetic_identities,
            videos_per_identity=SYNTHETIC_VIDEOS_PER_IDENTITY,
            frames=SYNTHETIC_FRAMES_PER_VIDEO,
            size=model_config.resolution,
            seed=cfg.seed,
            test_fraction=0.0,
            progress=cfg.progress,
            overwrite=True,
        )
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        torch.distributed.barrier()
    return root


def episode_dataset(cfg: TrainConfig, model_config: ModelConfig) -> torch.utils.data.Dataset:
    """``EpisodeDataset`` over each ``cfg.data`` root (split 'train') and/or the synthetic dataset, at the model's
    resolution; several are mixed in proportion to their episodes."""
    from lsr.data.episodes import EpisodeDataset

    roots = [Path(root) for root in cfg.data]
    if cfg.synthetic_identities > 0:
        roots.append(synthetic_root(cfg, model_config))
    needs_segmentation = model_config.variant in SEGMENTATION_VARIANTS
    datasets = []
    for root in roots:
        dataset = EpisodeDataset(
            root,
            split="train",
            shots=cfg.k,
            size=model_config.resolution,
            seed=cfg.seed,
            shots_from=cfg.shots_from,
            with_segmentation=needs_segmentation,
            warp_references=model_config.warp_references if model_config.uses_references else 0,
            expression_episodes=cfg.expression_episodes,
        )
        if needs_segmentation:
            probe = dataset[0]
            if "target_segmentation" not in probe or bool((probe["target_segmentation"] < 0).all()):
                raise DatasetError(
                    f"variant {model_config.variant!r} needs segmentation maps but {root} has none; add oracle maps "
                    "(lsr.data.oracle_seg / `lsr prepare`) or train --variant baseline / spade_landmarks"
                )
        datasets.append(dataset)
    return datasets[0] if len(datasets) == 1 else MixedEpisodes(datasets)
