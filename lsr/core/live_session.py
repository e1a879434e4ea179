"""Live re-enactment: one camera frame in, one re-enacted frame out, for as long as a stream lasts (``lsr app``'s
live tab).

A ``LiveSession`` holds what a stream needs between frames and nothing else: the encoded subject (its own, so
several streams and batch runs can share one backend), a landmark tracker (detection only when the face is lost),
One-Euro smoothing at the frames' real rate, the driver's first face (relative motion is measured from it) and the
last good output. Per frame:

    camera frame -> track 68 points -> smooth -> crop -> retarget onto the subject's anchor shot
      -> synthesise (backend; inside an open mouth, the camera frame's) -> composite into the anchor's scene (or
      the face crop) -> mark as synthetic

A frame without a face gives the last good output again with a note, never an error, so a stream survives a
hand in front of the camera. ``recentre()`` makes the next face the neutral one (the driver sat down again).
``render(target)`` draws given landmarks instead of a camera frame's (the app's expression sliders).
Torch-free: it runs on the torch pipeline and on the ONNX runtime alike.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from landmarks.parts.eyes.eye_bank import EyeChoice
from landmarks.parts.mouth.mouth_bank import MouthChoice
from landmarks.parts.eyes.driver_lids import DriverEyes, cut_driver_eyes
from landmarks.motion.retarget_mesh import DriverReference
from landmarks.parts.mouth.interior import DriverMouth, cut_driver_mouth
from lsr.core.engine import ReenactorBase
from lsr.core.subject import Subject
from lsr.core.finish import DriverGaze
from lsr.core.provenance import draw_watermark

MIN_FPS, MAX_FPS = 2.0, 60.0  # the One-Euro filter's rate follows the frames' spacing, within these bounds
NO_FACE_NOTE = "no face in the camera: showing the last frame"


@dataclasses.dataclass
class LiveFrame:
    """One step of a live stream."""

    image: np.ndarray
    """(H, W, 3) uint8 RGB: what to show (the anchor's scene, or the face crop)."""
    face: bool
    """Whether this camera frame had a face (False: ``image`` is the last good output, or the plain scene)."""
    layout: np.ndarray | None
    """The generator's layout for this frame (C, S, S) float32, when asked for and the model has one."""
    landmark_image: np.ndarray | None
    """(S, S, 3) uint8: the landmark image the generator received."""
    seconds: float
    """Processing time of this frame (tracking to composite)."""
    note: str = ""
    index: int = 0
    """Which camera frame of the stream this is (1, 2, ...: ``LiveSession.frames`` when it was prepared)."""


class LiveSession:
    """A camera stream driving one subject (module docstring).

    reenactor: a ``ReenactorBase`` (torch or ONNX); only its backend, detector and sizes are used, never its
    ``subject``. subject: the encoded subject (``reenactor.encode_subject``'s result). paste_back: composite into
    the anchor shot's frame (the source's own scene) instead of showing the face crop.
    """

    def __init__(self, reenactor: ReenactorBase, subject: Subject, *, paste_back: bool = True, smooth: bool = True,
                 with_layout: bool = False, watermark: bool = True, detector=None) -> None:
        from landmarks.motion.smooth import OneEuroFilter, driving_cutoffs
        from landmarks.detect.registry import make_tracker
        from lsr.core.scene import SourceScene

        self.reenactor, self.subject = reenactor, subject
        self.with_layout = with_layout and reenactor.backend.layout_kind != "none"
        self.watermark = watermark
        self.tracker = make_tracker(detector if detector is not None else reenactor.detector, live=True)
        self.one_euro = OneEuroFilter(25.0, driving_cutoffs()) if smooth else None
        self.scene = next(SourceScene(subject.shots, reenactor.crop_size)) if paste_back else None
        self.reference = DriverReference()
        self.gazes = DriverGaze(subject.anchor_gaze) if reenactor.eyes != "blend" else None  # warped or drawn eyes' gaze
        self.tracks = reenactor.part_tracks(subject, relative=True)  # the subject's own parts (landmarks.parts)
        self.last: LiveFrame | None = None
        self._last_time: float | None = None
        self.frames = self.faces = 0

    def recentre(self) -> None:
        """The next face becomes the driver's neutral face (relative motion is measured from it)."""
        self.reference.reset()
        if self.gazes is not None:
            self.gazes.reference = None

    def _mark(self, image: np.ndarray) -> np.ndarray:
        return draw_watermark(image) if self.watermark else image

    def still(self, note: str, started: float | None = None) -> LiveFrame:
        """What a frame without a face shows: the last good output (else the plain scene), with ``note``."""
        started = time.perf_counter() if started is None else started
        if self.one_euro is not None:
            self.one_euro.reset()  # never smooth across a gap
        if self.tracks is not None:
            self.tracks.reset()  # the parts are chosen afresh after a gap
        if self.last is not None:
            shown = self.last.image
        else:
            shots = self.subject.shots
            shown = self._mark(self.scene.image if self.scene is not None else shots.frames[shots.anchor])
        return LiveFrame(shown, False, None, None, time.perf_counter() - started, note, self.frames)

    def step(self, frame: np.ndarray, timestamp: float | None = None) -> LiveFrame:
        """One camera frame (H, W, 3) uint8 RGB -> the re-enacted frame. timestamp: capture time in seconds (default:
        now), which sets the smoothing's rate. ``prepare`` then ``finish``, in one go."""
        prepared = self.prepare(frame, timestamp)
        return prepared if isinstance(prepared, LiveFrame) else self.finish(prepared)

    def prepare(self, frame: np.ndarray, timestamp: float | None = None) -> Prepared | LiveFrame:
        """The first half of a step: track, smooth, retarget, warp the shots (the network's inputs). Returns a
        ``LiveFrame`` at once when the frame has no face. ``finish`` may run on another thread while the next frame
        is prepared (one stream: prepare calls in order, finish calls in order)."""
        from landmarks.align import crop_transform, transform_landmarks
        from landmarks.motion.retarget_points import retarget_driving

        started = time.perf_counter()
        now = started if timestamp is None else float(timestamp)
        self.frames += 1
        points = self.tracker.update(np.ascontiguousarray(frame))
        if points is None or not np.isfinite(points).all():
            self._last_time = None
            return self.still(NO_FACE_NOTE, started)
        gaps, _ = self.reference.lids(points)  # as detected; a camera has nothing ahead
        gaze = None if self.gazes is None else self.gazes(frame, points, getattr(self.tracker, "irises", None))
        mouth = cut_driver_mouth(frame, points) if self.reenactor.mouth_interior == "driver" else None
        eyes = cut_driver_eyes(frame, points, gaps) if self.reenactor.lids == "driver" else None
        if self.one_euro is not None:
            if self._last_time is not None and now > self._last_time:
                self.one_euro.fps = float(np.clip(1.0 / (now - self._last_time), MIN_FPS, MAX_FPS))
            points = self.one_euro(points)
        self._last_time = now
        crop_landmarks = transform_landmarks(points, crop_transform(points, self.reenactor.crop_size))
        self.reference.start(crop_landmarks)
        return self._inputs(retarget_driving(crop_landmarks, self.reference.landmarks,
                                             self.subject.reference_landmarks, gaps), started, gaze, mouth, eyes)

    def _inputs(self, target: np.ndarray, started: float, gaze: np.ndarray | None = None,
                driver_mouth: DriverMouth | None = None, driver_eyes: DriverEyes | None = None) -> Prepared:
        landmark_image, inputs = self.reenactor.network_inputs(target, subject=self.subject, gaze=gaze)
        choices = (None, None) if self.tracks is None else self.tracks(target, gaze)  # in order: prepare's thread
        return Prepared(np.asarray(target, np.float64), landmark_image, inputs, time.perf_counter() - started,
                        self.frames, gaze, driver_mouth, driver_eyes, *choices)

    def render(self, target: np.ndarray) -> LiveFrame:
        """Target landmarks (68, 2) in the anchor's crop pixels (e.g. the anchor's own, edited by
        ``landmarks.shape.edit``) -> the frame, as a camera frame with that face would give it."""
        started = time.perf_counter()
        self.frames += 1
        return self.finish(self._inputs(target, started))

    def in_scene(self, target: np.ndarray) -> np.ndarray:
        """Crop-pixel landmarks (68, 2) -> the scene's frame pixels (the face crop's own when not pasting back)."""
        from landmarks.scene.compositing import place_in_frame

        return np.asarray(target, np.float64) if self.scene is None else place_in_frame(target, self.scene.matrix)

    def finish(self, prepared: Prepared) -> LiveFrame:
        """The second half: the network, then the composite into the scene and the synthetic mark."""
        started = time.perf_counter()
        synthesis, layout = self.reenactor.synthesize_inputs(prepared.inputs, self.with_layout, prepared.target,
                                                             self.subject, prepared.gaze, prepared.driver_mouth,
                                                             prepared.driver_eyes, prepared.eye_choice,
                                                             prepared.mouth_choice)
        image = synthesis if self.scene is None else self.scene.composite(prepared.target, synthesis)
        self.faces += 1
        self.last = LiveFrame(self._mark(image), True, layout, prepared.landmark_image,
                              prepared.seconds + time.perf_counter() - started, index=prepared.index)
        return self.last


@dataclasses.dataclass
class Prepared:
    """A frame's network inputs, between ``LiveSession.prepare`` and ``LiveSession.finish``."""

    target: np.ndarray
    """(68, 2) target landmarks in crop pixels."""
    landmark_image: np.ndarray
    inputs: dict[str, np.ndarray]
    """``ReenactorBase.network_inputs``."""
    seconds: float
    index: int
    gaze: np.ndarray | None = None
    """(2, 2) where the target looks (drawn eyes, ``lsr.core.finish.DriverGaze``), or None."""
    driver_mouth: DriverMouth | None = None
    """The camera frame's open mouth (``landmarks.parts.mouth.interior``), or None."""
    driver_eyes: DriverEyes | None = None
    """The camera frame's shut eyes (``landmarks.parts.eyes.driver_lids``), or None."""
    eye_choice: EyeChoice | None = None
    """The subject's own eyes from its bank (``landmarks.parts.eyes.eye_bank``), or None."""
    mouth_choice: MouthChoice | None = None
    """The subject's own mouth from its bank (``landmarks.parts.mouth.mouth_bank``), or None."""
