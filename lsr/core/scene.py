"""The source's scene: the frames a re-enactment is composited into (``lsr reenact --paste-back``, issue 23).

* Image sources (one image, a folder, arrays): the anchor shot's full-resolution frame, every frame (or the
  anchor crop itself when the shots came as crops).
* A video source: its own frames in order, tracked like a driver, played back and forth when the driver is
  longer. For the way back the first pass's scene frames are kept as they are, with the matte and plate their
  composite made, when the whole video fits ``KEPT_BYTES``; a longer one is kept JPEG-compressed (about 50 kB a
  frame) and its layers are made again.

Each scene frame comes with its landmarks and crop transform. The driven face keeps the source's head pose of
that frame: ``place`` moves the target landmarks (in the anchor's crop coordinates) by the rigid motion from the
anchor's face to this frame's, so in a video the source's own head motion plays on under the driver's expression.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING

import cv2
import numpy as np

from lsr.core.inputs import SubjectShots

if TYPE_CHECKING:
    from landmarks.scene.compositing import SceneLayers

JPEG_QUALITY = 95
KEPT_BYTES = 512 * 2**20
"""A video source whose frames, with their person matte and background plate, take at most this many bytes is
played back from memory (``KEPT_PIXEL_BYTES`` a pixel), so 75 GRID frames (360x288) take 78 MB and a 550-frame
576x768 video would take 2.4 GB (kept as JPEG). Each layer made once, not again on every way back and forth."""
KEPT_PIXEL_BYTES = 10
"""A kept scene frame's bytes a pixel: its RGB, its person matte (float32) and its background plate (RGB)."""


@dataclasses.dataclass
class SceneFrame:
    image: np.ndarray
    """(H, W, 3) uint8 RGB: the scene."""
    landmarks: np.ndarray | None
    """(68, 2) float64 frame pixels of the source's face (None: no face found yet in a video source)."""
    matrix: np.ndarray | None
    """(2, 3) frame -> crop transform of that face at the crop side."""
    motion: tuple[float, np.ndarray, np.ndarray] | None
    """Similarity (scale, R, t) from the anchor's crop landmarks to this frame's, crop pixels."""
    layers: SceneLayers | None = dataclasses.field(default=None, repr=False)
    """``landmarks.scene.compositing.SceneLayers`` of this frame (its person matte and background plate), made by the first
    ``composite`` and kept: a still scene pays for them once."""

    def composite(self, crop_landmarks: np.ndarray, synthesis: np.ndarray) -> np.ndarray:
        """A synthesised face crop (its target landmarks in this frame's crop pixels) put into this frame
        (``landmarks.scene.compositing.composite_face``, the person moving with the head and the background staying)
        -> (H, W, 3) uint8."""
        from landmarks.scene.compositing import composite_face, place_in_frame
        from landmarks.scene.person_matte import scene_layers

        if self.layers is None:
            self.layers = scene_layers(self.image, self.landmarks)
        return composite_face(self.image, self.landmarks, place_in_frame(crop_landmarks, self.matrix), synthesis,
                              self.matrix, self.layers).frame

    def place(self, crop_landmarks: np.ndarray) -> np.ndarray:
        """Target landmarks in the anchor's crop coordinates -> this frame's crop coordinates (68, 2)."""
        from landmarks.motion.retarget_points import apply_similarity

        return crop_landmarks if self.motion is None else apply_similarity(crop_landmarks, *self.motion)

    def place_mesh(self, crop_mesh: np.ndarray) -> np.ndarray:
        """``place`` for a (468, 3) mesh: x, y as points, depth scaled with them."""
        from landmarks.motion.retarget_points import apply_similarity

        if self.motion is None:
            return crop_mesh
        scale = float(self.motion[0])
        return np.concatenate([apply_similarity(crop_mesh[:, :2], *self.motion), crop_mesh[:, 2:3] * scale], axis=1)


class SourceScene:
    """An endless stream of ``SceneFrame``s of a subject's source (module docstring)."""

    def __init__(self, shots: SubjectShots, crop_size: int, *, detector=None, fps: float = 25.0,
                 smooth: bool = True, track: list[np.ndarray | None] | None = None,
                 frames_needed: int | None = None) -> None:
        """track: a video source's points per frame as ``detector``'s tracker reads them (``Subject.video_track``),
        so that they are not tracked again; frames_needed: how many scene frames will be asked for, when known (a
        driver no longer than the video never plays it back, so its frames are not kept for the way back)."""
        from landmarks.align import crop_transform

        self.crop_size = int(crop_size)
        self._anchor = np.asarray(shots.landmarks[shots.anchor], np.float64)
        self._frames: Iterator[SceneFrame] | None = None
        if shots.video is not None:
            self._frames = self._video_frames(shots, detector, fps, smooth, track, frames_needed)
            self._still = None
            return
        if shots.anchor_frame is not None:
            image, points = shots.anchor_frame, np.asarray(shots.anchor_frame_landmarks, np.float64)
        else:  # shots given as crops: the anchor crop is the scene
            image, points = shots.frames[shots.anchor], self._anchor
        self._still = SceneFrame(image, points, crop_transform(points, self.crop_size), None)

    def __next__(self) -> SceneFrame:
        return self._still if self._frames is None else next(self._frames)

    def __iter__(self) -> SourceScene:
        return self

    def _frame(self, image: np.ndarray, points: np.ndarray | None) -> SceneFrame:
        from landmarks.align import crop_transform, transform_landmarks
        from landmarks.motion.retarget_points import RIGID_INDEX, similarity_procrustes

        if points is None:
            return SceneFrame(image, None, None, None)
        matrix = crop_transform(points, self.crop_size)
        rigid = list(RIGID_INDEX)
        motion = similarity_procrustes(self._anchor[rigid], transform_landmarks(points, matrix)[rigid])
        return SceneFrame(image, points, matrix, motion)

    def _video_frames(self, shots: SubjectShots, detector, fps: float, smooth: bool,
                      track: list[np.ndarray | None] | None = None,
                      frames_needed: int | None = None) -> Iterator[SceneFrame]:
        from landmarks.motion.smooth import OneEuroFilter
        from landmarks.detect.registry import make_tracker
        from landmarks.io.video import iter_frames, probe_video

        tracker = make_tracker(detector) if track is None else None
        one_euro = OneEuroFilter(fps) if smooth else None
        info = probe_video(shots.video)
        keep = frames_needed is None or frames_needed > info.frames  # the way back is needed
        in_memory = _fits_in_memory(info.frames, info.height, info.width)
        kept: list[SceneFrame] = []
        encoded: list[bytes] = []
        places: list[np.ndarray | None] = []
        last = None
        for index, image in enumerate(iter_frames(shots.video)):
            if tracker is not None:
                points = tracker.update(image)
            else:
                points = track[index] if index < len(track) else None  # type: ignore[index]
            if points is not None and np.isfinite(points).all():
                last = one_euro(points) if one_euro is not None else np.asarray(points, np.float64)
            places.append(last)
            scene = self._frame(image, last)  # a face-less stretch keeps the last face's place
            if keep and in_memory:
                kept.append(scene)  # its layers too, once its composite has made them
                if not _fits_in_memory(len(kept), *image.shape[:2]):  # longer than its header said: JPEG after all
                    encoded, kept, in_memory = [_jpeg(kept_scene.image) for kept_scene in kept], [], False
            elif keep:
                encoded.append(_jpeg(image))
            yield scene
        if not places:
            raise ValueError(f"the source video {shots.video} decoded no frames")
        if not keep:  # the driver ran past the video after all (its frame count was short): read it again
            if in_memory:
                kept = [self._frame(image, points) for image, points in zip(iter_frames(shots.video), places)]
            else:
                encoded = [_jpeg(image) for image in iter_frames(shots.video)]
        first = next((points for points in places if points is not None), None)
        if in_memory:  # a frame before the first face takes the first face's place
            kept = [scene if scene.landmarks is not None or first is None else self._frame(scene.image, first)
                    for scene in kept]
            for index in _back_and_forth(len(kept)):
                yield kept[index]
        for index in _back_and_forth(len(encoded)):
            image = cv2.cvtColor(cv2.imdecode(np.frombuffer(encoded[index], np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
            yield self._frame(image, places[index] if places[index] is not None else first)


def _fits_in_memory(frames: int, height: int, width: int) -> bool:
    """Whether ``frames`` scene frames of ``height`` x ``width`` pixels, with their layers, fit ``KEPT_BYTES``."""
    return frames * height * width * KEPT_PIXEL_BYTES <= KEPT_BYTES


def _back_and_forth(count: int) -> Iterator[int]:
    """The frame indices of a video played back from its last frame, then forth again, for ever (each end shown
    once, not twice)."""
    order = list(range(count - 2, 0, -1)) + list(range(0, count - 1))
    while True:
        yield from order or [0]
        order = list(range(count - 1, 0, -1)) + list(range(0, count - 1))


def _jpeg(image: np.ndarray) -> bytes:
    """A scene frame (H, W, 3) uint8 RGB kept for the way back: JPEG at ``JPEG_QUALITY`` (b"" where it fails)."""
    ok, encoded = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    return encoded.tobytes() if ok else b""


# ---- the engine's finishers: each frame's paste-back, run behind the network (lsr.core.overlap) --------


def paste_into_scene(frame, scene, stats):
    """A re-enacted frame (``lsr.core.engine.ReenactedFrame``, its image the scene frame) with the synthesis composited into that scene frame at the frame's
    target (``SceneFrame.composite``); a scene frame whose face was not found stays as it is."""
    if scene.landmarks is not None:
        started = time.perf_counter()
        frame.image = scene.composite(frame.landmarks, frame.synthesis)
        stats.add("paste_back", time.perf_counter() - started)
    return frame


def paste_into_driver(frame, points: np.ndarray, matrix: np.ndarray, stats):
    """A re-enacted frame (its image the synthesis) with the synthesis composited into its driver frame
    (``landmarks.scene.compositing.composite_face``: the driver's head and scene around the face; the head barely moves,
    its target being the driver's own face, so no person matte is made)."""
    from landmarks.scene.compositing import composite_face, place_in_frame

    started = time.perf_counter()
    frame.image = composite_face(frame.driver_frame, points, place_in_frame(frame.landmarks, matrix), frame.synthesis,
                                 matrix).frame
    stats.add("paste_back", time.perf_counter() - started)
    return frame
