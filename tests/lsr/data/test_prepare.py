"""``lsr prepare``: layouts, real clips into valid datasets, resume, and bad inputs."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from lsr.cli import main
from lsr.data.format import ClipReader, list_clips, read_manifest
from lsr.data.oracle_seg import read_official_segmap
from lsr.data.prepare import PrepareOptions, discover_sources, prepare_dataset, sample_indices
from lsr.errors import DatasetError


def _check_dataset(root: Path, size: int) -> list[ClipReader]:
    readers = [ClipReader(path) for path in list_clips(root)]
    assert readers
    for reader in readers:
        assert reader.size == size and reader.has_segmentation
        assert reader.frame(0).shape == (size, size, 3)
        seg = reader.segmentation(0)
        assert seg.max() < 19 and len(np.unique(seg)) >= 5  # a parsed face, not one class
        finite = np.isfinite(reader.landmarks).all(axis=(1, 2))
        assert finite.any()
        inside = reader.landmarks[finite]
        assert (inside > -0.1 * size).all() and (inside < 1.1 * size).all()
        assert len(reader.meta["crop_transforms"]) == reader.num_frames
    return readers


def test_sample_indices():
    assert sample_indices(100, 5).tolist() == [0, 25, 50, 74, 99]
    assert sample_indices(3, 10).tolist() == [0, 1, 2]
    assert sample_indices(7, 0).tolist() == list(range(7))


def test_discover_layouts(tmp_path: Path):
    for name in ("vox/id001/vidA/00001.mp4", "vox/id001/vidA/00002.mp4", "people/anna/talk.mp4", "single.mp4",
                 "release/test/id9/vidZ/combined/00000_rgb.png", "release/test/id9/vidZ/combined/00000_contour.png",
                 "photos/bob/set1/a.jpg"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(b"x")
    found = {(s.identity, s.video, s.kind, s.source_split) for s in discover_sources(tmp_path)}
    assert ("id001", "vidA_00001", "video", None) in found and ("id001", "vidA_00002", "video", None) in found
    assert ("people", "anna_talk", "video", None) in found  # names are relative to the input root
    assert [(s.identity, s.video) for s in discover_sources(tmp_path / "people")] == [("anna", "talk")]
    assert ("id9", "vidZ_test", "lsr_release", "test") in found
    assert ("bob", "set1", "images", None) in found
    assert len(found) == 6
    assert [s.identity for s in discover_sources(tmp_path / "single.mp4")] == ["single"]
    with pytest.raises(DatasetError, match="does not exist"):
        discover_sources(tmp_path / "nope")


@pytest.mark.slow
def test_lsr_release_one_identity_and_resume(shared_data: Path, tmp_path: Path):
    source = shared_data / "fsth_eval_sample" / "train" / "id00017"
    if not source.is_dir():
        pytest.skip(f"{source} absent")
    out = tmp_path / "fsth"
    summary = prepare_dataset(source, out, PrepareOptions(size=128, frames_per_clip=4), progress=False)
    assert summary.count("done") == 1 and summary.frames >= 3
    (reader,) = _check_dataset(out, 128)
    assert reader.meta["source_split"] == "train" and reader.video.endswith("_train")
    assert reader.meta["generator"]["framing_used"] == "keep"
    assert read_manifest(out)["splits"]["test"] == ["id00017"]  # evaluation identities
    again = prepare_dataset(source, out, PrepareOptions(size=128, frames_per_clip=4), progress=False)
    assert again.count("skipped") == 1 and again.count("done") == 0


@pytest.mark.slow
def test_lsr_release_uses_official_segmaps(shared_data: Path, tmp_path: Path):
    source = shared_data / "fsth_eval_sample_processed" / "train" / "id00017"
    if not source.is_dir():
        pytest.skip(f"{source} absent")
    prepare_dataset(source, tmp_path, PrepareOptions(size=224, frames_per_clip=2), progress=False)
    (reader,) = _check_dataset(tmp_path, 224)
    assert reader.meta["generator"]["segmentation"] == "official"
    first = reader.meta["source_frame_indices"][0]
    official = read_official_segmap(next(source.rglob(f"{first:05d}_segmap_merged.png")))
    assert (reader.segmentation(0) == official).mean() > 0.99


@pytest.mark.slow
@pytest.mark.parametrize("framing", ["keep", "align"])
def test_voxceleb2_clip(shared_data: Path, tmp_path: Path, framing: str):
    if framing == "align":
        pytest.importorskip("landmarks.align")
    source = shared_data / "clips" / "voxceleb2_sample" / "id00017"
    if not source.is_dir():
        pytest.skip(f"{source} absent")
    summary = prepare_dataset(source, tmp_path, PrepareOptions(size=128, frames_per_clip=3, framing=framing), progress=False)
    assert summary.count("done") == 1, summary.table()
    (reader,) = _check_dataset(tmp_path, 128)
    assert reader.identity == "id00017" and reader.meta["origin"] == "video"
    assert len(reader.meta["source_frame_indices"]) == reader.num_frames


def _bad_inputs(root: Path) -> None:
    (root / "empty").mkdir(parents=True)
    (root / "empty" / "zero.mp4").write_bytes(b"")
    (root / "garbage").mkdir()
    (root / "garbage" / "noise.mp4").write_bytes(np.random.default_rng(0).integers(0, 255, 4096, dtype=np.uint8).tobytes())
    import cv2

    faceless = root / "nobody" / "shots"
    faceless.mkdir(parents=True)
    for index in range(2):
        cv2.imwrite(str(faceless / f"{index}.png"), np.full((96, 96, 3), 40 + 60 * index, np.uint8))


def test_every_clip_failing_is_a_clear_error(tmp_path: Path, capsys):
    _bad_inputs(tmp_path / "in")
    with pytest.raises(DatasetError, match="all 3 clip"):
        prepare_dataset(tmp_path / "in", tmp_path / "out", PrepareOptions(size=64, frames_per_clip=2), workers=2, progress=False)
    assert main(["prepare", str(tmp_path / "in"), "--out", str(tmp_path / "out2"), "--resolution", "64", "--workers", "1"]) == 2
    assert "all 3 clip(s) failed" in capsys.readouterr().err
    assert main(["prepare", str(tmp_path / "in"), "--out", str(tmp_path / "out4"), "--resolution", "64", "--workers", "1",
                 "--no-progress"]) == 2  # the same clear error, without the bar (lsr eval's and lsr train's flag)
    assert "prepare:" not in (said := capsys.readouterr()).err and "all 3 clip(s) failed" in said.err
    assert main(["prepare", str(tmp_path / "missing"), "--out", str(tmp_path / "out3")]) == 2


@pytest.mark.slow
def test_bad_clips_are_skipped_and_reported(shared_data: Path, tmp_path: Path):
    pytest.importorskip("landmarks.align")  # image folders are aligned by default
    frames = sorted((shared_data / "fsth_eval_sample" / "train" / "id00061").rglob("*_rgb.png"))[:2]
    if not frames:
        pytest.skip("fsth_eval_sample absent")
    _bad_inputs(tmp_path / "in")
    good = tmp_path / "in" / "person" / "photos"
    good.mkdir(parents=True)
    for frame in frames:
        shutil.copy(frame, good / frame.name.replace("_rgb", ""))
    summary = prepare_dataset(tmp_path / "in", tmp_path / "out", PrepareOptions(size=64, frames_per_clip=2), progress=False)
    assert summary.count("done") == 1 and summary.count("failed") == 3
    table = summary.table()
    assert "zero.mp4" in table or "empty" in table
    messages = {o.source.video: o.message for o in summary.outcomes if o.status == "failed"}
    assert "InputFileError" in messages["zero"] and "no face" in messages["shots"]
    _check_dataset(tmp_path / "out", 64)
    assert (tmp_path / "out" / "prepare_summary.json").is_file()
