"""Fixtures for training tests: a tiny in-memory episode dataset and tiny train configs."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from lsr.config import LossConfig, OptimConfig, StagesConfig, TrainConfig


class DrawnEpisodes(torch.utils.data.Dataset):
    """Procedural K-shot episodes with exact segmentation: a face disk with a moving mouth per identity.

    Items follow ``lsr.train.steps.Batch`` keys; item i is a pure function of (seed, i).
    """

    def __init__(self, identities: int = 2, episodes: int = 8, size: int = 64, k: int = 2, seed: int = 0) -> None:
        self.identities, self.episodes, self.size, self.k, self.seed = identities, episodes, size, k, seed
        palette = np.random.default_rng(seed + 1000)
        self.skin = palette.uniform(60, 230, (identities, 3))
        self.background = palette.uniform(0, 255, (identities, 3))

    def __len__(self) -> int:
        return self.episodes

    def _frame(self, identity: int, dx: float, dy: float, mouth: float):
        s = self.size
        image = np.empty((s, s, 3), np.uint8)
        image[:] = self.background[identity]
        seg = np.zeros((s, s), np.uint8)
        landmarks = np.zeros((s, s, 3), np.uint8)
        centre = (int(s / 2 + dx * s), int(s / 2 + dy * s))
        radius = int(0.3 * s)
        cv2.circle(image, centre, radius, tuple(float(c) for c in self.skin[identity]), -1)
        cv2.circle(seg, centre, radius, 1, -1)
        cv2.circle(landmarks, centre, radius, (255, 255, 255), 1)
        mouth_box = (centre[0] - radius // 2, centre[1] + radius // 3, centre[0] + radius // 2, int(centre[1] + radius // 3 + 2 + mouth * radius / 2))
        cv2.rectangle(image, mouth_box[:2], mouth_box[2:], (40, 0, 0), -1)
        cv2.rectangle(seg, mouth_box[:2], mouth_box[2:], 11, -1)
        cv2.rectangle(landmarks, mouth_box[:2], mouth_box[2:], (255, 0, 0), 1)
        to_tensor = lambda a: torch.from_numpy(a).permute(2, 0, 1).float() / 127.5 - 1  # noqa: E731
        return to_tensor(image), to_tensor(landmarks), torch.from_numpy(seg.astype(np.int64))

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        rng = np.random.default_rng([self.seed, index])
        identity = index % self.identities
        frames = [self._frame(identity, *rng.uniform(-0.08, 0.08, 2), rng.uniform(0, 1)) for _ in range(self.k + 1)]
        shots = torch.stack([f[0] for f in frames[: self.k]])
        shot_landmarks = torch.stack([f[1] for f in frames[: self.k]])
        target, target_landmarks, seg = frames[-1]
        return {
            "shots": shots,
            "shot_landmark_images": shot_landmarks,
            "target": target,
            "target_landmark_image": target_landmarks,
            "target_segmentation": seg,
        }


def tiny_train_config(out: Path, **changes) -> TrainConfig:
    stages = changes.pop("stages", StagesConfig(pretrain_epochs=1, full_epochs=1, latent_epochs=1, steps_per_epoch=2))
    cfg = TrainConfig(
        data=(),
        synthetic_identities=1,
        out=out,
        preset="tiny",
        k=2,
        batch_size=2,
        workers=0,
        stages=stages,
        losses=changes.pop("losses", LossConfig(r1_every=2)),
        optim=changes.pop("optim", OptimConfig(lr=2e-3)),
        device="cpu",
        threads=1,
        checkpoint_every=100,
        log_every=1,
        image_every=2,
        progress=False,
    )
    return dataclasses.replace(cfg, **changes)


@pytest.fixture
def drawn_episodes() -> DrawnEpisodes:
    return DrawnEpisodes()
