"""``lsr reenact --paste-back`` composites into the source's own scene (issue 23): the output has the source's
frame size, and outside the head it is the source's frames (its background and body), not the driver's."""

from __future__ import annotations

import numpy as np
import pytest

from lsr.cli import main

SOURCE_FRAMES, DRIVER_FRAMES = 10, 16


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    import torch

    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    return LSRModel(preset_config("tiny")).save_pretrained(tmp_path_factory.mktemp("w") / "tiny")


def _write(path, frames, fps=25):
    from landmarks.io.video import VideoWriter

    with VideoWriter(path, fps) as writer:
        for frame in frames:
            writer.write(frame)
    return path


def _read(path) -> np.ndarray:
    from landmarks.io.video import iter_frames

    return np.stack(list(iter_frames(path)))


def ping_pong(index: int, count: int) -> int:
    """The source frame shown at output frame ``index``: forth, back, forth (``lsr.core.scene``)."""
    if count == 1:
        return 0
    period = 2 * (count - 1)
    position = index % period
    return position if position < count else period - position


def _outside_head(landmarks: np.ndarray, shape: tuple[int, int], grow: int) -> np.ndarray:
    import cv2

    from landmarks.scene.compositing import head_region

    region = head_region([landmarks], shape, person=True).astype(np.uint8)  # the matte composite reaches further
    return cv2.dilate(region, np.ones((2 * grow + 1, 2 * grow + 1), np.uint8)) == 0


def _psnr(first: np.ndarray, second: np.ndarray) -> float:
    error = np.mean((first.astype(np.float64) - second.astype(np.float64)) ** 2)
    return float("inf") if error == 0 else float(10 * np.log10(255**2 / error))


def test_two_synthetic_people_output_is_the_source_scene(weights, tmp_path):
    from lsr.data.synth import render_video

    source_clip, driver_clip = render_video(31, SOURCE_FRAMES, 256), render_video(32, DRIVER_FRAMES, 256)
    # the source is wider than the driver (and than any crop): its frame size must survive
    wide = np.pad(source_clip.frames, ((0, 0), (0, 0), (64, 64), (0, 0)), mode="edge")
    source, driver = _write(tmp_path / "source.mp4", wide), _write(tmp_path / "driver.mp4", driver_clip.frames)
    out = tmp_path / "out.mp4"
    assert main(["reenact", "--weights", str(weights), "--source", str(source), "--driver", str(driver), "--out",
                 str(out), "--paste-back", "--finetune-steps", "0", "--k", "4", "--no-progress"]) == 0
    output, sources = _read(out), _read(source)
    assert output.shape == (DRIVER_FRAMES, 256, 384, 3)
    shifted = source_clip.landmarks + [64.0, 0.0]  # exact landmarks of the padded source frames
    for index, frame in enumerate(output):
        scene = ping_pong(index, SOURCE_FRAMES)
        outside = _outside_head(shifted[scene], frame.shape[:2], grow=8)
        assert outside.mean() > 0.3  # the test looks at a real part of the frame
        assert _psnr(frame[outside], sources[scene][outside]) >= 30  # the source's background and body
        driver_frame = np.pad(driver_clip.frames[index], ((0, 0), (64, 64), (0, 0)), mode="edge")
        assert _psnr(frame[outside], driver_frame[outside]) < 20  # not the driver's scene


def test_driver_scene_stays_available(weights, tmp_path):
    from lsr.data.synth import render_video

    source = _write(tmp_path / "source.mp4", render_video(31, 4, 256).frames)
    driver_clip = render_video(32, 6, 256)
    driver = _write(tmp_path / "driver.mp4", np.pad(driver_clip.frames, ((0, 0), (0, 0), (32, 32), (0, 0)), mode="edge"))
    out = tmp_path / "dub.mp4"
    assert main(["reenact", "--weights", str(weights), "--source", str(source), "--driver", str(driver), "--out",
                 str(out), "--paste-back", "--scene", "driver", "--finetune-steps", "0", "--k", "2", "--no-progress"]) == 0
    output, drivers = _read(out), _read(driver)
    assert output.shape == drivers.shape
    outside = _outside_head(driver_clip.landmarks[0] + [32.0, 0.0], output.shape[1:3], grow=8)
    assert _psnr(output[0][outside], drivers[0][outside]) >= 30


def test_image_source_scene_is_the_anchor_photo_at_its_size(weights, tmp_path):
    from landmarks.io.image_files import write_image
    from lsr.data.synth import render_video

    folder = tmp_path / "shots"
    folder.mkdir()
    clip = render_video(31, 3, 256)
    for index, frame in enumerate(clip.frames):
        write_image(folder / f"{index}.png", np.pad(frame, ((16, 16), (0, 0), (0, 0)), mode="edge"))
    driver = _write(tmp_path / "driver.mp4", render_video(32, 5, 256).frames)
    out = tmp_path / "out.mp4"
    assert main(["reenact", "--weights", str(weights), "--source", str(folder), "--driver", str(driver), "--out",
                 str(out), "--paste-back", "--anchor", "1", "--finetune-steps", "0", "--k", "3", "--no-progress"]) == 0
    output = _read(out)
    assert output.shape == (5, 288, 256, 3)
    anchor = np.pad(clip.frames[1], ((16, 16), (0, 0), (0, 0)), mode="edge")
    outside = _outside_head(clip.landmarks[1] + [0.0, 16.0], output.shape[1:3], grow=8)
    assert all(_psnr(frame[outside], anchor[outside]) >= 30 for frame in output)


def test_anchor_outside_the_shots_is_one_line(weights, tmp_path, capsys):
    from landmarks.io.image_files import write_image
    from lsr.data.synth import render_video

    source = tmp_path / "a.png"
    write_image(source, render_video(31, 1, 256).frames[0])
    driver = _write(tmp_path / "driver.mp4", render_video(32, 2, 256).frames)
    code = main(["reenact", "--weights", str(weights), "--source", str(source), "--driver", str(driver), "--out",
                 str(tmp_path / "o.mp4"), "--paste-back", "--anchor", "3", "--finetune-steps", "0", "--no-progress"])
    assert code == 2
    assert "--anchor 3 is not one of the 1 shots" in capsys.readouterr().err
    assert not (tmp_path / "o.mp4").exists()


def test_shared_clips_sun_driven_by_tpsmm(weights, shared_data, tmp_path):
    """The issue's real pair, trimmed: musetalk_sun.mp4 (a small face in a 576x768 frame) driven by tpsmm_driving.mp4."""
    from landmarks.detect.registry import make_detector
    from landmarks.io.video import iter_frames

    clips = shared_data / "clips"
    if not (clips / "musetalk_sun.mp4").is_file() or not (clips / "tpsmm_driving.mp4").is_file():
        pytest.skip("musetalk_sun.mp4 / tpsmm_driving.mp4 absent")

    def trim(name, count):
        frames = []
        for frame in iter_frames(clips / name):
            frames.append(frame)
            if len(frames) == count:
                break
        return _write(tmp_path / name, frames)

    source, driver = trim("musetalk_sun.mp4", 12), trim("tpsmm_driving.mp4", 8)
    out = tmp_path / "out.mp4"
    assert main(["reenact", "--weights", str(weights), "--source", str(source), "--driver", str(driver), "--out",
                 str(out), "--paste-back", "--finetune-steps", "0", "--k", "2", "--no-progress"]) == 0
    output, sources = _read(out), _read(source)
    assert output.shape == (8, *sources.shape[1:])
    detector = make_detector()
    for index in (0, 7):
        scene = sources[ping_pong(index, len(sources))]
        outside = _outside_head(detector.detect(scene)[0].landmarks, scene.shape[:2], grow=12)
        assert _psnr(output[index][outside], scene[outside]) >= 30
