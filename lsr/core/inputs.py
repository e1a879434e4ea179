"""Loading a re-enactment's inputs: the subject's K shots and the driver (torch-free, streaming).

Shared by ``lsr.pipeline.Reenactor`` (torch) and ``deploy.runtime.OnnxReenactor`` (ONNX): one loader
for both runtimes. numpy + OpenCV + the ``landmarks`` toolkit only.

Sources (the subject, thesis §4.3.1: K shots averaged into the latents):
* one or more image files, or a folder of images (every image with a face is usable);
* one video: up to 4K candidate frames spread evenly over it are decoded in one streaming pass and
  the frames with a face are kept;
* already-loaded (H, W, 3) uint8 RGB arrays.
Each usable shot is cropped like the training data (``landmarks.align.crop``). K shots are then chosen to
cover the person (``choose_shots``, ``landmarks.parts.coverage``): spread over them, the most neutral face among them,
and the person's extreme moments (the widest mouth, the most closed eyes, the furthest turns and glances) swapped
in where no chosen shot shows them. ``k=None`` uses min(8, usable); an explicit K larger than the usable shots is an
error (it never silently repeats shots).
Shots of another person's face (a video that cuts to someone else, a stray photo) are left out
and replaced by other frames of the person (``landmarks.detect.same_person``; a note says so).

Drivers:
* a video file, a folder of images, or one image (frames, tracked with ``LandmarkTracker``);
* raw landmarks: a ``.npy`` / ``.json`` file or an (N, 68, 2) array. ``landmark_space="frame"`` means
  pixel coordinates of the driver's frames (each frame is then cropped by its own crop transform);
  ``"crop"`` means coordinates already in a training-framed crop of side ``landmark_size`` (default: the
  model resolution), rescaled to the model resolution. A ``.json`` file holds either the nested list or
  ``{"landmarks": [...], "space": "frame"|"crop", "size": S}``. NaN/inf in raw arrays is rejected with
  an error naming the frames (there is no picture to pass through; interpolate or drop those frames).
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import json
import os
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from landmarks.parts.coverage import spread
from landmarks.exceptions import InputFileError, NoFaceError
from landmarks.io.image_files import IMAGE_SUFFIXES, read_image
from landmarks.shape.ibug68 import NUM_LANDMARKS
from landmarks.io.video import VIDEO_SUFFIXES
from lsr.core import MAX_K

LANDMARK_SUFFIXES = (".npy", ".json")
DEFAULT_K = 8
CANDIDATES_PER_SHOT = 4  # video sources: decode 4K evenly spread frames to find K with a face

LandmarkSpace = Literal["frame", "crop"]
SourceInput = str | os.PathLike | np.ndarray | Sequence[str | os.PathLike | np.ndarray]


@dataclasses.dataclass
class SubjectShots:
    """K aligned crops of one person.

    frames: (K, S, S, 3) uint8 RGB crops; landmarks: (K, 68, 2) float32 in crop pixels; names: where each came from.
    """

    frames: np.ndarray
    landmarks: np.ndarray
    names: list[str] = dataclasses.field(default_factory=list)
    notes: list[str] = dataclasses.field(default_factory=list)
    """What the loader decided for the user (unreadable images skipped, which of several faces was used)."""
    anchor: int = 0
    """Index of the anchor shot: the source's neutral face (relative motion starts from it) and its scene."""
    anchor_frame: np.ndarray | None = None
    """(H, W, 3) uint8: the anchor shot's full-resolution frame, the scene a re-enactment is composited into
    (None for a video source, whose own frames are the scene, or for shots given as crops)."""
    anchor_frame_landmarks: np.ndarray | None = None
    """(68, 2) float64: the anchor's landmarks in ``anchor_frame`` pixels."""
    video: Path | None = None
    """The source video, when the source is one: its frames, in order, are the scene."""
    meshes: np.ndarray | None = None
    """(K, 468, 3) float32 face meshes in crop pixels (the mesh detector's; NaN rows: none), or None (dlib's
    detector, or shots given as crops with landmarks only): a warp-guided model then warps its references by
    the 68-point TPS alone."""


@dataclasses.dataclass(frozen=True)
class DriverInfo:
    """What the output needs to know before the first frame: kind, frame count, fps, frame size (W, H) or None."""

    kind: Literal["video", "images", "landmarks"]
    frames: int
    fps: float
    size: tuple[int, int] | None
    path: Path | None
    has_audio: bool = False


def choose_shots(frames: Sequence[np.ndarray], points: Sequence[np.ndarray], k: int) -> list[int]:
    """K of the usable shots, chosen to cover the person's range of mouth opening, eye closure, head pose and gaze
    (``landmarks.parts.coverage.choose_covering``, the anchor among them: ``landmarks.shape.expression.pick_anchor``).
    frames: N x (S, S, 3) uint8 crops; points: N x (68, 2) their landmarks -> sorted indices (all when N <= k)."""
    from landmarks.parts.appearance import gazes
    from landmarks.parts.coverage import choose_covering, face_features
    from landmarks.shape.expression import pick_anchor

    if len(frames) <= k:
        return list(range(len(frames)))
    landmarks = np.stack([np.asarray(p, np.float64) for p in points])
    size = frames[0].shape[:2]
    return choose_covering(face_features(landmarks, size, gazes(frames, landmarks)), k, pick_anchor(landmarks, size))


def coverage_features(shots: SubjectShots, targets: np.ndarray, target_size: int) -> tuple[np.ndarray, np.ndarray]:
    """What the shots and a driven sequence show (``landmarks.parts.coverage.face_features``): targets: (T, 68, 2) the
    driven landmarks in crop pixels of side ``target_size`` (NaN rows: no face, left out) -> ((K, 5) of the shots,
    with their gaze; (T', 5) of the targets, whose gaze is unknown)."""
    from landmarks.parts.appearance import gazes
    from landmarks.parts.coverage import face_features

    targets = np.asarray(targets, np.float64).reshape(-1, NUM_LANDMARKS, 2)
    found = targets[np.isfinite(targets).all(axis=(1, 2))]
    return (face_features(shots.landmarks, shots.frames.shape[1:3], gazes(shots.frames, shots.landmarks)),
            face_features(found, (target_size, target_size)))


def cover_shots(shots: SubjectShots, k: int) -> SubjectShots:
    """At most ``k`` of the shots, chosen as ``load_subject_shots`` chooses them (``choose_shots``)."""
    if len(shots.frames) <= k:
        return shots
    chosen = choose_shots(list(shots.frames), list(shots.landmarks), k)
    names = [shots.names[i] for i in chosen] if len(shots.names) == len(shots.frames) else shots.names
    lost = shots.anchor not in chosen  # its frame went with its shot: anchor 0, composited into its crop
    return dataclasses.replace(shots, frames=shots.frames[chosen], landmarks=shots.landmarks[chosen], names=names,
                               meshes=None if shots.meshes is None else shots.meshes[chosen],
                               anchor=0 if lost else chosen.index(shots.anchor),
                               anchor_frame=None if lost else shots.anchor_frame,
                               anchor_frame_landmarks=None if lost else shots.anchor_frame_landmarks)


def _check_k(k: int | None) -> None:
    if k is not None and not (isinstance(k, (int, np.integer)) and 1 <= k <= MAX_K):
        raise InputFileError(f"K (shots) must be an integer in 1..{MAX_K}, got {k!r}")


def is_video(path: Path) -> bool:
    return path.suffix.lower() in VIDEO_SUFFIXES


# The LSR release keeps landmark drawings and oracle maps beside its frames; they are not shots.
LSR_RELEASE_DRAWINGS = ("_contour.png", "_segmap_merged.png")


def list_images(folder: Path) -> list[Path]:
    """Image files of a folder, sorted by name; an error when there are none."""
    images = sorted(
        p for p in folder.iterdir()
        if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES and not p.name.endswith(LSR_RELEASE_DRAWINGS)
    )
    if not images:
        raise InputFileError(f"folder {folder} holds no images ({', '.join(IMAGE_SUFFIXES)}); give images or a video")
    return images


def _source_candidates(source: SourceInput, k: int | None) -> Iterator[tuple[str, np.ndarray | InputFileError]]:
    """(name, (H, W, 3) uint8 RGB) candidate frames of a source, streaming; an image of a folder that cannot be
    read comes as (name, its InputFileError), so one corrupt file does not sink the others."""
    items = [source] if isinstance(source, (str, os.PathLike, np.ndarray)) else list(source)
    if not items:
        raise InputFileError("no source given: pass image files, a folder of images or a video")
    for number, item in enumerate(items):
        if isinstance(item, np.ndarray):
            if item.ndim != 3 or item.shape[2] != 3 or item.dtype != np.uint8:
                raise InputFileError(f"source array #{number} must be (H, W, 3) uint8 RGB, got {item.shape} {item.dtype}")
            yield f"array#{number}", item
            continue
        path = Path(item)
        if not path.exists():
            raise InputFileError(f"source not found: {path}")
        if path.is_dir():
            for image_path in list_images(path):
                try:
                    image = read_image(image_path)
                except InputFileError as exc:
                    yield str(image_path), exc
                    continue
                yield str(image_path), image
        elif is_video(path):
            from landmarks.io.video import iter_frames, probe_video
            from lsr.core.overlap import prefetch

            total = probe_video(path).frames
            wanted = set(spread(total, CANDIDATES_PER_SHOT * (k or DEFAULT_K)))
            candidates = ((index, frame) for index, frame in enumerate(iter_frames(path)) if index in wanted)
            with contextlib.closing(prefetch(candidates)) as frames:  # decoded on a thread beside the detection
                for index, frame in frames:
                    yield f"{path}#{index}", frame
        elif path.suffix.lower() in IMAGE_SUFFIXES:
            yield str(path), read_image(path)
        else:
            raise InputFileError(
                f"unsupported source {path}: give images ({', '.join(IMAGE_SUFFIXES)}), a folder or a video"
            )


def load_subject_shots(source: SourceInput, size: int, *, k: int | None = None, detector=None,
                       face_index: int = 0, anchor: int | None = None) -> SubjectShots:
    """Detect, crop and pick the K shots of a subject (see the module docstring for the rules).

    size: crop side S (the model resolution). detector: a ``landmarks.detect.face_detector.FaceDetector`` (default: the mesh detector).
    face_index: which face of a frame with several (0 = the largest). Unreadable images of a folder are skipped
    while another image is usable; what was skipped or chosen is in ``SubjectShots.notes``.
    anchor: which of the K chosen shots is the scene and the neutral face (None: the most frontal one with a
    closed mouth, ``landmarks.shape.expression.pick_anchor``). Shots whose face is smaller than the crop are cut from
    the full-resolution frames (and a note says so).
    Raises ``NoFaceError`` when no candidate has a face, ``InputFileError`` for unreadable input, K too large or
    an anchor outside 0..K-1.
    """
    from landmarks.align import crop, transform_landmarks, transform_mesh
    from landmarks.detect.registry import make_detector
    from landmarks.scene.compositing import face_side

    _check_k(k)
    if face_index < 0:
        raise InputFileError(f"face index must be >= 0, got {face_index}")
    detector = detector if detector is not None else make_detector()
    frames, points, names, tried, unreadable, crowded, too_few, min_faces = [], [], [], [], [], 0, 0, []
    meshes: list[np.ndarray | None] = []
    frame_points, arrays = [], {}
    for name, image in _source_candidates(source, k):
        tried.append(name)
        if isinstance(image, InputFileError):
            unreadable.append(image)
            continue
        faces = detector.detect(np.ascontiguousarray(image))
        if not faces:
            min_faces.append(detector.min_face_size(image.shape))
            continue
        crowded += len(faces) > 1
        if face_index >= len(faces):
            too_few += 1
            continue
        face = faces[face_index]
        cropped, matrix = crop(image, face.landmarks, size)
        frames.append(cropped)
        points.append(transform_landmarks(face.landmarks, matrix).astype(np.float32))
        meshes.append(None if face.mesh is None else transform_mesh(face.mesh, matrix).astype(np.float32))
        frame_points.append(np.asarray(face.landmarks, np.float64))
        names.append(name)
        if name.startswith("array#"):
            arrays[name] = image
    files = sorted({name.split("#")[0] for name in tried})
    where = files[0] if len(files) == 1 else f"{len(files)} source files"
    if not frames:
        if unreadable and len(unreadable) == len(tried):
            raise unreadable[0]
        if too_few:
            raise NoFaceError(f"face index {face_index} asked for, but no source frame of {where} shows more than "
                              f"{face_index} face(s); lower --face-index (0 = the largest face)")
        smallest = min(min_faces, default=0)
        raise NoFaceError(
            f"no face found in the source ({where}, {len(tried)} frame(s) tried); use frontal, well-lit shots of one "
            f"person, with the face at least about {smallest} px wide: crop a large photo closer to the face"
        )
    notes = [f"skipped {exc}" for exc in unreadable]
    if crowded:
        which = "the largest" if face_index == 0 else f"face {face_index} by size (0 = the largest)"
        notes.append(f"{crowded} source frame(s) show more than one face: used {which}; --face-index picks another")
    if too_few:
        notes.append(f"{too_few} source frame(s) had fewer than {face_index + 1} faces and were not used")
    if k is not None and k > len(frames):
        raise InputFileError(
            f"K={k} is larger than the usable source frames: only {len(frames)} of {len(tried)} tried frame(s) of "
            f"{where} have a face; lower --k to <= {len(frames)} or give more shots"
        )
    chosen, note = of_the_person(frames, points, choose_shots(frames, points, k or DEFAULT_K))
    notes += [note] if note else []
    if k is not None and k > len(chosen):
        raise InputFileError(f"K={k} is larger than the source frames that show the person, {len(chosen)}: {note}; "
                             f"lower --k to <= {len(chosen)}")
    shots = SubjectShots(
        np.stack([frames[i] for i in chosen]), np.stack([points[i] for i in chosen]), [names[i] for i in chosen], notes,
        meshes=np.stack([meshes[i] for i in chosen]) if all(meshes[i] is not None for i in chosen) else None,
    )
    sides = [face_side(frame_points[i]) for i in chosen]
    if np.median(sides) < size:
        shots.notes.append(f"the source's face is small ({np.median(sides):.0f} px framed, under the {size} px working "
                           "crop): shots are cut from the full-resolution frames and upscaled, and the result is "
                           "composited back at the source's size; closer or larger source frames give a sharper face")
    items = [source] if isinstance(source, (str, os.PathLike, np.ndarray)) else list(source)
    if len(items) == 1 and isinstance(items[0], (str, os.PathLike)) and is_video(Path(items[0])):
        return set_anchor(dataclasses.replace(shots, video=Path(items[0])), anchor)
    full = {names[i]: (arrays.get(names[i]), frame_points[i]) for i in chosen}
    return set_anchor(shots, anchor, full_frames=full)


def of_the_person(frames: list[np.ndarray], points: list[np.ndarray],
                   chosen: list[int]) -> tuple[list[int], str | None]:
    """The chosen shots without another person's face (``landmarks.detect.same_person.same_person``), each one left out
    replaced by the next usable frame of the person -> (indices into ``frames``, sorted; a note or None).
    Fewer than 3 shots have no majority to judge by and are kept."""
    from landmarks.detect import same_person as identity

    if len(chosen) < 3:
        return chosen, None
    if not identity.available():
        return chosen, "the shots were not checked for another person's face (dlib's face recogniser is not installed)"
    found = identity.face_descriptors([frames[i] for i in chosen], [points[i] for i in chosen])  # NaN: turned
    keep = identity.same_person(found)
    if keep.all():
        return chosen, None
    kept = [i for i, ok in zip(chosen, keep) if ok]
    centre = found[identity.medoid(found)]  # what same_person measured from
    added = 0
    for index in (i for i in range(len(frames)) if i not in chosen):
        if len(kept) == len(chosen):
            break
        descriptor = identity.face_descriptors([frames[index]], [points[index]])[0]
        if not np.isfinite(descriptor).all() or np.linalg.norm(descriptor - centre) <= identity.SAME_PERSON_RADIUS:
            kept.append(index)
            added += 1
    note = (f"left out {len(chosen) - int(keep.sum())} of {len(chosen)} chosen source frame(s) showing another "
            f"person's face (dlib's face descriptor farther than {identity.SAME_PERSON_RADIUS:g} from the person's)"
            + (f"; {added} other frame(s) of the person used instead" if added else ""))
    return sorted(kept), note


def set_anchor(shots: SubjectShots, anchor: int | None = None, *,
               full_frames: dict[str, tuple[np.ndarray | None, np.ndarray]] | None = None) -> SubjectShots:
    """The shots with their anchor chosen (``anchor`` or ``landmarks.shape.expression.pick_anchor``) and, for image
    sources, its full frame as the scene. full_frames: shot name -> (its (H, W, 3) frame, or None to read the
    image file of that name; its (68, 2) landmarks in the frame). Shots without one composite into their crop."""
    from landmarks.shape.expression import pick_anchor

    count = len(shots.frames)
    if anchor is not None and not 0 <= anchor < count:
        raise InputFileError(f"--anchor {anchor} is not one of the {count} shots (0..{count - 1})")
    chosen = pick_anchor(shots.landmarks, shots.frames.shape[1:3]) if anchor is None else int(anchor)
    frame = points = None
    if shots.video is None and full_frames and chosen < len(shots.names) and shots.names[chosen] in full_frames:
        frame, points = full_frames[shots.names[chosen]]
        frame = read_image(shots.names[chosen]) if frame is None else frame
    return dataclasses.replace(shots, anchor=chosen, anchor_frame=frame,
                               anchor_frame_landmarks=None if points is None else np.asarray(points, np.float64))


# ---- drivers ---------------------------------------------------------------------------------------------


def read_landmark_array(
    driver: str | os.PathLike | np.ndarray, *, landmark_space: LandmarkSpace | None = None, landmark_size: int | None = None
) -> tuple[np.ndarray, LandmarkSpace, int | None]:
    """A raw landmark driver -> ((N, 68, 2) float32, space, size). NaN/inf rows are an ``InputFileError``."""
    name = "landmark array" if isinstance(driver, np.ndarray) else str(driver)
    space_in_file, size_in_file = None, None
    if isinstance(driver, np.ndarray):
        array = driver
    else:
        path = Path(driver)
        if not path.is_file():
            raise InputFileError(f"driver landmarks not found: {path}")
        try:
            if path.suffix.lower() == ".npy":
                array = np.load(path, allow_pickle=False)
            else:
                data = json.loads(path.read_text())
                if isinstance(data, dict):
                    space_in_file, size_in_file = data.get("space"), data.get("size")
                    data = data.get("landmarks")
                array = np.asarray(data, dtype=np.float64)
        except (OSError, ValueError, json.JSONDecodeError) as exc:
            raise InputFileError(f"cannot read driver landmarks {path}: {exc}; write an (N, 68, 2) .npy or .json") from exc
    array = np.asarray(array)
    if array.dtype.kind not in "fiu" or array.ndim != 3 or array.shape[1:] != (NUM_LANDMARKS, 2) or len(array) == 0:
        raise InputFileError(
            f"driver landmarks {name} must be a non-empty (N, {NUM_LANDMARKS}, 2) numeric array (x, y), "
            f"got shape {array.shape} dtype {array.dtype}"
        )
    bad = np.flatnonzero(~np.isfinite(array).all(axis=(1, 2)))
    if len(bad):
        raise InputFileError(
            f"driver landmarks {name} contain NaN/inf in {len(bad)} frame(s) (first: {bad[:5].tolist()}); raw "
            "landmark drivers must be complete: interpolate or drop those frames (video drivers pass face-less frames through)"
        )
    space = landmark_space or space_in_file or "frame"
    if space not in ("frame", "crop"):
        raise InputFileError(f"landmark space must be 'frame' or 'crop', got {space!r} ({name})")
    return array.astype(np.float32), space, landmark_size or size_in_file


def describe_driver(driver: str | os.PathLike | np.ndarray, fps: float | None = None) -> DriverInfo:
    """Kind, frame count, fps and frame size of a driver, without decoding it (errors name the file)."""
    if isinstance(driver, np.ndarray):
        array, _, _ = read_landmark_array(driver)
        return DriverInfo("landmarks", len(array), fps or 25.0, None, None)
    path = Path(driver)
    if not path.exists():
        raise InputFileError(f"driver not found: {path}")
    if path.is_dir():
        images = list_images(path)
        height, width = read_image(images[0]).shape[:2]
        return DriverInfo("images", len(images), fps or 25.0, (width, height), path)
    if is_video(path):
        from landmarks.io.video import probe_video

        info = probe_video(path)
        return DriverInfo("video", info.frames, fps or info.fps, (info.width, info.height), path, info.has_audio)
    if path.suffix.lower() in IMAGE_SUFFIXES:  # one still frame
        height, width = read_image(path).shape[:2]
        return DriverInfo("images", 1, fps or 25.0, (width, height), path)
    if path.suffix.lower() in LANDMARK_SUFFIXES:
        array, _, _ = read_landmark_array(path)
        return DriverInfo("landmarks", len(array), fps or 25.0, None, path)
    raise InputFileError(
        f"unsupported driver {path}: give a video ({', '.join(VIDEO_SUFFIXES)}), an image or a folder of images, "
        f"or landmarks ({', '.join(LANDMARK_SUFFIXES)})"
    )


def iter_driver_frames(info: DriverInfo) -> Iterator[np.ndarray]:
    """Frames of a video or image-folder driver, one at a time: (H, W, 3) uint8 RGB, all of the first's size."""
    if info.kind == "video":
        from landmarks.io.video import iter_frames

        yield from iter_frames(info.path)
        return
    expected = None
    for path in [info.path] if info.path.is_file() else list_images(info.path):
        frame = read_image(path)
        if expected is not None and frame.shape != expected:
            raise InputFileError(
                f"driver image {path} is {frame.shape[1]}x{frame.shape[0]}, the first image is "
                f"{expected[1]}x{expected[0]}; a driver folder needs frames of one size"
            )
        expected = frame.shape
        yield frame


def track_driver(info: DriverInfo, tracker, look_ahead: int = 0) -> tuple[list, Iterator]:
    """A video or image-folder driver's frames with their faces: (the first ``look_ahead`` frames' faces, tracked
    now, before any is driven; an iterator over every frame that tracks the rest as it goes). A face: (points
    (68, 2) or None, mesh (468, 3) or None and irises (2, 4) or None: the mesh tracker's, seconds it took); the
    iterator gives (frame, *face). The driver is decoded twice where it looks ahead; ``tracker`` tracks each frame
    once, in order."""

    def track(frame: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None, float]:
        started = time.perf_counter()
        points = tracker.update(frame)
        mesh, irises = getattr(tracker, "mesh", None), getattr(tracker, "irises", None)  # dlib's gives neither
        return (points, None if mesh is None else np.array(mesh), None if irises is None else np.array(irises),
                time.perf_counter() - started)

    ahead = []
    if look_ahead > 0:
        with contextlib.closing(iter_driver_frames(info)) as first:
            ahead = [track(frame) for frame in itertools.islice(first, look_ahead)]

    def tracked() -> Iterator:
        for number, frame in enumerate(iter_driver_frames(info)):
            yield frame, *(ahead[number] if number < len(ahead) else track(frame))

    return ahead, tracked()


def scale_points(points: np.ndarray, scale: float) -> np.ndarray:
    """Landmarks between crop sides, pixel centres at integers: (p + 0.5) * scale - 0.5."""
    points = np.asarray(points, np.float64)
    return points if scale == 1 else (points + 0.5) * scale - 0.5


def resize_shots(shots: SubjectShots, size: int) -> SubjectShots:
    """Shots cropped at another side -> (K, size, size, 3) crops with their landmarks scaled (the same shots)."""
    crop = shots.frames.shape[1]
    if crop == size:
        return shots
    interpolation = cv2.INTER_AREA if crop > size else cv2.INTER_LINEAR
    frames = np.stack([cv2.resize(frame, (size, size), interpolation=interpolation) for frame in shots.frames])
    meshes = None if shots.meshes is None else scale_mesh(shots.meshes, size / crop).astype(np.float32)
    return dataclasses.replace(shots, frames=frames, landmarks=scale_points(shots.landmarks, size / crop).astype(np.float32),
                               meshes=meshes)


def scale_mesh(mesh: np.ndarray, scale: float) -> np.ndarray:
    """(..., 468, 3) mesh between crop sides: x, y as ``scale_points``, depth times ``scale`` -> float64."""
    mesh = np.asarray(mesh, np.float64)
    return np.concatenate([scale_points(mesh[..., :2], scale), mesh[..., 2:] * scale], axis=-1)


def source_key(source) -> str | None:
    """The resolved path of a source that is one file or folder (a list of one too), else None."""
    if isinstance(source, (str, os.PathLike)):
        return str(Path(source).resolve())
    if isinstance(source, (list, tuple)) and len(source) == 1 and isinstance(source[0], (str, os.PathLike)):
        return str(Path(source[0]).resolve())
    return None


def same_input(source_key: str | None, driver) -> bool:
    """Whether ``driver`` is the very file or folder the subject came from (``source_key``'s)."""
    return source_key is not None and isinstance(driver, (str, os.PathLike)) and str(Path(driver).resolve()) == source_key
