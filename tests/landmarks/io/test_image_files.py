"""Image and video I/O: every common image kind reads as RGB uint8; video round-trips; bad files raise."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from landmarks.exceptions import InputFileError
from landmarks.io.image_files import atomic_output, read_image, to_rgb_uint8, write_image
from landmarks.io.video import VideoWriter, iter_frames, probe_video


class TestToRgbUint8:
    def test_grey_uint8_repeats_channels(self, rng):
        grey = rng.integers(0, 256, (5, 7), dtype=np.uint8)
        rgb = to_rgb_uint8(grey)
        assert rgb.shape == (5, 7, 3) and rgb.dtype == np.uint8
        assert (rgb == grey[:, :, None]).all()

    def test_uint16_scales_to_8_bit(self):
        assert (to_rgb_uint8(np.full((2, 2, 3), 65535, np.uint16)) == 255).all()
        assert (to_rgb_uint8(np.full((2, 2), 257 * 100, np.uint16)) == 100).all()

    def test_float_is_unit_range_and_clipped(self):
        rgb = to_rgb_uint8(np.array([[[-1.0, 0.5, 2.0]]]))
        assert rgb.tolist() == [[[0, 128, 255]]]

    def test_rgba_composites_on_white(self):
        rgba = np.zeros((1, 2, 4), np.uint8)
        rgba[0, 0] = (255, 0, 0, 255)  # opaque red
        rgba[0, 1] = (255, 0, 0, 0)  # fully transparent -> white
        assert to_rgb_uint8(rgba).tolist() == [[[255, 0, 0], [255, 255, 255]]]

    def test_bad_shape_raises(self):
        with pytest.raises(InputFileError):
            to_rgb_uint8(np.zeros((4, 4, 2), np.uint8))


class TestReadImage:
    def test_png_round_trip(self, tmp_path, astronaut):
        write_image(tmp_path / "a.png", astronaut)
        assert np.array_equal(read_image(tmp_path / "a.png"), astronaut)

    def test_grey_file(self, tmp_path, astronaut):
        grey = cv2.cvtColor(astronaut, cv2.COLOR_RGB2GRAY)
        cv2.imwrite(str(tmp_path / "g.png"), grey)
        image = read_image(tmp_path / "g.png")
        assert image.shape == (512, 512, 3) and np.array_equal(image[:, :, 0], grey)

    def test_rgba_file_composites_on_white(self, tmp_path, astronaut):
        bgra = cv2.cvtColor(astronaut, cv2.COLOR_RGB2BGRA)
        bgra[:10, :, 3] = 0  # transparent strip
        cv2.imwrite(str(tmp_path / "a.png"), bgra)
        image = read_image(tmp_path / "a.png")
        assert (image[:10] == 255).all()
        assert np.array_equal(image[10:], astronaut[10:])

    def test_16_bit_file(self, tmp_path, astronaut):
        cv2.imwrite(str(tmp_path / "a16.png"), cv2.cvtColor(astronaut, cv2.COLOR_RGB2BGR).astype(np.uint16) * 257)
        assert np.array_equal(read_image(tmp_path / "a16.png"), astronaut)

    def test_exif_orientation_is_applied(self, tmp_path, astronaut):
        from PIL import Image

        # Store the picture rotated 90 degrees counter-clockwise with EXIF orientation 6
        # ("rotate 90 clockwise to display"): a correct reader returns it upright.
        exif = Image.Exif()
        exif[0x0112] = 6
        Image.fromarray(np.rot90(astronaut).copy()).save(tmp_path / "r.jpg", exif=exif.tobytes(), quality=95)
        image = read_image(tmp_path / "r.jpg")
        assert image.shape == astronaut.shape
        assert np.abs(image.astype(int) - astronaut).mean() < 4.0  # JPEG loss only

    @pytest.mark.parametrize("name", ["corrupt.png", "corrupt.jpg"])
    def test_corrupt_file_raises_naming_it(self, tmp_path, rng, name):
        path = tmp_path / name
        path.write_bytes(rng.integers(0, 256, 2000, dtype=np.uint8).tobytes())
        with pytest.raises(InputFileError, match=name):
            read_image(path)

    def test_missing_and_empty_files_raise(self, tmp_path):
        with pytest.raises(InputFileError, match="not found"):
            read_image(tmp_path / "nope.png")
        (tmp_path / "empty.png").write_bytes(b"")
        with pytest.raises(InputFileError, match="empty"):
            read_image(tmp_path / "empty.png")


def test_atomic_output_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "x.txt"
    with pytest.raises(RuntimeError):
        with atomic_output(target) as temp:
            temp.write_text("partial")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    with atomic_output(target) as temp:
        temp.write_text("whole")
    assert target.read_text() == "whole" and list(tmp_path.iterdir()) == [target]


def _write_clip(path: Path, count: int, height: int, width: int, **kwargs) -> list[np.ndarray]:
    frames = [np.full((height, width, 3), 20 * index, np.uint8) for index in range(count)]
    with VideoWriter(path, 25, **kwargs) as writer:
        for frame in frames:
            writer.write(frame)
    return frames


class TestVideo:
    def test_round_trip_with_odd_size_and_metadata(self, tmp_path):
        path = tmp_path / "clip.mp4"
        frames = _write_clip(path, 6, 33, 41, metadata={"comment": "made by a test"})
        info = probe_video(path)
        assert (info.frames, info.width, info.height, info.fps, info.has_audio) == (6, 42, 34, 25.0, False)
        decoded = list(iter_frames(path))
        assert len(decoded) == 6
        for got, want in zip(decoded, frames):  # flat grey frames survive H.264 almost exactly
            assert abs(float(got[:33, :41].mean()) - float(want.mean())) < 2.0
        import av

        with av.open(str(path)) as container:
            assert container.metadata.get("comment") == "made by a test"
        assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]  # no temp left

    def test_error_inside_block_leaves_no_file(self, tmp_path):
        with pytest.raises(RuntimeError):
            with VideoWriter(tmp_path / "clip.mp4", 25) as writer:
                writer.write(np.zeros((16, 16, 3), np.uint8))
                raise RuntimeError("boom")
        assert list(tmp_path.iterdir()) == []

    def test_audio_is_carried_over(self, tmp_path, shared_data):
        source = shared_data / "clips" / "tpsmm_driving.mp4"
        frames = [frame for _, frame in zip(range(10), iter_frames(source))]
        with VideoWriter(tmp_path / "a.mp4", 25, audio_from=source) as writer:
            for frame in frames:
                writer.write(frame)
        info = probe_video(tmp_path / "a.mp4")
        assert info.has_audio and info.frames == 10
        assert info.duration < 0.6  # audio cut to the 0.4 s of video (+ one AAC packet)

    def test_corrupt_video_raises(self, tmp_path, rng):
        path = tmp_path / "corrupt.mp4"
        path.write_bytes(rng.integers(0, 256, 4000, dtype=np.uint8).tobytes())
        with pytest.raises(InputFileError, match="corrupt.mp4"):
            probe_video(path)
        with pytest.raises(InputFileError, match="corrupt.mp4"):
            list(iter_frames(path))

    def test_zero_frame_video_raises(self, tmp_path):
        import av

        path = tmp_path / "empty.mp4"
        with av.open(str(path), mode="w") as container:  # a valid container whose video stream has no frames
            stream = container.add_stream("libx264", rate=25)
            stream.width, stream.height, stream.pix_fmt = 64, 64, "yuv420p"
            container.start_encoding()
        # FFmpeg's MP4 muxer drops a stream without packets, so this reads as "no video stream".
        with pytest.raises(InputFileError, match="empty.mp4 (has no video stream|contains no .*frames)"):
            probe_video(path)
        with pytest.raises(InputFileError, match="empty.mp4 (has no video stream|contains no .*frames)"):
            list(iter_frames(path))
        (tmp_path / "zero.mp4").write_bytes(b"")
        with pytest.raises(InputFileError, match="empty"):
            probe_video(tmp_path / "zero.mp4")


def test_atomic_folder_replaces_a_folder_whole_or_not_at_all(tmp_path):
    from landmarks.io.image_files import atomic_folder

    target = tmp_path / "site"
    with atomic_folder(target) as temp:
        (temp / "a.txt").write_text("one")
    assert (target / "a.txt").read_text() == "one"
    with pytest.raises(RuntimeError), atomic_folder(target) as temp:
        (temp / "b.txt").write_text("half")
        raise RuntimeError("interrupted")
    assert sorted(p.name for p in target.iterdir()) == ["a.txt"]  # the old folder, untouched
    with atomic_folder(target) as temp:
        (temp / "b.txt").write_text("two")
    assert sorted(p.name for p in target.iterdir()) == ["b.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["site"]  # no temp or old folder left
