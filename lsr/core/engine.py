"""The re-enactment frame loop shared by both runtimes (torch-free: numpy, OpenCV, onnxruntime face models via ``landmarks``).

``ReenactorBase`` does everything around the two networks: subject shots -> K crops and landmark images,
the driver -> tracked, smoothed, retargeted, cropped landmarks -> landmark images, the synthesised crop ->
pasted back into the driver frame, face-less frames passed through. A runtime supplies only a
``SynthesisBackend`` (two numpy functions): ``lsr.pipeline.Reenactor`` runs them with torch,
``deploy.runtime.OnnxReenactor`` with onnxruntime. Same code, same numbers, one API.

Why here: the image operations (crop, rasterise, paste-back, retarget, One-Euro) live in ``landmarks``; this
loop only composes them, torch-free, for both runtimes.

Coordinates: the synthesis happens in a training-framed crop of side S (thesis §4.4), one crop transform per
driver frame from its (smoothed) landmarks, so pasting back uses the exact inverse of the crop warp. Relative mode
(default when source and driver differ) moves the source's own face by the driver's motion since its first face
(``landmarks.motion.retarget_mesh.retarget_face``), in crop coordinates; absolute mode uses the driver's crop landmarks.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import os
import time
from collections.abc import Callable, Iterator
from typing import Literal

import numpy as np

from lsr.core.inputs import (
    DriverInfo,
    LandmarkSpace,
    SourceInput,
    SubjectShots,
    describe_driver,
    load_subject_shots,
    read_landmark_array,
    resize_shots,
    same_input,
    scale_points,
    source_key,
    track_driver,
)
from landmarks.parts.eyes.driver_lids import DriverEyes, cut_driver_eyes
from landmarks.exceptions import InputFileError, NoFaceError
from landmarks.parts.mouth.opening_gain import EXPRESSION_GAIN, GAIN_RANGE
from landmarks.parts.eyes.eye_bank import EyeChoice
from landmarks.parts.mouth.mouth_bank import MouthChoice
from landmarks.parts.eyes.lids import LOOK_AHEAD
from landmarks.motion.retarget_mesh import RETARGET_MODES, DriverReference
from landmarks.parts.mouth.interior import DriverMouth, cut_driver_mouth
from lsr.core.backend import SynthesisBackend
from lsr.core.overlap import finish_behind, prefetch
from lsr.core.part_tracks import PartTracks, part_tracks
from lsr.core.scene import paste_into_driver, paste_into_scene
from lsr.core.subject import Subject
from lsr.core.images import from_network, square_resize, to_network
from lsr.core.finish import (BANK_PARTS, BANKS, EYES, LIDS, MOUTH_INTERIORS, MOUTHS, Choice, DriverGaze, draws_mouth,
                             finish_parts)

Mode = Literal["auto", "relative", "absolute"]
Scene = Literal["source", "driver"]
"""What ``paste_back`` composites into: the source's own frames (its anchor shot or its video) or the driver's."""
STAGES = ("decode", "landmarks", "subject_encoding", "warps", "synthesis", "paste_back")


@dataclasses.dataclass
class ReenactedFrame:
    """One output frame. ``image`` is the composited scene frame (paste-back) or the (C, C, 3) synthesis."""

    index: int
    image: np.ndarray
    """(H, W, 3) uint8 RGB: what goes into the output video."""
    has_face: bool
    """False: the driver frame had no face and ``image`` is it, passed through unchanged."""
    driver_frame: np.ndarray | None
    """(H, W, 3) uint8 driver frame (None for raw landmark drivers)."""
    landmark_image: np.ndarray | None
    """(S, S, 3) uint8: the rasterised target landmarks fed to the generator (None without a face)."""
    synthesis: np.ndarray | None
    """(S, S, 3) uint8: the synthesised crop (None without a face)."""
    layout: np.ndarray | None
    """(C_l, S, S) float32: the generator's layout (only when asked for and the variant has one)."""
    landmarks: np.ndarray | None = None
    """(68, 2) float64: the target landmarks in crop pixels (after retargeting; None without a face)."""
    gaze: np.ndarray | None = None
    """(2, 2) float64: the target's gaze (``landmarks.parts.eyes.iris.gaze_offsets``), when the eyes are drawn."""
    driver_mouth: DriverMouth | None = None
    """The driver frame's open mouth, whose interior the synthesis takes (``mouth_interior`` "driver")."""
    driver_eyes: DriverEyes | None = None
    """The driver frame's shut eyes, which the synthesis takes (``lids`` "driver")."""
    eye_choice: EyeChoice | None = None
    mouth_choice: MouthChoice | None = None
    """The subject's own eyes and mouth the frame takes from its part banks (``bank``; ``landmarks.parts``)."""


@dataclasses.dataclass
class ReenactStats:
    """Counts and per-stage seconds of the last ``reenact`` call (plus the subject encoding)."""

    frames: int = 0
    no_face: int = 0
    seconds: dict[str, float] = dataclasses.field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))

    def add(self, stage: str, seconds: float) -> None:
        self.seconds[stage] = self.seconds.get(stage, 0.0) + seconds

    def merge(self, other: ReenactStats) -> None:
        self.frames += other.frames
        self.no_face += other.no_face
        for stage, seconds in other.seconds.items():
            self.add(stage, seconds)


@dataclasses.dataclass
class _Prepared:
    """A face frame ready for the network: the frame so far, the network's inputs, its paste-back (or None)."""

    frame: ReenactedFrame
    inputs: dict[str, np.ndarray]
    finish: Callable[[ReenactedFrame], ReenactedFrame] | None


class ReenactorBase:
    """Subject encoding once, then one synthesised frame per driver frame (thesis §4.3). See the module docstring.

    backend: a ``SynthesisBackend``. detector: "mesh" | "hog" | "cnn" or a ``landmarks.detect.face_detector.FaceDetector``.
    """

    def __init__(self, backend: SynthesisBackend, *, detector: str | object = "mesh", crop_size: int | None = None) -> None:
        self.backend = backend
        self.crop_size = crop_size or default_crop_size(backend)
        self._detector_spec = detector
        self._detector = None
        self.reference_warp: str = "mesh"
        """How a warp-guided model's references are warped when meshes are at hand: "mesh" (piecewise affine over
        the face mesh, TPS outside) or "tps" (the 68-point TPS everywhere)."""
        self._mouth: str = "drawn" if draws_mouth(backend) else "nearest"
        self._expression_gain: float = EXPRESSION_GAIN
        self.subject: Subject | None = None
        self.last_stats = ReenactStats()

    @property
    def mouth(self) -> str:
        """A warp-guided model's mouth: "drawn" (the nearest warped shot's where the target opens it wider than the
        shots, ``landmarks.parts.mouth.nearest_mouth``, then redrawn by the model's mouth generator, ``lsr.core.finish``; the
        default when the model has one), "nearest" (without the redrawing; the default otherwise) or "blend" (the
        network's blend alone)."""
        return self._mouth

    @mouth.setter
    def mouth(self, mouth: str) -> None:
        if mouth not in MOUTHS:
            raise ValueError(f"mouth must be one of {MOUTHS}, got {mouth!r}")
        if mouth == "drawn" and not draws_mouth(self.backend):
            raise InputFileError("--mouth drawn needs a model with a mouth generator (a weights folder with mouth/, or an "
                              "ONNX bundle with mouth_generator.onnx); use --mouth nearest")
        self._mouth = mouth

    @property
    def expression_gain(self) -> float:
        """How many times, at most, mesh-warped references carry a shot's mouth toward a target that opens it wider
        (``landmarks.parts.mouth.opening_gain``; 1 = exactly onto the target's points: the lips beyond the shots land where
        they should, but read as less open; MODEL_CARD.md)."""
        return self._expression_gain

    @expression_gain.setter
    def expression_gain(self, gain: float) -> None:
        low, high = GAIN_RANGE
        if not low <= float(gain) <= high:
            raise ValueError(f"expression_gain must be in [{low:g}, {high:g}], got {gain!r}")
        self._expression_gain = float(gain)

    mouth_interior = Choice(MOUTH_INTERIORS, "driver", "Inside an open mouth (``lsr.core.finish.MOUTH_INTERIORS``).")
    lids = Choice(LIDS, "drawn", "Where the target shuts its eyes (``lsr.core.finish.LIDS``).")
    eyes = Choice(EYES, "warped", "The eyes' irises (``lsr.core.finish.EYES``).")
    bank = Choice(BANKS, "all", "Which of the subject's frames its own parts come from (``lsr.core.finish.BANKS``).")
    bank_parts = Choice(BANK_PARTS, "eyes", "Which parts come from the banks (``lsr.core.finish.BANK_PARTS``).")

    @property
    def resolution(self) -> int:
        """Side of the network's input (the model resolution)."""
        return int(self.backend.resolution)

    @property
    def warp_references(self) -> int:
        return int(getattr(self.backend, "warp_references", 0))

    @property
    def crop_size(self) -> int:
        """Side of the face crop the shots, the target landmarks and the output live in (>= ``resolution``)."""
        return self._crop_size

    @crop_size.setter
    def crop_size(self, size: int) -> None:
        size = int(size)
        fixed = getattr(self.backend, "crop_size", None)  # an ONNX graph takes its references at one side
        if size < self.resolution or (size != self.resolution and not self.warp_references) or (fixed and size != fixed):
            raise InputFileError(f"crop size {size} must equal the model resolution {self.resolution} "
                                 f"(or be larger, for a warp-guided torch model; {fixed or 'any'} for this backend)")
        self._crop_size = size
        self.subject = None  # shots are cropped at this side: encode again

    @property
    def detector(self):
        if self._detector is None:  # face models load on first use, not at construction
            from landmarks.detect.registry import make_detector

            spec = self._detector_spec
            self._detector = make_detector(spec) if isinstance(spec, str) else spec
        return self._detector

    # ---- subject ---------------------------------------------------------------------------------------
    def encode_subject(self, source: SourceInput | SubjectShots, k: int | None = None, face_index: int = 0,
                       anchor: int | None = None, cache: bool = True) -> Subject:
        """Load the K shots of ``source`` (images, a folder, a video or arrays; see ``lsr.core.inputs``), encode and cache.

        k: shots to average (1..32); None = min(8, usable shots). face_index: which face of a frame with several
        (0 = the largest). anchor: which shot is the neutral face and the scene (None: the most frontal one with
        a closed mouth). Returns the cached ``Subject`` (``subject.shots.notes``: what the loader skipped or chose).
        cache: False returns the subject without replacing the cached one (a live stream's own, ``lsr.core.live_session``,
        while batch runs use the cache).
        """
        started = time.perf_counter()
        shots = source if isinstance(source, SubjectShots) else load_subject_shots(
            source, self.crop_size, k=k, detector=self.detector, face_index=face_index, anchor=anchor
        )
        if not cache:
            return self._encode(shots, source_key(source))
        self.subject = self._encode(shots, source_key(source))
        self.last_stats = ReenactStats()
        self.last_stats.add("subject_encoding", time.perf_counter() - started)
        return self.subject

    def _encode(self, shots: SubjectShots, source_key: str | None) -> Subject:
        from landmarks.shape.raster import draw_landmarks

        size, crop = self.resolution, self.crop_size
        if shots.frames.ndim != 4 or shots.frames.shape[1:] != (crop, crop, 3):
            raise InputFileError(f"subject shots must be (K, {crop}, {crop}, 3) uint8 crops, got {shots.frames.shape}")
        small = resize_shots(shots, size)
        landmark_images = np.stack([draw_landmarks(p, size) for p in small.landmarks])  # (K, S, S, 3)
        layout_latent, style_latent = self.backend.encode_subject(
            to_network(small.frames)[None], to_network(landmark_images)[None]  # (1, K, 3, S, S) each
        )
        return Subject(shots, np.asarray(layout_latent, np.float32), np.asarray(style_latent, np.float32), source_key)

    # ---- frames ----------------------------------------------------------------------------------------
    def synthesize_crop(
        self, crop_landmarks: np.ndarray, with_layout: bool = False, latents: tuple[np.ndarray, np.ndarray] | None = None,
        subject: Subject | None = None, crop_mesh: np.ndarray | None = None, gaze: np.ndarray | None = None,
        driver_mouth: DriverMouth | None = None, driver_eyes: DriverEyes | None = None,
        eye_choice: EyeChoice | None = None, mouth_choice: MouthChoice | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Target landmarks (68, 2) in crop pixels -> (synthesis (C, C, 3) uint8, landmark image (S, S, 3) uint8, layout).

        C is ``crop_size``, S the model resolution. A warp-guided model also gets the nearest shots warped onto the
        target at C and blends them with its own image at C: over the face mesh when ``reference_warp`` is "mesh"
        and both the target (``crop_mesh``, (468, 3) crop pixels) and the shots have meshes
        (``landmarks.warp.piecewise_affine.warp_references_mesh``), else by the 68-point TPS (``landmarks.warp.tps.warp_references``).
        latents: (layout_latent, style_latent), (1, D) each, in place of the subject's (e.g. one shot's alone).
        subject: an encoded subject other than the cached one (a live stream's own, ``lsr.core.live_session``).
        gaze: the target's (2, 2) ``landmarks.parts.eyes.iris.gaze_offsets``, for ``eyes`` "drawn" or "warped".
        driver_mouth: the driver frame's mouth (``landmarks.parts.mouth.interior.cut_driver_mouth``), for
        ``mouth_interior`` "driver". driver_eyes: the driver frame's shut eyes (``landmarks.parts.eyes.driver_lids.cut_driver_eyes``),
        for ``lids`` "driver". eye_choice, mouth_choice: the subject's own parts from its banks (``part_tracks``)."""
        landmark_image, inputs = self.network_inputs(crop_landmarks, latents, subject, crop_mesh, gaze)
        image, layout = self.synthesize_inputs(inputs, with_layout, crop_landmarks, subject, gaze, driver_mouth,
                                               driver_eyes, eye_choice, mouth_choice)
        return image, landmark_image, layout

    def synthesize_inputs(self, inputs: dict[str, np.ndarray], with_layout: bool = False,
                          crop_landmarks: np.ndarray | None = None, subject: Subject | None = None,
                          gaze: np.ndarray | None = None, driver_mouth: DriverMouth | None = None,
                          driver_eyes: DriverEyes | None = None, eye_choice: EyeChoice | None = None,
                          mouth_choice: MouthChoice | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """``network_inputs``' dict -> (synthesis (C, C, 3) uint8, layout (C_l, S, S) float32 or None). ``crop_landmarks``
        given, ``mouth`` "nearest" or "drawn": the mouth of ``subject``'s nearest warped shot as
        ``landmarks.parts.mouth.nearest_mouth`` says; "drawn": then redrawn by the mouth generator (``lsr.core.finish``); and with
        a ``gaze``, the eyes as ``eyes`` says; with a ``driver_mouth``, the interior as ``mouth_interior`` says; the
        shut lids as ``lids`` says (the driver's with ``driver_eyes``, else drawn); with an ``eye_choice`` and a
        ``mouth_choice``, the subject's own eyes and mouth from its part banks over all that (``landmarks.parts``)."""
        image, layout = self.backend.synthesize(
            inputs["landmark_image"], inputs["layout_latent"], inputs["style_latent"], with_layout,
            *((inputs["references"], inputs["reference_masks"]) if "references" in inputs else ()),
        )
        image = from_network(image[0])
        if crop_landmarks is not None:
            image = finish_parts(image, self, inputs, crop_landmarks, subject or self._require_subject(), gaze,
                                 driver_mouth, driver_eyes, eye_choice, mouth_choice)
        return image, None if layout is None else np.asarray(layout[0], np.float32)

    def network_inputs(self, crop_landmarks: np.ndarray, latents: tuple[np.ndarray, np.ndarray] | None = None,
                       subject: Subject | None = None, crop_mesh: np.ndarray | None = None,
                       gaze: np.ndarray | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """What the frame network gets for target landmarks (68, 2) in crop pixels: (landmark image (S, S, 3) uint8,
        the named inputs of the frame graph: landmark_image (1, 3, S, S), layout_latent and style_latent (1, D), and
        for a warp-guided model references (1, N, 3, C, C) and reference_masks (1, N, 1, C, C)). With ``eyes``
        "warped", the references' irises move to ``gaze`` (2, 2) (``landmarks.parts.eyes.iris_shift``)."""
        from landmarks.shape.raster import draw_landmarks

        subject = subject if subject is not None else self._require_subject()
        landmark_image = draw_landmarks(scale_points(crop_landmarks, self.resolution / self.crop_size), self.resolution)
        layout_latent, style_latent = latents if latents is not None else (subject.layout_latent, subject.style_latent)
        warped = None
        if self.warp_references:
            shots = subject.shots
            irises = subject.shot_irises if self.eyes == "warped" else None
            if self.reference_warp == "mesh" and crop_mesh is not None and shots.meshes is not None:
                from landmarks.warp.piecewise_affine import warp_references_mesh

                warped, valid, _ = warp_references_mesh(shots.frames, shots.meshes, shots.landmarks, crop_mesh,
                                                        crop_landmarks, self.warp_references, irises=irises, gaze=gaze,
                                                        expression_gain=self.expression_gain)
            else:
                from landmarks.warp.tps import warp_references

                warped, valid, _ = warp_references(shots.frames, shots.landmarks, crop_landmarks, self.warp_references,
                                                   irises=irises, gaze=gaze)
        inputs = {"landmark_image": to_network(landmark_image)[None], "layout_latent": layout_latent,
                  "style_latent": style_latent}
        if warped is not None:
            inputs["references"], inputs["reference_masks"] = to_network(warped)[None], valid[None, :, None]
        return landmark_image, inputs

    def reenact(
        self,
        driver: str | os.PathLike | np.ndarray,
        *,
        mode: Mode = "auto",
        smooth: bool = True,
        paste_back: bool = False,
        scene: Scene = "source",
        with_layout: bool = False,
        landmark_space: LandmarkSpace | None = None,
        landmark_size: int | None = None,
        progress: bool = False,
        retarget: str = "2d",
    ) -> Iterator[ReenactedFrame]:
        """Stream re-enacted frames, one per driver frame, in order (a generator: nothing is held but one frame).

        driver: a video, a folder of images, a .npy/.json landmark file or an (N, 68, 2) array (``lsr.core.inputs``).
        mode: "relative" (driver motion on the source's face shape), "absolute" (the driver's landmarks), or
            "auto": absolute when the driver is the source file itself, else relative.
        smooth: One-Euro smoothing of the driver landmarks (and so of the crop framing).
        paste_back: composite the face into full frames (``landmarks.scene.compositing.composite_face``: background and body
            stay, hair follows the head rigidly); otherwise the output is the (C, C) synthesis.
        scene: what paste_back composites into: "source", the source's scene (``lsr.core.scene``: the
            anchor shot's frame, or the source video's frames back and forth), at its size; "driver", the driver's
            frames (dubbing; a face swap across people; raw landmark drivers have none: the crop).
        retarget: how relative motion moves the source (``landmarks.motion.retarget_mesh.retarget_face``): "2d", the 68
            points' relative motion; "3d", the source's own face mesh turned by the driver's head rotation, the
            expression moved in the canonical head frame (needs meshes of both faces: the mesh detector, a video or
            image driver; elsewhere "2d").
        Face-less driver frames pass through (the scene frame, the driver frame, or its centre square resized)
        and are counted; a driver without a face in any frame raises ``NoFaceError`` after its last frame.
        """
        if mode not in ("auto", "relative", "absolute"):
            raise InputFileError(f"mode must be 'auto', 'relative' or 'absolute', got {mode!r}")
        if scene not in ("source", "driver"):
            raise InputFileError(f"scene must be 'source' or 'driver', got {scene!r}")
        if retarget not in RETARGET_MODES:
            raise InputFileError(f"retarget must be one of {', '.join(RETARGET_MODES)}, got {retarget!r}")
        subject = self._require_subject()
        info = describe_driver(driver)
        relative = mode == "relative" or (mode == "auto" and not same_input(subject.source, driver))
        with_layout = with_layout and self.backend.layout_kind != "none"
        self.last_stats = stats = ReenactStats()
        into_source = paste_back and scene == "source" and not same_input(subject.source, driver)
        tracks = self.part_tracks(subject, relative)  # first: a video source's bank pass tracks its frames once
        scenes = None
        if into_source:
            from lsr.core.scene import SourceScene

            tracked_by, track = subject.video_track or (None, None)
            scenes = SourceScene(subject.shots, self.crop_size, detector=self.detector, fps=info.fps, smooth=smooth,
                                 track=track if tracked_by is self.detector else None, frames_needed=info.frames or None)
        if info.kind == "landmarks":
            read_landmark_array(driver, landmark_space=landmark_space, landmark_size=landmark_size)  # fail early
            frames = self._landmark_driver(driver, info, relative, smooth, landmark_space, landmark_size, stats, scenes)
        else:
            frames = self._frame_driver(info, relative, smooth, paste_back and not into_source, stats, scenes, retarget)
        # three overlapping stages: the frames prepared (decoded, tracked, retargeted, the shots warped) on a thread
        # ahead, the network here, each frame's paste-back on a worker behind (lsr.core.overlap)
        frames = finish_behind(self._synthesized(prefetch(frames), with_layout, stats, tracks))
        return _with_progress(frames, info.frames) if progress else frames  # checks above run now; frames lazily

    __call__ = reenact

    def _uses_mesh_references(self) -> bool:
        return bool(self.warp_references) and self.reference_warp == "mesh"

    def _crop_mesh(self, mesh: np.ndarray | None, raw_points: np.ndarray, points: np.ndarray,
                   matrix: np.ndarray, retarget: str = "2d") -> np.ndarray | None:
        """The driver's (468, 3) mesh in crop pixels, moved with the 68 points' smoothing, for the references' mesh
        warp and the 3D retargeting; None when neither needs it, when the shots have no meshes, or when it is not at
        hand."""
        if (not (self._uses_mesh_references() or retarget == "3d") or mesh is None
                or self._require_subject().shots.meshes is None or not np.isfinite(mesh).all()):
            return None
        from landmarks.align import transform_mesh
        from landmarks.motion.retarget_mesh import spreading_weights

        mesh = np.asarray(mesh, np.float64).copy()
        # the One-Euro filter moved the 68 points: carry that shift onto the vertices near them
        mesh[:, :2] += spreading_weights() @ (np.asarray(points, np.float64) - raw_points)
        return transform_mesh(mesh, matrix)

    def _source_face(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The anchor shot's face that relative motion moves: (68, 2) crop landmarks, (468, 3) mesh or None."""
        subject = self._require_subject()
        return subject.reference_landmarks, subject.reference_mesh

    def _drive(self, crop_landmarks: np.ndarray, crop_mesh: np.ndarray | None, reference: DriverReference,
               lids: tuple[np.ndarray, np.ndarray], relative: bool, source: tuple[np.ndarray, np.ndarray | None],
               retarget: str = "2d") -> tuple[np.ndarray, np.ndarray | None]:
        """What the source is driven with: (68 points, mesh for the references or None). Relative motion: the
        driver's since its first face (``reference``; ``lids``: its reference lid gaps, ``DriverReference.lids``)
        on the source's face (``landmarks.motion.retarget_mesh.retarget_face`` in mode ``retarget``; FOMM / LivePortrait
        style, the mouth exactly as open as the driver's); absolute: the driver's own. source: the subject's face
        that relative motion moves (``_source_face``), read once per stream."""
        from landmarks.motion.retarget_mesh import retarget_face

        if not relative:
            return crop_landmarks, crop_mesh if self._uses_mesh_references() else None
        source_landmarks, source_mesh = source
        gaps, mesh_gaps = lids
        meshes = crop_mesh is not None and reference.mesh is not None and source_mesh is not None
        landmarks, moved = retarget_face(crop_landmarks[None], reference.landmarks, source_landmarks,
                                         crop_mesh[None] if meshes else None, reference.mesh if meshes else None,
                                         source_mesh if meshes else None, retarget, gaps, mesh_gaps)
        mesh = moved[0] if moved is not None and np.isfinite(moved[0]).all() else None
        return landmarks[0], mesh if self._uses_mesh_references() else None

    def _prepare(self, index: int, driver_frame: np.ndarray | None, target: np.ndarray, stats: ReenactStats,
                 target_mesh: np.ndarray | None = None, finish: Callable | None = None, image: np.ndarray | None = None,
                 gaze: np.ndarray | None = None, driver_mouth: DriverMouth | None = None,
                 driver_eyes: DriverEyes | None = None) -> _Prepared:
        """A face frame made ready for the network (on the preparing thread): the target's landmark image and, for a
        warp-guided model, its nearest shots warped onto it. finish: the frame's paste-back (run behind the loop);
        image: the frame's picture until then (None: the synthesis)."""
        started = time.perf_counter()
        landmark_image, inputs = self.network_inputs(target, crop_mesh=target_mesh, gaze=gaze)
        stats.add("warps", time.perf_counter() - started)
        return _Prepared(ReenactedFrame(index, image, True, driver_frame, landmark_image, None, None, target, gaze,
                                        driver_mouth, driver_eyes), inputs, finish)

    def part_tracks(self, subject: Subject, relative: bool) -> PartTracks | None:
        """``lsr.core.part_tracks.part_tracks`` as this reenactor's ``bank`` and ``bank_parts`` say."""
        return part_tracks(subject, self.bank, self.bank_parts, self.detector, relative)

    def _synthesized(self, items, with_layout: bool, stats: ReenactStats, tracks: PartTracks | None = None
                     ) -> Iterator[ReenactedFrame | Callable]:
        """The network on each prepared frame, here (the items come from the preparing thread); the frames, or their
        finishers (``lsr.core.overlap.finish_behind``), in order. decode = what the network waited for. tracks:
        the bank parts, chosen here in order."""
        with contextlib.closing(items):  # stopped early: the preparing threads stop too
            while True:
                started = time.perf_counter()
                item = next(items, None)
                stats.add("decode", time.perf_counter() - started)
                if item is None:
                    return
                if isinstance(item, _Prepared):
                    started, frame = time.perf_counter(), item.frame
                    if tracks is not None:
                        frame.eye_choice, frame.mouth_choice = tracks(frame.landmarks, frame.gaze)
                    frame.synthesis, frame.layout = self.synthesize_inputs(item.inputs, with_layout, frame.landmarks,
                                                                           gaze=frame.gaze,
                                                                           driver_mouth=frame.driver_mouth,
                                                                           driver_eyes=frame.driver_eyes,
                                                                           eye_choice=frame.eye_choice,
                                                                           mouth_choice=frame.mouth_choice)
                    stats.add("synthesis", time.perf_counter() - started)
                    frame.image = frame.synthesis if frame.image is None else frame.image
                    item = frame if item.finish is None else functools.partial(item.finish, frame)
                elif tracks is not None and isinstance(item, ReenactedFrame) and not item.has_face:
                    tracks.reset()  # a gap in the face: the parts are chosen afresh after it
                yield item

    def _into_scene(self, scenes, index: int, driver_frame: np.ndarray | None, target: np.ndarray,
                    stats: ReenactStats, target_mesh: np.ndarray | None = None, gaze: np.ndarray | None = None,
                    driver_mouth: DriverMouth | None = None, driver_eyes: DriverEyes | None = None) -> _Prepared:
        """The target (anchor crop pixels; its mesh, when there is one) prepared at the next scene frame's head pose,
        its finisher compositing the synthesis into that scene frame."""
        scene = next(scenes)
        target = scene.place(target)  # a video source whose face was not found yet: the anchor's place
        if target_mesh is not None:
            target_mesh = scene.place_mesh(target_mesh)
        return self._prepare(index, driver_frame, target, stats, target_mesh,
                             functools.partial(paste_into_scene, scene=scene, stats=stats), scene.image, gaze,
                             driver_mouth, driver_eyes)

    def _landmark_driver(self, driver, info: DriverInfo, relative: bool, smooth: bool, landmark_space, landmark_size,
                         stats: ReenactStats, scenes=None) -> Iterator[ReenactedFrame | _Prepared]:
        from landmarks.align import crop_transform, transform_landmarks
        from landmarks.motion.smooth import OneEuroFilter, driving_cutoffs

        array, space, size = read_landmark_array(driver, landmark_space=landmark_space, landmark_size=landmark_size)
        one_euro = OneEuroFilter(info.fps, driving_cutoffs()) if smooth else None
        reference, source = DriverReference(), self._source_face()
        if relative:  # the whole array is at hand: its first faces set the lids at rest, as a file driver's do
            reference.look_ahead(list(array[:LOOK_AHEAD]), [None] * min(len(array), LOOK_AHEAD))
        for index, points in enumerate(array):
            started = time.perf_counter()
            lids = reference.lids(points) if relative else None
            points = one_euro(points) if one_euro is not None else points
            if space == "frame":
                crop_landmarks = transform_landmarks(points, crop_transform(points, self.crop_size))
            else:
                crop_landmarks = points.astype(np.float64) * (self.crop_size / float(size or self.resolution))
            reference.start(crop_landmarks)
            target, _ = self._drive(crop_landmarks, None, reference, lids, relative, source)
            stats.add("landmarks", time.perf_counter() - started)
            stats.frames += 1
            yield (self._into_scene(scenes, index, None, target, stats) if scenes is not None
                   else self._prepare(index, None, target, stats))

    def _frame_driver(self, info: DriverInfo, relative: bool, smooth: bool, paste_back: bool, stats: ReenactStats,
                      scenes=None, retarget: str = "2d") -> Iterator[ReenactedFrame | _Prepared]:
        """paste_back: into the driver's frames; scenes: a ``SourceScene`` to composite into instead."""
        from landmarks.align import crop_transform, transform_landmarks
        from landmarks.motion.smooth import OneEuroFilter, driving_cutoffs
        from landmarks.detect.registry import make_tracker
        from lsr.core.overlap import prefetch

        size = self.crop_size
        tracker = make_tracker(self.detector)
        one_euro = OneEuroFilter(info.fps, driving_cutoffs()) if smooth else None
        reference, source = DriverReference(), self._source_face()
        ahead, tracked = track_driver(info, tracker, LOOK_AHEAD if relative else 0)  # the lids at rest, first
        reference.look_ahead([points for points, *_ in ahead], [mesh for _, mesh, *_ in ahead])
        gazes = DriverGaze(self._require_subject().anchor_gaze if relative else None) if self.eyes != "blend" else None
        frames = prefetch(tracked)  # decoding and tracking on a thread, a few frames ahead of the synthesis
        index = 0
        for frame, points, mesh, irises, tracking_seconds in frames:
            started = time.perf_counter() - tracking_seconds
            raw_points = points
            if points is not None and one_euro is not None:
                points = one_euro(points)
            matrix = crop_landmarks = crop_mesh = lids = None
            if points is not None and np.isfinite(points).all():
                matrix = crop_transform(points, size)
                crop_landmarks = transform_landmarks(points, matrix)
                crop_mesh = self._crop_mesh(mesh, raw_points, points, matrix, retarget if relative else "2d")
                lids = (reference.lids(raw_points, mesh) if relative or self.lids == "driver"
                        else None)  # as detected, as lsr eval reads them: relative motion and the driver's eyes
                reference.start(crop_landmarks, crop_mesh)  # the driver's first face: its motion moves the source's
                crop_landmarks, crop_mesh = self._drive(crop_landmarks, crop_mesh, reference, lids, relative, source,
                                                        retarget)
            elif one_euro is not None:
                one_euro.reset()  # never smooth across a gap
            gaze = None if gazes is None or crop_landmarks is None else gazes(frame, raw_points, irises)
            mouth = (cut_driver_mouth(frame, raw_points) if crop_landmarks is not None
                     and self.mouth_interior == "driver" else None)  # the points as detected: the pixels' own
            eyes = (cut_driver_eyes(frame, raw_points, lids[0]) if crop_landmarks is not None and lids is not None
                    and self.lids == "driver" else None)  # against the driver's lids at rest
            stats.add("landmarks", time.perf_counter() - started)
            if crop_landmarks is None:
                stats.no_face += 1
                stats.frames += 1
                if scenes is not None:
                    passthrough = next(scenes).image
                else:
                    passthrough = frame if paste_back else square_resize(frame, size)
                yield ReenactedFrame(index, passthrough, False, frame, None, None, None)
                index += 1
                continue
            stats.frames += 1
            if scenes is not None:
                yield self._into_scene(scenes, index, frame, crop_landmarks, stats, crop_mesh, gaze, mouth, eyes)
            else:  # paste_back: into the driver's own frame (its head and scene around the face), behind the loop
                yield self._prepare(index, frame, crop_landmarks, stats, crop_mesh, functools.partial(
                    paste_into_driver, points=points, matrix=matrix, stats=stats) if paste_back else None, gaze=gaze,
                    driver_mouth=mouth, driver_eyes=eyes)
            index += 1
        if stats.frames and stats.no_face == stats.frames:  # a writer that is still open discards its file
            raise NoFaceError(f"no face found in any of the {stats.frames} frame(s) of the driver {info.path}; "
                              "give a driver that shows a face (or its landmarks as .npy/.json)")

    def _require_subject(self) -> Subject:
        if self.subject is None:
            raise NoFaceError("no subject encoded yet: call encode_subject(source) before re-enacting")
        return self.subject


def _with_progress(frames: Iterator[ReenactedFrame], total: int) -> Iterator[ReenactedFrame]:
    """``frames`` under a progress bar; closing this closes them (their threads stop)."""
    from tqdm import tqdm

    with contextlib.closing(frames), tqdm(frames, total=total, desc="reenact", unit="frame", dynamic_ncols=True) as bar:
        yield from bar


def default_crop_size(backend: SynthesisBackend) -> int:
    """The crop (and output) side: ``crop_scale`` (model config) times the model resolution for a warp-guided model
    (detail comes from the warped shots, the network runs at its own resolution), else the model resolution."""
    return int(backend.resolution) * (int(getattr(backend, "crop_scale", 2)) if getattr(backend, "warp_references", 0) else 1)
