"""Video reading and H.264 writing with PyAV (streaming, bounded memory).

``probe_video`` and ``iter_frames`` turn every decoding problem (missing, corrupt,
no video stream, zero frames) into an ``InputFileError`` naming the file.

Both honour the stream's rotation, as a player does: phones store portrait clips
as landscape frames plus a rotation, either the display matrix (side data; what
FFmpeg reads from an MP4/MOV ``tkhd`` matrix) or, in files from older tools, a
legacy ``rotate`` stream tag (degrees clockwise). Frames come out upright and
``probe_video`` reports the upright size; flips in a display matrix are not
applied (phones do not write them).

``VideoWriter`` encodes libx264 / yuv420p into a temp file beside the target and
moves it into place only when the ``with`` block ends without an error (temp files
of killed earlier writers of the same target are swept first); it can
carry the audio of a source video (copied when the codec fits MP4, otherwise
transcoded to AAC) and container metadata tags. It writes upright frames with no
display matrix and drops a ``rotate`` tag from the metadata it is given, so no
stale rotation turns the output again.
"""

from __future__ import annotations

import dataclasses
import glob
import os
import re
import tempfile
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np

from landmarks.exceptions import InputFileError
from landmarks.io.image_files import make_readable

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".webm", ".gif", ".mpg", ".mpeg", ".flv", ".wmv")
_MP4_AUDIO_COPY = ("aac", "mp3", "alac", "ac3", "eac3", "opus", "flac")


@dataclasses.dataclass(frozen=True)
class VideoInfo:
    frames: int
    fps: float
    width: int
    height: int
    has_audio: bool
    duration: float  # seconds
    rotation: int = 0  # degrees counter-clockwise applied on decode (0, 90, 180, 270); width/height are upright


def _tag_rotation(stream: Any) -> int:
    """The legacy ``rotate`` tag (degrees clockwise, any case) as degrees counter-clockwise; 0 when absent."""
    for key, value in stream.metadata.items():
        if key.lower() == "rotate":
            try:
                return -round(float(value))
            except ValueError:  # a garbled tag: play it as stored, like FFmpeg does
                return 0
    return 0


def _quarter_turns(frame: Any, tag_rotation: int) -> int:
    """Counter-clockwise quarter turns (0..3) that make ``frame`` upright.

    The display matrix on the frame wins over the legacy tag (FFmpeg attaches the stream's matrix to every
    decoded frame). ``VideoFrame.rotation`` is the counter-clockwise angle in [-180, 180].
    """
    degrees = frame.rotation or tag_rotation
    return round(degrees / 90) % 4


_CV2_TURNS = {1: cv2.ROTATE_90_COUNTERCLOCKWISE, 2: cv2.ROTATE_180, 3: cv2.ROTATE_90_CLOCKWISE}


def _upright(image: np.ndarray, turns: int) -> np.ndarray:
    """(H, W, 3) stored frame -> the displayed (upright) frame after ``turns`` counter-clockwise quarter turns."""
    return image if turns == 0 else cv2.rotate(image, _CV2_TURNS[turns])


def _open_input(path: Path) -> Any:
    import av

    if not path.exists():
        raise InputFileError(f"video not found: {path}")
    if not path.is_file():
        raise InputFileError(f"video path is not a file: {path}")
    if path.stat().st_size == 0:
        raise InputFileError(f"video file is empty (0 bytes): {path}")
    try:
        container = av.open(str(path), mode="r")
    except (av.FFmpegError, OSError, ValueError) as exc:
        raise InputFileError(f"cannot open {path} as a video (corrupt or unsupported): {exc}") from exc
    if not container.streams.video:
        container.close()
        raise InputFileError(f"{path} has no video stream; give a video file (mp4, mov, mkv, ...)")
    return container


def _scan(container: Any, stream: Any, *, count_packets: bool) -> tuple[int, int]:
    """(packets with data, quarter turns of the first decodable frame) in one demux pass.

    Decodes only until the first frame comes out (the display matrix travels on decoded frames); counts
    every packet only when ``count_packets`` (containers that store no frame count). Turns fall back to the
    legacy tag when no frame decodes (``iter_frames`` then reports the file).
    """
    packets, turns = 0, None
    tag_rotation = _tag_rotation(stream)
    for packet in container.demux(stream):
        packets += int(packet.size > 0)
        if turns is None:
            decoded = packet.decode()  # the empty packet at the end flushes a decoder that held frames back
            if decoded:
                turns = _quarter_turns(decoded[0], tag_rotation)
        if turns is not None and not count_packets:
            break
    return packets, turns if turns is not None else round(tag_rotation / 90) % 4


def probe_video(path: str | os.PathLike[str]) -> VideoInfo:
    """Frame count, frame rate, upright size, rotation, audio presence and duration of a video file."""
    import av

    path = Path(path)
    container = _open_input(path)
    try:
        stream = container.streams.video[0]
        frames = int(stream.frames or 0)
        # some containers do not store a count: count packets (decoding only the first frame, for its rotation)
        packets, turns = _scan(container, stream, count_packets=frames == 0)
        frames = frames or packets
        rate = stream.average_rate or stream.guessed_rate or stream.base_rate
        fps = float(rate) if rate else 25.0
        width, height = int(stream.codec_context.width), int(stream.codec_context.height)
        if turns % 2:  # a quarter turn swaps the sides: report what iter_frames yields
            width, height = height, width
        has_audio = bool(container.streams.audio)
        duration = container.duration / 1e6 if container.duration else frames / fps
    except av.FFmpegError as exc:
        raise InputFileError(f"cannot read {path} as a video (corrupt?): {exc}") from exc
    finally:
        container.close()
    if frames == 0 or width == 0 or height == 0:
        raise InputFileError(f"{path} contains no video frames; give a video with at least one frame")
    return VideoInfo(
        frames=frames, fps=fps, width=width, height=height, has_audio=has_audio, duration=duration, rotation=90 * turns
    )


def iter_frames(path: str | os.PathLike[str]) -> Iterator[np.ndarray]:
    """Decode frames one at a time: each (H, W, 3) uint8 RGB, upright (the stream's rotation applied).

    A file cut short (a stopped download) yields the frames before the damage and stops: fewer than
    ``probe_video`` declares, which callers report. Nothing decodable is an ``InputFileError``."""
    import av

    path = Path(path)
    container = _open_input(path)
    count = 0
    try:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        tag_rotation = _tag_rotation(stream)
        for frame in container.decode(stream):
            count += 1
            yield _upright(frame.to_ndarray(format="rgb24"), _quarter_turns(frame, tag_rotation))
    except av.FFmpegError as exc:
        if count == 0:
            raise InputFileError(f"decoding {path} failed before its first frame (corrupt video?): {exc}") from exc
        # a cut file (stopped download): keep the frames that decoded; callers compare with probe_video's count
    finally:
        container.close()
    if count == 0:
        raise InputFileError(f"{path} contains no decodable video frames; give a valid video")


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def sweep_stale_temps(path: str | os.PathLike[str]) -> list[Path]:
    """Delete the temp files that writers of ``path`` left when they were killed (SIGKILL, power loss).

    A writer's temp name carries its process id (``.<stem>.lsr<pid>-<random>.tmp.mp4``); only files whose
    process is gone are removed, so a concurrent writer is never disturbed. Returns the removed paths."""
    path = Path(path)
    pattern = re.compile(rf"^\.{re.escape(path.stem)}\.lsr(\d+)-\w+\.tmp\.mp4$")
    removed = []
    for candidate in path.parent.glob(f".{glob.escape(path.stem)}.lsr*.tmp.mp4"):
        match = pattern.match(candidate.name)
        if match and not _process_alive(int(match.group(1))):
            candidate.unlink(missing_ok=True)
            removed.append(candidate)
    return removed


def _even(frame: np.ndarray) -> np.ndarray:
    """yuv420p needs even sizes: replicate the last row/column when odd."""
    height, width = frame.shape[:2]
    pad_y, pad_x = height % 2, width % 2
    if pad_y or pad_x:
        frame = np.pad(frame, ((0, pad_y), (0, pad_x), (0, 0)), mode="edge")
    return frame


class VideoWriter:
    """H.264 MP4 writer used as a context manager.

    with VideoWriter(path, fps, audio_from=src, metadata={"comment": "..."}) as writer:
        writer.write(frame)  # (H, W, 3) uint8 RGB, same size every frame; odd sizes padded to even

    The file appears under ``path`` only when the block ends without an error. x264's ``veryfast`` preset at CRF 18
    by default: on a 480² talking head it encodes in 4.3 ms a frame against ``medium``'s 15.8 ms, for a file 3 %
    larger (the same CRF keeps the quality), which leaves a core's worth of time to the synthesis on 2 cores.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        fps: float,
        *,
        audio_from: str | os.PathLike[str] | None = None,
        metadata: dict[str, str] | None = None,
        crf: int = 18,
        preset: str = "veryfast",
    ) -> None:
        if fps <= 0:
            raise ValueError(f"fps must be > 0, got {fps}")
        self.path = Path(path)
        self.fps = Fraction(fps).limit_denominator(1001)
        self.audio_from = Path(audio_from) if audio_from is not None else None
        self.metadata = dict(metadata or {})
        self.crf, self.preset = crf, preset
        self.frames_written = 0
        self._container: Any = None
        self._stream: Any = None
        self._temp: Path | None = None
        self._size: tuple[int, int] | None = None
        self._audio_source: Any = None
        self._audio_stream: Any = None
        self._audio_copy = False

    def __enter__(self) -> VideoWriter:
        import av

        self.path.parent.mkdir(parents=True, exist_ok=True)
        sweep_stale_temps(self.path)
        handle, name = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.stem}.lsr{os.getpid()}-", suffix=".tmp.mp4")
        os.close(handle)
        self._temp = Path(name)
        self._container = av.open(name, mode="w", format="mp4")
        for key, value in self.metadata.items():
            if key.lower() != "rotate":  # frames are written upright: a copied rotation would turn them again
                self._container.metadata[key] = str(value)
        return self

    def _start(self, height: int, width: int) -> None:
        stream = self._container.add_stream("libx264", rate=self.fps)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"crf": str(self.crf), "preset": self.preset}
        stream.set_display_matrix(None)  # upright frames, identity display: players must not rotate them
        self._stream, self._size = stream, (height, width)
        if self.audio_from is not None:
            # Every stream must exist before the first packet is muxed (that writes the header).
            self._add_audio_stream()

    def write(self, frame: np.ndarray) -> None:
        """Append one (H, W, 3) uint8 RGB frame."""
        import av

        frame = np.asarray(frame)
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise ValueError(f"frame must be (H, W, 3) uint8 RGB, got {frame.shape} {frame.dtype}")
        frame = _even(frame)
        if self._stream is None:
            self._start(*frame.shape[:2])
        elif frame.shape[:2] != self._size:
            raise ValueError(f"frame size {frame.shape[:2]} differs from the first frame's {self._size}")
        video_frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
        for packet in self._stream.encode(video_frame):
            self._container.mux(packet)
        self.frames_written += 1

    def _add_audio_stream(self) -> None:
        assert self.audio_from is not None
        self._audio_source = _open_input(self.audio_from)
        if not self._audio_source.streams.audio:
            self._audio_source.close()
            self._audio_source = None
            return
        in_audio = self._audio_source.streams.audio[0]
        self._audio_copy = in_audio.codec_context.name in _MP4_AUDIO_COPY
        if self._audio_copy:
            self._audio_stream = self._container.add_stream_from_template(in_audio)
        else:  # e.g. PCM in a MOV/AVI: MP4 needs a compressed codec
            self._audio_stream = self._container.add_stream("aac", rate=in_audio.rate or 48000)

    def _mux_audio(self) -> None:
        """Mux the source's first audio stream, cut to the video's duration."""
        import av

        source = self._audio_source
        if source is None:
            return
        limit = self.frames_written / float(self.fps) + 0.05
        in_audio = source.streams.audio[0]
        try:
            if self._audio_copy:
                for packet in source.demux(in_audio):
                    if packet.dts is None or packet.pts is None:
                        continue
                    if packet.pts * packet.time_base > limit:
                        break
                    packet.stream = self._audio_stream
                    self._container.mux(packet)
            else:
                for frame in source.decode(in_audio):
                    if frame.time is not None and frame.time > limit:
                        break
                    frame.pts = None
                    for packet in self._audio_stream.encode(frame):
                        self._container.mux(packet)
                for packet in self._audio_stream.encode(None):
                    self._container.mux(packet)
        except av.FFmpegError as exc:
            raise InputFileError(f"cannot copy audio from {self.audio_from}: {exc}") from exc

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        assert self._temp is not None
        try:
            if exc_type is None:
                if self._stream is None:
                    raise ValueError(f"no frames were written to {self.path}")
                for packet in self._stream.encode(None):  # flush the encoder
                    self._container.mux(packet)
                self._mux_audio()
            self._container.close()
            self._container = None
            if exc_type is None:
                make_readable(self._temp)
                os.replace(self._temp, self.path)
        finally:
            if self._container is not None:
                try:
                    self._container.close()
                except Exception:  # already failing: the original error matters more
                    pass
            if self._audio_source is not None:
                self._audio_source.close()
                self._audio_source = None
            self._temp.unlink(missing_ok=True)


def trim_clip(video: str | os.PathLike[str], out: str | os.PathLike[str], frames: int) -> Path:
    """Write the first ``frames`` frames of ``video`` (with its audio) to ``out`` (H.264, atomically)."""
    info = probe_video(video)
    with VideoWriter(out, info.fps, audio_from=video if info.has_audio else None) as writer:
        for index, frame in enumerate(iter_frames(video)):
            if index >= frames:
                break
            writer.write(frame)
    return Path(out)
