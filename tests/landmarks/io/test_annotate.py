"""``lsr landmarks`` end to end: image, folder and video inputs, and one-line errors from the CLI."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from landmarks.io.annotate import annotate_path
from landmarks.exceptions import NoFaceError
from landmarks.io.image_files import read_image, write_image
from landmarks.io.video import VideoWriter, iter_frames, probe_video
from lsr.cli import main


@pytest.fixture(scope="module")
def short_video(tmp_path_factory, astronaut):
    """8 frames of the astronaut drifting a few pixels per frame, 256x256, no audio."""
    import cv2

    path = tmp_path_factory.mktemp("video") / "drift.mp4"
    small = cv2.resize(astronaut, (256, 256), interpolation=cv2.INTER_AREA)
    with VideoWriter(path, 25) as writer:
        for index in range(8):
            writer.write(np.roll(small, (index, 2 * index), axis=(0, 1)))
    return path


def test_cli_on_an_image(tmp_path, astronaut):
    write_image(tmp_path / "astronaut.png", astronaut)
    out = tmp_path / "out"
    assert main(["landmarks", str(tmp_path / "astronaut.png"), "--out", str(out)]) == 0
    landmarks = np.load(out / "landmarks.npy")
    assert landmarks.shape == (1, 68, 2) and landmarks.dtype == np.float32 and np.isfinite(landmarks).all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["kind"] == "image" and summary["frames"] == 1 and summary["missing"] == []
    assert abs(summary["pose_yaw_pitch_roll_deg"][0][0]) < 30
    overlay = read_image(out / "overlay.png")
    assert overlay.shape == astronaut.shape and not np.array_equal(overlay, astronaut)
    assert sorted(p.name for p in out.iterdir()) == ["landmarks.npy", "overlay.png", "summary.json"]


def test_cli_on_a_video(tmp_path, short_video):
    out = tmp_path / "out"
    assert main(["landmarks", str(short_video), "--out", str(out)]) == 0
    landmarks = np.load(out / "landmarks.npy")
    raw = np.load(out / "landmarks_raw.npy")
    assert landmarks.shape == raw.shape == (8, 68, 2) and np.isfinite(landmarks).all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["kind"] == "video" and summary["fps"] == 25.0 and summary["missing"] == []
    assert summary["smoothing"] == {"enabled": True, "min_cutoff": 1.0, "beta": 0.05}
    assert summary["detections"] == 1
    info = probe_video(out / "overlay.mp4")
    assert (info.frames, info.width, info.height) == (8, 256, 256)
    assert len(list(iter_frames(out / "overlay.mp4"))) == 8  # decodes, every frame present
    # The face drifts right by 2 px/frame: the tracked jaw follows.
    assert raw[-1, 0, 0] - raw[0, 0, 0] == pytest.approx(14.0, abs=3.0)


def test_folder_marks_missing_images_without_failing(tmp_path, astronaut, rng):
    folder = tmp_path / "images"
    write_image(folder / "b_face.png", astronaut)
    write_image(folder / "a_noise.png", rng.integers(0, 256, (128, 128, 3), dtype=np.uint8))
    (folder / "c_corrupt.jpg").write_bytes(b"not a jpeg")
    (folder / "notes.txt").write_text("ignored")
    summary = annotate_path(folder, tmp_path / "out")
    assert summary["files"] == ["a_noise.png", "b_face.png", "c_corrupt.jpg"]
    assert summary["missing"] == [0, 2]
    assert "c_corrupt.jpg" in summary["problems"]
    landmarks = np.load(tmp_path / "out" / "landmarks.npy")
    assert np.isnan(landmarks[[0, 2]]).all() and np.isfinite(landmarks[1]).all()
    assert sorted(p.name for p in (tmp_path / "out" / "overlays").iterdir()) == ["a_noise.png", "b_face.png"]


def test_folder_without_any_face_fails_and_leaves_no_folder(tmp_path, rng):
    write_image(tmp_path / "in" / "noise.png", rng.integers(0, 256, (64, 64, 3), dtype=np.uint8))
    with pytest.raises(NoFaceError, match="no face found in any of the 1 images"):
        annotate_path(tmp_path / "in", tmp_path / "out" / "deep")
    assert not (tmp_path / "out").exists()  # neither the folders it made nor the overlays
    (tmp_path / "kept").mkdir()
    with pytest.raises(NoFaceError):
        annotate_path(tmp_path / "in", tmp_path / "kept")
    assert (tmp_path / "kept").is_dir() and not any((tmp_path / "kept").iterdir())  # the user's folder stays, empty


@pytest.mark.parametrize("case", ["proc", "parent_is_file"])
def test_unwritable_out_is_one_line_before_any_work(tmp_path, astronaut, capsys, monkeypatch, case):
    import landmarks.io.annotate as annotate_module

    monkeypatch.setattr(annotate_module, "make_detector", None)  # any detection would fail loudly
    write_image(tmp_path / "face.png", astronaut)
    (tmp_path / "blocker").write_text("a file")
    out = "/proc/x" if case == "proc" else str(tmp_path / "blocker" / "out")
    assert main(["landmarks", str(tmp_path / "face.png"), "--out", out]) == 2
    err = capsys.readouterr().err
    assert err.startswith("lsr: error: --out") and err.count("\n") == 1 and "cannot be written" in err


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("noise.png", "noise", "no face found in noise.png"),
        ("broken.png", "random", "cannot decode .*broken.png"),
        ("broken.mp4", "random", "cannot open .*broken.mp4"),
        ("empty.mp4", "", "empty"),
        ("absent.png", None, "not found"),
    ],
)
def test_cli_errors_are_one_line_and_exit_2(tmp_path, rng, capsys, name, content, message):
    path = tmp_path / name
    if content == "noise":
        write_image(path, rng.integers(0, 256, (200, 200, 3), dtype=np.uint8))
    elif content == "random":
        path.write_bytes(rng.integers(0, 256, 3000, dtype=np.uint8).tobytes())
    elif content == "":
        path.write_bytes(b"")
    assert main(["landmarks", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lsr: error: ") and "\n" not in err
    assert re.search(message, err), err
    assert not (tmp_path / "out" / "landmarks.npy").exists()


def test_cli_annotates_the_astronaut(tmp_path, capsys):
    import skimage.data

    write_image(tmp_path / "astronaut.png", skimage.data.astronaut())
    assert main(["landmarks", str(tmp_path / "astronaut.png"), "--out", str(tmp_path / "landmarks")]) == 0
    assert np.load(tmp_path / "landmarks" / "landmarks.npy").shape == (1, 68, 2)
    assert (tmp_path / "landmarks" / "overlay.png").is_file()
