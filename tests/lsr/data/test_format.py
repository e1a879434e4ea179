"""The on-disk dataset format: round trips, manifest, and readers failing with clear DatasetErrors."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from lsr.data import format as fmt
from lsr.errors import DatasetError

SIZE = 16


def _clip_arrays(rng: np.random.Generator, frames: int = 3):
    images = rng.integers(0, 256, (frames, SIZE, SIZE, 3), dtype=np.uint8)
    segs = rng.integers(0, 19, (frames, SIZE, SIZE), dtype=np.uint8)
    landmarks = rng.uniform(0, SIZE, (frames, 68, 2)).astype(np.float32)
    landmarks[1] = np.nan  # a missing frame
    pose = rng.uniform(-30, 30, (frames, 3)).astype(np.float32)
    pose[1] = np.nan
    return images, segs, landmarks, pose


def _write(root: Path, rng: np.random.Generator, identity: str = "idA", video: str = "v0", with_seg: bool = True) -> Path:
    images, segs, landmarks, pose = _clip_arrays(rng)
    meta = {"origin": "synthetic", "fps": 25.0, "generator": {"seed": 1}}
    return fmt.write_clip(root / identity / video, images, landmarks, pose, meta, segs if with_seg else None)


def test_round_trip(tmp_path: Path, rng: np.random.Generator) -> None:
    images, segs, landmarks, pose = _clip_arrays(rng)
    meta = {"origin": "video", "fps": 30.0, "crop_transforms": [[[1, 0, 0], [0, 1, 0]], None, None]}
    clip_dir = fmt.write_clip(tmp_path / "p1" / "clipA", iter(images), landmarks, pose, meta, iter(segs))
    assert not list(tmp_path.glob("p1/*.tmp-*")), "temp folder left behind"
    reader = fmt.ClipReader(clip_dir)
    assert reader.num_frames == len(reader) == 3 and reader.size == SIZE
    assert reader.identity == "p1" and reader.video == "clipA" and reader.missing_frames == [1]
    np.testing.assert_array_equal(reader.frame(2), images[2])
    np.testing.assert_array_equal(reader.segmentation(-1), segs[2])
    np.testing.assert_array_equal(reader.landmarks, landmarks)  # NaN rows compare equal
    np.testing.assert_array_equal(reader.pose, pose)
    assert reader.meta["crop_transforms"][0] == [[1, 0, 0], [0, 1, 0]]
    loaded = fmt.read_clip(clip_dir)
    np.testing.assert_array_equal(loaded["frames"], images)
    np.testing.assert_array_equal(loaded["segmentation"], segs)
    with pytest.raises(IndexError):
        reader.frame(3)


def test_clip_without_segmentation(tmp_path: Path, rng: np.random.Generator) -> None:
    reader = fmt.ClipReader(_write(tmp_path, rng, with_seg=False))
    assert not reader.has_segmentation
    with pytest.raises(DatasetError, match="no segmentation"):
        reader.segmentation(0)
    assert fmt.read_clip(reader.clip_dir)["segmentation"] is None


def test_manifest_and_list_clips(tmp_path: Path, rng: np.random.Generator) -> None:
    for identity, video in (("a", "v0"), ("a", "v1"), ("b", "v0"), ("c", "v0")):
        _write(tmp_path, rng, identity, video)
    fmt.write_manifest(tmp_path, {"train": ["a", "b"], "test": ["c"]})
    manifest = fmt.read_manifest(tmp_path)
    assert manifest["counts"]["train"] == {"identities": 2, "clips": 3, "frames": 9}
    assert manifest["counts"]["test"] == {"identities": 1, "clips": 1, "frames": 3}
    assert [p.relative_to(tmp_path).as_posix() for p in fmt.list_clips(tmp_path, "train")] == ["a/v0", "a/v1", "b/v0"]
    assert len(fmt.list_clips(tmp_path)) == 4
    with pytest.raises(DatasetError, match="split 'val' not in"):
        fmt.list_clips(tmp_path, "val")
    with pytest.raises(DatasetError, match="splits are by identity"):
        fmt.write_manifest(tmp_path, {"train": ["a"], "test": ["a"]})
    with pytest.raises(DatasetError, match="lsr synth"):
        fmt.read_manifest(tmp_path / "nowhere")


def test_write_refuses_bad_input_and_leaves_nothing(tmp_path: Path, rng: np.random.Generator) -> None:
    images, segs, landmarks, pose = _clip_arrays(rng)
    meta = {"origin": "synthetic", "fps": 25.0}
    bad = segs.copy()
    bad[2, 0, 0] = 19
    with pytest.raises(DatasetError, match="class id 19"):
        fmt.write_clip(tmp_path / "x" / "v", images, landmarks, pose, meta, bad)
    with pytest.raises(DatasetError, match="3 frames but 2 landmark rows"):
        fmt.write_clip(tmp_path / "x" / "v", images, landmarks[:2], pose[:2], meta)
    with pytest.raises(DatasetError, match="origin"):
        fmt.write_clip(tmp_path / "x" / "v", images, landmarks, pose, {"fps": 1.0})
    assert list((tmp_path / "x").iterdir()) == [], "a failed write must leave no folder"
    _write(tmp_path, rng, "x", "v")
    with pytest.raises(DatasetError, match="already exists"):
        _write(tmp_path, rng, "x", "v")


@pytest.mark.parametrize(
    ("corrupt", "message"),
    [
        (lambda d: (d / "landmarks.npy").unlink(), r"landmarks\.npy is missing"),
        (lambda d: np.save(d / "landmarks.npy", np.zeros((3, 5, 2), np.float32)), r"shape \(3, 5, 2\), expected \(3, 68, 2\)"),
        (lambda d: np.save(d / "pose.npy", np.zeros((3, 3), np.float64)), "dtype float64, expected float32"),
        (lambda d: (d / "frames" / "00001.png").unlink(), "2 PNG files but meta.json says num_frames = 3"),
        (lambda d: (d / "meta.json").unlink(), r"meta\.json is missing"),
        (lambda d: (d / "meta.json").write_text("{"), "not valid JSON"),
        (
            lambda d: (d / "meta.json").write_text(json.dumps({**json.loads((d / "meta.json").read_text()), "format_version": 99})),
            "format_version 99",
        ),
    ],
)
def test_reader_errors_on_open(tmp_path: Path, rng: np.random.Generator, corrupt, message: str) -> None:
    clip_dir = _write(tmp_path, rng)
    corrupt(clip_dir)
    with pytest.raises(DatasetError, match=message):
        fmt.ClipReader(clip_dir)


def test_reader_errors_on_bad_maps(tmp_path: Path, rng: np.random.Generator) -> None:
    clip_dir = _write(tmp_path, rng)
    cv2.imwrite(str(clip_dir / "segmentation" / "00002.png"), np.full((SIZE, SIZE), 25, np.uint8))
    cv2.imwrite(str(clip_dir / "frames" / "00001.png"), np.zeros((SIZE + 1, SIZE, 3), np.uint8))
    reader = fmt.ClipReader(clip_dir)
    with pytest.raises(DatasetError, match="class id 25 >= 19"):
        reader.segmentation(2)
    with pytest.raises(DatasetError, match="expected"):
        reader.frame(1)
    with pytest.raises(DatasetError, match="does not exist"):
        fmt.ClipReader(tmp_path / "missing")
