"""Rotated video: phone clips (display matrix or legacy ``rotate`` tag) decode upright; outputs carry no rotation.

Fixtures are tiny clips written here with PyAV: an upright portrait pattern (a bright square in the top-left
corner, so every turn and mirror is told apart) stored turned the way a phone stores it, plus the rotation
that tells a player how to turn it back.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from landmarks.io.video import VideoWriter, iter_frames, probe_video

av = pytest.importorskip("av")

HEIGHT, WIDTH, SQUARE = 64, 48, 16  # upright portrait: taller than wide
# An iPhone held upright writes landscape frames and this tkhd matrix (16.16 fixed point, last entry 2.30):
# ffprobe reads it as "rotation of -90.00 degrees", players turn the frames 90 degrees clockwise.
PHONE_PORTRAIT_MATRIX = (0, 1 << 16, 0, -(1 << 16), 0, 0, 0, 0, 1 << 30)


def upright_pattern() -> np.ndarray:
    """(HEIGHT, WIDTH, 3) uint8: dark grey with a white square in the top-left corner."""
    image = np.full((HEIGHT, WIDTH, 3), 30, np.uint8)
    image[:SQUARE, :SQUARE] = 255
    return image


def write_rotated_clip(path: Path, form: str, degrees: int, upright: list[np.ndarray] | None = None) -> Path:
    """A clip that displays as ``upright`` ((H, W, 3) uint8 RGB frames; default 3 ``upright_pattern``) once turned.

    form: "matrix" (MP4 display matrix; ``degrees`` counter-clockwise, as ``VideoFrame.rotation`` reads it),
    "phone" (MP4 with ``PHONE_PORTRAIT_MATRIX``; ``degrees`` ignored) or "tag" (MKV with the legacy
    ``rotate`` stream tag; ``degrees`` clockwise, as older FFmpeg wrote it; MP4 muxers no longer keep it).
    """
    counter_clockwise = {"matrix": degrees, "phone": -90, "tag": -degrees}[form]
    upright = upright if upright is not None else [upright_pattern()] * 3
    # what the camera stored: the upright picture turned back against the display rotation
    stored = [np.ascontiguousarray(np.rot90(image, k=-counter_clockwise // 90)) for image in upright]
    with av.open(str(path), mode="w", format="matroska" if form == "tag" else "mp4") as container:
        stream = container.add_stream("libx264", rate=10)
        stream.width, stream.height, stream.pix_fmt = stored[0].shape[1], stored[0].shape[0], "yuv420p"
        if form == "phone":
            stream.set_display_matrix(PHONE_PORTRAIT_MATRIX)
        elif form == "matrix":
            stream.set_display_rotation(degrees)
        else:
            stream.metadata["rotate"] = str(degrees)
        for image in stored:
            for packet in stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)
    return path


def assert_upright(frame: np.ndarray) -> None:
    """The pattern, not a turned or mirrored copy: portrait size, square top-left, other corners dark."""
    assert frame.shape == (HEIGHT, WIDTH, 3)
    corners = {
        "top-left": frame[:SQUARE, :SQUARE],
        "top-right": frame[:SQUARE, -SQUARE:],
        "bottom-left": frame[-SQUARE:, :SQUARE],
        "bottom-right": frame[-SQUARE:, -SQUARE:],
    }
    means = {name: float(block.mean()) for name, block in corners.items()}
    assert means["top-left"] > 200, means
    assert all(value < 80 for name, value in means.items() if name != "top-left"), means


class TestRotatedInput:
    @pytest.mark.parametrize("form", ["matrix", "tag"])
    @pytest.mark.parametrize("degrees", [90, 180, 270])
    def test_frames_come_out_upright_and_probe_reports_the_upright_size(self, tmp_path, form, degrees):
        path = write_rotated_clip(tmp_path / f"clip.{'mp4' if form == 'matrix' else 'mkv'}", form, degrees)
        info = probe_video(path)
        assert (info.width, info.height, info.frames) == (WIDTH, HEIGHT, 3)
        counter_clockwise = degrees if form == "matrix" else -degrees
        assert info.rotation == counter_clockwise % 360
        frames = list(iter_frames(path))
        assert len(frames) == 3
        for frame in frames:
            assert_upright(frame)

    def test_phone_portrait_matrix(self, tmp_path):
        """The exact matrix an upright phone writes (not PyAV's helper), so the sign convention is pinned."""
        path = write_rotated_clip(tmp_path / "phone.mp4", "phone", 0)
        with av.open(str(path)) as container:  # stored lying on its side, as a phone does
            stored = next(container.decode(video=0))
            assert (stored.width, stored.height) == (HEIGHT, WIDTH) and stored.rotation == -90
        info = probe_video(path)
        assert (info.width, info.height, info.rotation) == (WIDTH, HEIGHT, 270)
        assert_upright(next(iter_frames(path)))

    def test_unrotated_clip_is_untouched(self, tmp_path):
        path = write_rotated_clip(tmp_path / "plain.mp4", "matrix", 0)
        info = probe_video(path)
        assert (info.width, info.height, info.rotation) == (WIDTH, HEIGHT, 0)
        assert_upright(next(iter_frames(path)))


class TestWriterCarriesNoRotation:
    def test_rewritten_phone_clip_has_no_display_matrix_or_rotate_tag(self, tmp_path):
        source = write_rotated_clip(tmp_path / "phone.mp4", "phone", 0)
        out = tmp_path / "out.mp4"
        # a caller copying the source's tags must not smuggle a rotation in
        with VideoWriter(out, probe_video(source).fps, metadata={"rotate": "90", "comment": "kept"}) as writer:
            for frame in iter_frames(source):
                writer.write(frame)
        with av.open(str(out)) as container:
            stream = container.streams.video[0]
            assert "rotate" not in {key.lower() for key in (*container.metadata, *stream.metadata)}
            assert container.metadata.get("comment") == "kept"
            first = next(container.decode(stream))
            assert first.rotation == 0 and (first.width, first.height) == (WIDTH, HEIGHT)
            # PyAV 18.1.0 iterates side data entries, 18.1.1 (a Mapping) their types
            kinds = [getattr(entry, "type", entry) for entry in first.side_data]
            assert not any(kind.name == "DISPLAYMATRIX" for kind in kinds)
        info = probe_video(out)
        assert (info.width, info.height, info.rotation) == (WIDTH, HEIGHT, 0)
        for frame in iter_frames(out):
            assert_upright(frame)


def test_writer_sweeps_temp_files_of_killed_writers_only(tmp_path):
    import subprocess
    import sys

    from landmarks.io.video import VideoWriter

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(gone.stdout)  # that process has exited
    stale = tmp_path / f".out.lsr{dead_pid}-abc123.tmp.mp4"
    live = tmp_path / f".out.lsr{os.getppid()}-def456.tmp.mp4"  # a running process: a concurrent writer
    other = tmp_path / f".other.lsr{dead_pid}-abc123.tmp.mp4"  # another target's file
    for path in (stale, live, other):
        path.write_bytes(b"half a video")
    with VideoWriter(tmp_path / "out.mp4", 10) as writer:
        writer.write(np.zeros((32, 32, 3), np.uint8))
    assert not stale.exists() and live.exists() and other.exists()
    assert (tmp_path / "out.mp4").is_file()
