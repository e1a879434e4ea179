"""K-shot episode datasets: item contract, determinism, DataLoader workers, consistent augmentation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from lsr.data.augment import AugmentConfig, augment_frames, sample_affine, warp_frames, warp_landmarks, warp_segmentation
from lsr.data.episodes import SEGMENTATION_IGNORE_INDEX, CrossIdentityDataset, EpisodeDataset
from lsr.errors import ConfigError, DatasetError

SIZE = 64


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory) -> Path:
    from lsr.data.synth import generate_dataset

    root = tmp_path_factory.mktemp("episodes")
    generate_dataset(root, identities=3, videos_per_identity=2, frames=5, size=SIZE, seed=0, test_fraction=0.0, progress=False)
    # One frame without landmarks: it must never be chosen.
    landmarks_path = root / "id00000" / "vid000" / "landmarks.npy"
    landmarks = np.load(landmarks_path)
    landmarks[0] = np.nan
    np.save(landmarks_path, landmarks)
    return root


def _check_item(item: dict[str, torch.Tensor], shots: int, size: int) -> None:
    assert item["shots"].shape == (shots, 3, size, size) and item["shots"].dtype == torch.float32
    assert item["shot_landmark_images"].shape == (shots, 3, size, size)
    assert item["target"].shape == (3, size, size)
    assert item["target_landmark_image"].shape == (3, size, size)
    assert item["target_landmarks"].shape == (68, 2) and item["target_landmarks"].dtype == torch.float32
    assert item["shot_landmarks"].shape == (shots, 68, 2)
    assert item["target_segmentation"].shape == (size, size) and item["target_segmentation"].dtype == torch.int64
    assert item["identity"].dtype == torch.int64 and item["identity"].ndim == 0
    for key in ("shots", "target", "shot_landmark_images", "target_landmark_image"):
        assert item[key].min() >= -1.0 and item[key].max() <= 1.0, key
    assert item["target_landmark_image"].max() > 0.0  # something drawn
    assert torch.isfinite(item["target_landmarks"]).all() and torch.isfinite(item["shot_landmarks"]).all()
    segmentation = item["target_segmentation"]
    assert ((segmentation >= 0) & (segmentation < 19) | (segmentation == SEGMENTATION_IGNORE_INDEX)).all()


@pytest.mark.parametrize("shots", [1, 8])
def test_item_contract(dataset_root: Path, shots: int):
    dataset = EpisodeDataset(dataset_root, split="train", shots=shots, seed=1)
    assert len(dataset) == 3 * 2 * 5 - 1  # the NaN frame is not a target
    _check_item(dataset[0], shots, SIZE)
    _check_item(dataset[len(dataset) - 1], shots, SIZE)


def test_nan_frames_never_chosen_and_target_not_a_shot(dataset_root: Path):
    dataset = EpisodeDataset(dataset_root, shots=4, shots_from="video", seed=2, episodes=40)
    nan_clip = next(i for i, c in enumerate(dataset.index.clips) if c.identity == "id00000" and c.video == "vid000")
    assert all(not (ref.clip == nan_clip and ref.frame == 0) for refs in dataset._pools.values() for ref in refs)
    for index in range(0, 40, 7):
        item = dataset[index]
        assert torch.isfinite(item["shot_landmarks"]).all()
        assert not any(torch.equal(item["target"], shot) for shot in item["shots"])


def test_video_apart_draws_the_shots_from_the_other_half_of_the_clip(dataset_root: Path):
    dataset = EpisodeDataset(dataset_root, shots=2, shots_from="video_apart", seed=3, episodes=20)
    for target in dataset.targets:
        pool = dataset._shot_pool(target)
        frames = [ref.frame for ref in dataset._pools[dataset._pool_key(target)]]
        middle = (min(frames) + max(frames)) / 2.0
        assert pool and all(ref.clip == target.clip and (ref.frame < middle) != (target.frame < middle) for ref in pool)
    _check_item(dataset[0], 2, SIZE)
    with pytest.raises(ConfigError, match="video_apart"):
        EpisodeDataset(dataset_root, shots_from="neighbours")


def test_resize_and_augmentation_keep_contract(dataset_root: Path):
    dataset = EpisodeDataset(dataset_root, shots=2, size=48, augment=AugmentConfig(), seed=0)
    _check_item(dataset[3], 2, 48)


def test_deterministic_per_seed(dataset_root: Path):
    first = EpisodeDataset(dataset_root, shots=3, seed=7, augment=AugmentConfig())
    second = EpisodeDataset(dataset_root, shots=3, seed=7, augment=AugmentConfig())
    other = EpisodeDataset(dataset_root, shots=3, seed=8, augment=AugmentConfig())
    a, b = first[4], second[4]
    assert all(torch.equal(a[key], b[key]) for key in a)
    # Order of access does not matter.
    first[9]
    assert torch.equal(first[4]["target"], a["target"])
    assert any(not torch.equal(a["shots"], other[i]["shots"]) for i in range(3))
    first.set_epoch(1)
    assert not torch.equal(first[4]["shots"], a["shots"]) or not torch.equal(first[4]["target"], a["target"])


def test_dataloader_two_workers_matches_single_process(dataset_root: Path):
    """Workers from a fork server: forked from this test process, whose other threads (onnxruntime's, the iris net's,
    torch's) may hold a lock at the fork, a worker once hung for good on it."""
    dataset = EpisodeDataset(dataset_root, shots=2, seed=3, episodes=6, augment=AugmentConfig())
    loader = DataLoader(dataset, batch_size=3, num_workers=2, shuffle=False, multiprocessing_context="forkserver")
    batches = list(loader)
    assert batches[0]["shots"].shape == (3, 2, 3, SIZE, SIZE)
    assert batches[1]["target_segmentation"].shape == (3, SIZE, SIZE)
    direct = dataset[4]
    assert torch.equal(batches[1]["target"][1], direct["target"])
    assert torch.equal(batches[1]["shots"][1], direct["shots"])


def test_cross_identity_pairs(dataset_root: Path):
    dataset = CrossIdentityDataset(dataset_root, split="train", shots=2, seed=0)
    for index in range(6):
        item = dataset[index]
        assert item["source_identity"] != item["driver_identity"]
        assert item["shots"].shape == (2, 3, SIZE, SIZE) and item["driver"].shape == (3, SIZE, SIZE)
        assert item["driver_landmark_image"].shape == (3, SIZE, SIZE) and item["driver_landmarks"].shape == (68, 2)


def test_bad_arguments(dataset_root: Path, tmp_path: Path):
    with pytest.raises(ConfigError, match="1..32"):
        EpisodeDataset(dataset_root, shots=0)
    with pytest.raises(ConfigError, match="1..32"):
        EpisodeDataset(dataset_root, shots=33)
    with pytest.raises(DatasetError, match="manifest"):
        EpisodeDataset(tmp_path)
    with pytest.raises(ConfigError):
        EpisodeDataset(dataset_root, augment=AugmentConfig(max_scale=-1.0))


class TestAugmentation:
    def test_landmark_lands_on_the_warped_dot(self):
        size = 64
        generator = torch.Generator().manual_seed(0)
        config = AugmentConfig(max_rotation_deg=20.0, max_scale=0.2, max_shift=0.1)
        landmarks = torch.full((1, 68, 2), 32.0)
        landmarks[0, 30] = torch.tensor([40.0, 22.0])
        image = torch.zeros(1, 3, size, size)
        image[0, :, 22, 40] = 1.0  # bright dot at landmark 30 (x=40, y=22)
        for _ in range(5):
            matrices = sample_affine(generator, 1, size, config)
            warped = warp_frames(image, matrices)
            moved = warp_landmarks(landmarks, matrices)[0, 30]
            peak = torch.nonzero(warped[0, 0] == warped[0, 0].max())[0]  # (y, x)
            assert abs(float(moved[0]) - float(peak[1])) <= 1.0 and abs(float(moved[1]) - float(peak[0])) <= 1.0

    def test_segmentation_moves_with_the_frame_and_stays_integer(self):
        generator = torch.Generator().manual_seed(1)
        matrices = sample_affine(generator, 2, 32, AugmentConfig(max_rotation_deg=10.0, max_shift=0.1))
        segmentation = torch.zeros(2, 32, 32, dtype=torch.int64)
        segmentation[:, 10:20, 12:22] = 10
        frames = (segmentation == 10).to(torch.float32).unsqueeze(1).repeat(1, 3, 1, 1)
        warped_seg = warp_segmentation(segmentation, matrices)
        warped_frames = warp_frames(frames, matrices)
        assert warped_seg.dtype == torch.int64 and set(warped_seg.unique().tolist()) <= {0, 10}
        agree = (warped_seg == 10) == (warped_frames[:, 0] > 0.5)
        assert agree.float().mean() > 0.97  # only boundary pixels may differ (nearest vs bilinear)

    def test_augment_frames_keeps_ranges(self):
        generator = torch.Generator().manual_seed(2)
        images = torch.rand(3, 3, 16, 16)
        out, points, seg = augment_frames(images, torch.rand(3, 68, 2) * 16, None, generator, AugmentConfig())
        assert out.shape == images.shape and points.shape == (3, 68, 2) and seg is None
        assert out.min() >= 0.0 and out.max() <= 1.0
        with pytest.raises(ValueError):
            augment_frames(images, torch.rand(2, 68, 2), None, generator, AugmentConfig())


def test_warp_references_are_the_nearest_shots_warped_onto_the_target(dataset_root: Path):
    from landmarks.warp.tps import warp_references

    dataset = EpisodeDataset(dataset_root, split=None, shots=4, seed=3, warp_references=2)
    item = dataset[5]
    assert item["references"].shape == (2, 3, SIZE, SIZE) and item["reference_masks"].shape == (2, 1, SIZE, SIZE)
    assert item["references"].min() >= -1 and item["references"].max() <= 1
    frames = ((item["shots"].permute(0, 2, 3, 1) + 1) * 127.5).round().to(torch.uint8).numpy()
    expected, masks, _ = warp_references(frames, item["shot_landmarks"].numpy(), item["target_landmarks"].numpy(), 2)
    np.testing.assert_array_equal(((item["references"].permute(0, 2, 3, 1) + 1) * 127.5).round().numpy(), expected)
    np.testing.assert_array_equal(item["reference_masks"][:, 0].numpy(), masks)
    # a warp of a shot of the same identity is closer to the target than the raw shot, on average
    target = item["target"]
    raw_error = (item["shots"] - target).abs().mean(dim=(1, 2, 3)).min()
    assert (item["references"][0] - target).abs().mean() < raw_error + 0.05


def test_expression_episodes_open_the_mouth_beyond_every_shot(dataset_root: Path):
    from landmarks.shape.expression import mouth_opening

    dataset = EpisodeDataset(dataset_root, shots=2, shots_from="identity", seed=4, episodes=12, expression_episodes=1.0)
    plain = EpisodeDataset(dataset_root, shots=2, shots_from="identity", seed=4, episodes=12)
    for index in range(12):
        item = dataset[index]
        target = mouth_opening(item["target_landmarks"].numpy())
        shots = mouth_opening(item["shot_landmarks"].numpy())
        assert (shots < target).all(), (index, target, shots)  # no shot shows the target's mouth
    # Off (the default), episodes are drawn exactly as before the option existed.
    assert torch.equal(plain[3]["target"], EpisodeDataset(dataset_root, shots=2, shots_from="identity", seed=4,
                                                          episodes=12, expression_episodes=0.0)[3]["target"])
    with pytest.raises(ConfigError, match="expression_episodes"):
        EpisodeDataset(dataset_root, expression_episodes=1.5)
