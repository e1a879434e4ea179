"""MediaPipe's face detector (BlazeFace, short range) and 468-point face mesh on onnxruntime: no torch, no dlib.

The two networks are Google's Apache-2.0 models, converted once to ONNX by ``lsr face-models convert`` (``landmarks.detect.rebuild_mediapipe``)
(sources and checksums in ``landmarks/assets/mediapipe/SOURCES.json``). What runs around them follows
MediaPipe's own graphs (face_detection_short_range_cpu, face_landmark_front_cpu):

1. **Detection**: the frame is letterboxed into 128x128, scaled to [-1, 1]; 896 SSD anchors (strides 8, 16)
   give boxes and 6 keypoints (eyes, nose tip, mouth, ears); sigmoid scores >= ``min_score``; weighted
   non-maximum suppression at IoU 0.3.
2. **Region of interest**: a square 1.5x the box's longer side, rotated so the eye line is level.
3. **Mesh**: the region is sampled into 192x192 in [0, 1]; the net returns 468 (x, y, z) points in those
   pixels and a face-presence logit. Points go back to the frame through the region's affine transform.
3b. **Eyes** (``refine_eyes``; MediaPipe's iris_landmark_left_and_right_cpu graph, as its face mesh does
   with refined landmarks): a square 2.3x the eye-corner distance around each eye, levelled, is sampled into 64x64
   in [0, 1] (the image-right eye mirrored: the net knows image-left eyes); the iris net's first 16 of its 71 eye
   points replace the mesh's 16 eye-contour vertices of that eye (x, y; z stays). The mesh net alone barely moves
   its lids: on the hold-out frames of the 7 shared evaluation clips its lid gap varies about 0.6 times as much
   as the iris net's (standard deviation 0.011 against 0.018 eye distances, mean over the people), agrees with it
   at 0.26-0.90 per person, and repeats itself less on the same frame moved by half a pixel and zoomed 2%
   (correlation 0.54-0.97 per person, the iris net's 0.89-1.00).
4. **Tracking** (``landmarks.detect.mediapipe_tracker``): the next frame's region comes from this frame's mesh (eye corners
   33 and 263 level the square), so detection runs only when presence drops.

Shapes: images (H, W, 3) uint8 RGB; boxes (4,) float32 x0, y0, x1, y1; meshes (468, 3) float32 x, y in frame
pixels and z in the same pixel scale (smaller = nearer the camera).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import json
import os
import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from landmarks.exceptions import ModelFilesError

ASSETS = Path(__file__).resolve().parents[1] / "assets" / "mediapipe"
DETECTOR_FILE = "face_detection_short_range.onnx"
MESH_FILE = "face_landmark.onnx"
IRIS_FILE = "iris_landmark.onnx"
MESH_POINTS = 468
DETECTOR_SIZE = 128
MESH_SIZE = 192
ROI_SCALE = 1.5  # MediaPipe's RectTransformationCalculator scale for both the detection and the mesh region
IRIS_SIZE = 64
EYE_ROI_SCALE = 2.3  # MediaPipe's iris_landmark_landmarks_to_roi: the eye's square, 2.3x its corner distance
EYE_CONTOURS = (
    ((33, 133), (33, 7, 163, 144, 145, 153, 154, 155, 133, 246, 161, 160, 159, 158, 157, 173), False),
    ((362, 263), (263, 249, 390, 373, 374, 380, 381, 382, 362, 466, 388, 387, 386, 385, 384, 398), True),
)
"""Per eye: the corners whose line the eye's square is levelled on (image left to right), the mesh vertices the iris
net's first 16 points replace (corner, lower lid, corner, upper lid: MediaPipe's update_face_landmarks order), and
whether the crop is mirrored (the image-right eye)."""
EYE_CORNERS = (33, 263)  # mesh vertices of the image-left eye's outer corner and the image-right eye's outer corner


def _session(filename: str) -> Any:
    path = ASSETS / filename
    if not path.is_file():
        raise ModelFilesError(
            f"face model {path.name} not found in {path.parent}; reinstall the package "
            "(or rebuild it: lsr face-models convert)"
        )
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1  # 2-5 ms nets: a second thread costs more in hand-off than it gains
    options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


_LOCAL = threading.local()


def session(filename: str) -> Any:
    """One onnxruntime session per thread and model (``run`` is thread-safe, but one thread each keeps them apart)."""
    sessions = getattr(_LOCAL, "sessions", None)
    if sessions is None:
        sessions = _LOCAL.sessions = {}
    if filename not in sessions:
        sessions[filename] = _session(filename)
    return sessions[filename]


@functools.lru_cache(maxsize=1)
def ssd_anchors() -> np.ndarray:
    """(896, 2) anchor centres in [0, 1] of the short-range detector: MediaPipe's SsdAnchorsCalculator with
    4 layers, strides 8, 16, 16, 16, fixed anchor size, 2 anchors per layer (layers of one stride merged)."""
    centres = []
    for stride, per_cell in ((8, 2), (16, 6)):
        cells = DETECTOR_SIZE // stride
        ys, xs = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
        grid = np.stack([(xs + 0.5) / cells, (ys + 0.5) / cells], axis=-1).reshape(-1, 1, 2)
        centres.append(np.repeat(grid, per_cell, axis=1).reshape(-1, 2))
    return np.concatenate(centres).astype(np.float32)


@dataclasses.dataclass
class Detection:
    """One BlazeFace detection in frame pixels. box: (4,) x0, y0, x1, y1; keypoints: (6, 2) x, y of the
    image-left eye, image-right eye, nose tip, mouth centre, image-left ear, image-right ear; score in [0, 1]."""

    box: np.ndarray
    keypoints: np.ndarray
    score: float


def _letterbox(image: np.ndarray, size: int) -> tuple[np.ndarray, float, np.ndarray]:
    """Fit the image into size x size, centred, black bars. Returns (size, size, 3) uint8, scale, (2,) offset:
    frame = (letterboxed - offset) / scale."""
    height, width = image.shape[:2]
    scale = size / max(height, width)
    new_w, new_h = max(1, round(width * scale)), max(1, round(height * scale))
    resized = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    boxed = np.zeros((size, size, 3), np.uint8)
    left, top = (size - new_w) // 2, (size - new_h) // 2
    boxed[top : top + new_h, left : left + new_w] = resized
    return boxed, scale, np.array([left, top], np.float32)


def _iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    x0 = np.maximum(box[0], boxes[:, 0])
    y0 = np.maximum(box[1], boxes[:, 1])
    x1 = np.minimum(box[2], boxes[:, 2])
    y1 = np.minimum(box[3], boxes[:, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area = (box[2] - box[0]) * (box[3] - box[1])
    areas = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    return inter / np.maximum(area + areas - inter, 1e-9)


def weighted_nms(boxes: np.ndarray, keypoints: np.ndarray, scores: np.ndarray,
                 threshold: float = 0.3) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """MediaPipe's WEIGHTED suppression: each cluster (IoU > threshold with its best box) becomes the
    score-weighted mean of its boxes and keypoints, with the best score. Returns [(box, keypoints, score)]."""
    order = np.argsort(-scores)
    remaining = list(order)
    kept = []
    while remaining:
        best = remaining[0]
        overlaps = _iou(boxes[best], boxes[remaining])
        cluster = [remaining[i] for i in np.flatnonzero(overlaps > threshold)]
        weights = scores[cluster][:, None]
        box = (boxes[cluster] * weights).sum(0) / weights.sum()
        points = (keypoints[cluster] * weights[:, :, None]).sum(0) / weights.sum()
        kept.append((box.astype(np.float32), points.astype(np.float32), float(scores[best])))
        remaining = [index for index in remaining if index not in set(cluster)]
    return kept


def sigmoid(logits: np.ndarray) -> np.ndarray:
    """The nets' logits -> probabilities, float64 (MediaPipe clips detection logits at +-100)."""
    return 1.0 / (1.0 + np.exp(-np.clip(np.asarray(logits, np.float64), -100.0, 100.0)))


def detector_input(image: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """(H, W, 3) uint8 RGB -> the detector's (1, 128, 128, 3) float32 input in [-1, 1] (letterboxed), and the
    scale and (2,) offset that map its pixels back: frame = (input - offset) / scale."""
    boxed, scale, offset = _letterbox(image, DETECTOR_SIZE)
    return (boxed.astype(np.float32) / 127.5 - 1.0)[None], scale, offset


def decode_detections(regressors: np.ndarray, logits: np.ndarray, scale: float, offset: np.ndarray,
                      min_score: float = 0.5) -> list[Detection]:
    """The detector's outputs -> detections in frame pixels, best first (MediaPipe's TensorsToDetections with
    sigmoid scores, then weighted suppression). regressors: (1, 896, 16); logits: (1, 896, 1)."""
    raw, scores = regressors[0], sigmoid(logits[0, :, 0])  # (896, 16), (896,)
    keep = np.flatnonzero(scores >= min_score)
    if keep.size == 0:
        return []
    anchors = ssd_anchors()[keep] * DETECTOR_SIZE  # (n, 2) in letterbox pixels
    raw = raw[keep]
    centre = anchors + raw[:, 0:2]
    half = raw[:, 2:4] / 2.0
    boxes = np.concatenate([centre - half, centre + half], axis=1)
    points = anchors[:, None, :] + raw[:, 4:16].reshape(-1, 6, 2)
    found = []
    for box, keypoints, score in weighted_nms(boxes, points, scores[keep]):
        box = ((box.reshape(2, 2) - offset) / scale).reshape(4)
        found.append(Detection(box=box.astype(np.float32), keypoints=((keypoints - offset) / scale).astype(np.float32), score=score))
    return found


def detect_faces(image: np.ndarray, min_score: float = 0.5) -> list[Detection]:
    """BlazeFace (short range) on the whole frame: detections in frame pixels, best first.

    image: (H, W, 3) uint8 RGB. The short-range model sees the frame at 128 px on its longer side and finds
    faces of about 1/8 of that side and up; ``detect_tiled`` covers smaller faces.
    """
    tensor, scale, offset = detector_input(image)
    net = session(DETECTOR_FILE)
    regressors, logits = net.run(None, {net.get_inputs()[0].name: tensor})
    return decode_detections(regressors, logits, scale, offset, min_score)


TILE_LEVELS = 2  # tiles of 1/2, then 1/4 of the shorter side: faces down to about 1/16 of it (a full-body shot)
MIN_TILE = 160  # px: below this a tile adds nothing the whole frame did not see


def _tiles(height: int, width: int, side: int) -> list[tuple[int, int]]:
    """Top-left corners of side x side tiles overlapping by half, covering the frame (the last row/column flush)."""
    step = max(1, side // 2)
    tops = sorted({*range(0, max(1, height - side), step), max(0, height - side)})
    lefts = sorted({*range(0, max(1, width - side), step), max(0, width - side)})
    return [(top, left) for top in tops for left in lefts]


def detect_tiled(image: np.ndarray, min_score: float = 0.5) -> list[Detection]:
    """Whole-frame detection, then, when nothing is found, overlapping square tiles of half, then a quarter of the
    shorter side, so that small faces reach the detector's range. Detections in frame pixels, best first."""
    found = detect_faces(image, min_score)
    if found:
        return found
    height, width = image.shape[:2]
    candidates: list[Detection] = []
    side = min(height, width)
    for _ in range(TILE_LEVELS):
        side //= 2
        if side < MIN_TILE or candidates:
            break
        for top, left in _tiles(height, width, side):
            tile = np.ascontiguousarray(image[top : top + side, left : left + side])
            for detection in detect_faces(tile, min_score):
                shift = np.array([left, top], np.float32)
                candidates.append(Detection(detection.box + np.tile(shift, 2), detection.keypoints + shift, detection.score))
    if not candidates:
        return []
    boxes = np.stack([d.box for d in candidates])
    points = np.stack([d.keypoints for d in candidates])
    scores = np.array([d.score for d in candidates], np.float32)
    return [Detection(box, keypoints, score) for box, keypoints, score in weighted_nms(boxes, points, scores)]


@dataclasses.dataclass(frozen=True)
class Region:
    """A rotated square in the frame: centre (x, y), side, and rotation in radians: the angle of the face's eye line,
    clockwise on screen (image y points down), so the crop turns it level (MediaPipe's NormalizedRect.rotation)."""

    centre: tuple[float, float]
    side: float
    rotation: float

    def to_crop(self, size: int = MESH_SIZE) -> np.ndarray:
        """(2, 3) affine matrix mapping frame pixels into the size x size crop."""
        cos, sin = np.cos(self.rotation), np.sin(self.rotation)
        scale = size / self.side
        # crop = scale * R(-rotation) (frame - centre) + size / 2
        rotate = np.array([[cos, sin], [-sin, cos]]) * scale
        shift = np.array([size / 2.0, size / 2.0]) - rotate @ np.asarray(self.centre)
        return np.concatenate([rotate, shift[:, None]], axis=1).astype(np.float64)


def _region(centre: np.ndarray, width: float, height: float, start: np.ndarray, end: np.ndarray) -> Region:
    """MediaPipe's DetectionsToRects (rotation from start->end level) + RectTransformation (square long, 1.5x)."""
    rotation = -np.arctan2(-(end[1] - start[1]), end[0] - start[0])
    side = max(width, height) * ROI_SCALE
    return Region((float(centre[0]), float(centre[1])), float(side), float(rotation))


def region_from_detection(detection: Detection) -> Region:
    box = detection.box
    centre = np.array([(box[0] + box[2]) / 2.0, (box[1] + box[3]) / 2.0])
    return _region(centre, box[2] - box[0], box[3] - box[1], detection.keypoints[0], detection.keypoints[1])


def region_from_mesh(mesh: np.ndarray) -> Region:
    """The next frame's region from this frame's mesh (MediaPipe's face_landmark_landmarks_to_roi): the points'
    box in the rotated frame, rotation levelling the outer eye corners."""
    start, end = mesh[EYE_CORNERS[0], :2], mesh[EYE_CORNERS[1], :2]
    rotation = -np.arctan2(-(end[1] - start[1]), end[0] - start[0])
    cos, sin = np.cos(rotation), np.sin(rotation)
    points = mesh[:, :2]
    # Measure the extent in the face's own (levelled) axes, as MediaPipe does for rotated rects.
    levelled = points @ np.array([[cos, -sin], [sin, cos]])
    low, high = levelled.min(0), levelled.max(0)
    middle = (low + high) / 2.0
    centre = middle @ np.array([[cos, sin], [-sin, cos]])
    side = float(max(high - low)) * ROI_SCALE
    return Region((float(centre[0]), float(centre[1])), side, float(rotation))


@dataclasses.dataclass
class MeshResult:
    """mesh: (468, 3) float32 in frame pixels; presence: face probability in [0, 1]; region: the crop used;
    irises: the iris net's irises."""

    mesh: np.ndarray
    presence: float
    region: Region
    irises: np.ndarray | None = None
    """(2, 4) float64 [x, y, radius, aperture] per eye, image left first (``eye_iris``), when the eyes were refined."""


def to_frame(points: np.ndarray, crop: np.ndarray) -> np.ndarray:
    """(N, 2) points in a crop's pixels -> frame pixels, through the inverse of the (2, 3) frame-to-crop matrix."""
    inverse = cv2.invertAffineTransform(crop)
    return points @ inverse[:, :2].T + inverse[:, 2]


def eye_region(mesh: np.ndarray, corners: tuple[int, int]) -> Region:
    """The iris net's square around one eye: centred between its corners, levelled on them, ``EYE_ROI_SCALE``
    times their distance wide."""
    start, end = np.asarray(mesh[corners[0], :2], np.float64), np.asarray(mesh[corners[1], :2], np.float64)
    rotation = -np.arctan2(-(end[1] - start[1]), end[0] - start[0])
    centre = (start + end) / 2.0
    side = float(np.linalg.norm(end - start)) * EYE_ROI_SCALE
    return Region((float(centre[0]), float(centre[1])), side, float(rotation))


def eye_crop(region: Region) -> np.ndarray:
    """(2, 3) affine matrix from frame pixels into the iris net's 64x64 crop, pixel centres on integers (OpenCV's):
    the region's centre lands at 31.5, between the middle pixels, so that mirroring the crop mirrors the eye about
    its centre, as MediaPipe's continuous coordinates do."""
    matrix = region.to_crop(IRIS_SIZE)
    matrix[:, 2] -= 0.5
    return matrix


def eye_input(image: np.ndarray, region: Region, mirrored: bool) -> np.ndarray:
    """The iris net's (1, 64, 64, 3) float32 input in [0, 1] for one eye's square (edge pixels repeated)."""
    crop = cv2.warpAffine(image, eye_crop(region), (IRIS_SIZE, IRIS_SIZE), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
    if mirrored:
        crop = crop[:, ::-1]
    return np.ascontiguousarray(crop.astype(np.float32) / 255.0)[None]


_EYE_THREAD: concurrent.futures.ThreadPoolExecutor | None = None
_EYE_LOCK = threading.Lock()


def _forget_eye_thread() -> None:  # a forked child has no such thread
    global _EYE_THREAD
    _EYE_THREAD = None


os.register_at_fork(after_in_child=_forget_eye_thread)


def eye_thread() -> concurrent.futures.ThreadPoolExecutor:
    """The thread that runs the second eye's iris net while the calling thread runs the first."""
    global _EYE_THREAD
    with _EYE_LOCK:
        if _EYE_THREAD is None:
            _EYE_THREAD = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="lsr-iris")
        return _EYE_THREAD


def iris_outputs(tensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The iris net on one eye's input, on this thread's session: (its 71 eye points (x, y, z), its 5 iris points
    (centre, then 4 on the edge)) in its 64x64 crop."""
    net = session(IRIS_FILE)
    outputs = net.run(None, {net.get_inputs()[0].name: tensor})
    return (next(out for out in outputs if out.size == 71 * 3).reshape(71, 3),
            next(out for out in outputs if out.size == 5 * 3).reshape(5, 3))


def lid_gap(contour: np.ndarray) -> float:
    """The gap between an eye contour's lids (corner, 7 lower-lid points, corner, 7 upper-lid points): the mean
    distance of the middle three pairs, in the contour's units."""
    return float(np.mean(np.linalg.norm(contour[11:14, :2] - contour[3:6, :2], axis=1)))


def eye_iris(eye_points: np.ndarray, iris: np.ndarray, region: Region, mirrored: bool) -> np.ndarray:
    """``iris_outputs`` of one eye's square -> (4,) float64 [x, y, radius, aperture]: the iris centre and radius in
    frame pixels, and the lid gap of the net's own contour (corner, 7 lower-lid points, corner, 7 upper-lid points:
    the middle three pairs) over the eye's corner distance."""
    iris, contour = np.array(iris[:, :2], np.float64), np.array(eye_points[:16, :2], np.float64)
    if mirrored:
        iris[:, 0] = IRIS_SIZE - iris[:, 0]
        contour[:, 0] = IRIS_SIZE - contour[:, 0]
    iris = to_frame(iris - 0.5, eye_crop(region))
    radius = float(np.mean(np.linalg.norm(iris[1:] - iris[0], axis=1)))
    gap = lid_gap(contour) / IRIS_SIZE * EYE_ROI_SCALE
    return np.array([iris[0, 0], iris[0, 1], radius, gap])


BLOCK = 8  # the iris gate's blocks: 8 x 8 of the 64 x 64 input


def block_change(tensor: np.ndarray, last: np.ndarray) -> float:
    """The largest mean absolute change between two iris-net inputs ((1, 64, 64, 3) float32 in [0, 1]) over the
    ``BLOCK`` x ``BLOCK`` pixel blocks of the crop: a glance moves the dark iris through a block even where the
    whole crop's mean barely moves. Summed in float64, as deploy/web/src/facemesh.ts blockChange sums it."""
    change = np.abs(tensor[0].astype(np.float64) - last[0].astype(np.float64)).sum(axis=2)
    side = IRIS_SIZE // BLOCK
    return float(change.reshape(side, BLOCK, side, BLOCK).sum(axis=(1, 3)).max()) / (BLOCK * BLOCK * 3)


@dataclasses.dataclass
class IrisGate:
    """The iris net only where an eye changed (live tracking): per eye, the input, the mesh's own lid gap
    (crop pixels) and the net's outputs of its last run. An eye whose input changed by less than ``max_change``
    (``block_change``) and whose mesh lid gap moved by less than ``max_gap_change`` since that run takes those
    outputs again, placed by this frame's square, at most ``max_skips`` frames in a row. Measured on the validation
    clips (docs/decisions/2026-12-07-page-composite.md): it skips about half the runs on a still face and few on a
    moving one; the judged eye correlation and gaze over whole clips move about as much as the tracker's own noise
    moves them."""

    max_change: float = 0.02
    max_gap_change: float = 0.3
    max_skips: int = 2
    runs: int = 0
    skips: int = 0

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the last runs (a lost face, a new detection): every eye runs next time."""
        self.last: list[tuple[np.ndarray, float, tuple[np.ndarray, np.ndarray]] | None] = [None, None]
        self.streak = [0, 0]

    def kept(self, eye: int, tensor: np.ndarray, gap: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The last run's outputs for ``eye`` where they still hold for this input and lid gap, else None."""
        last = self.last[eye]
        if last is None or self.streak[eye] >= self.max_skips or not abs(gap - last[1]) < self.max_gap_change:
            return None
        if not block_change(tensor, last[0]) < self.max_change:
            return None
        self.streak[eye] += 1
        self.skips += 1
        return last[2]

    def ran(self, eye: int, tensor: np.ndarray, gap: float, outputs: tuple[np.ndarray, np.ndarray]) -> None:
        """Keep a run of the net on ``eye``."""
        self.last[eye] = (tensor, gap, outputs)
        self.streak[eye] = 0
        self.runs += 1


def refine_eyes(image: np.ndarray, mesh: np.ndarray, gate: IrisGate | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``mesh`` with both eyes' 16 contour vertices (x, y) from the iris net (module docstring, step 3b), and the
    irises the net found on the way. image: (H, W, 3) uint8 RGB; mesh: (468, 3) frame pixels -> ((468, 3) float32
    (a copy; unchanged when the mesh is not finite or an eye's corners coincide), (2, 4) ``eye_iris`` rows, NaN
    where not run). The two eyes run at once, the second on another thread: the net is single-threaded and
    compute-bound, so both take about 3.2 ms on 2 cores where one after the other took 5.7 (and batching them,
    5.6). gate: an eye it keeps takes its last outputs instead of a run (``IrisGate``)."""
    refined = np.array(mesh, np.float32)
    irises = np.full((2, 4), np.nan)
    if not np.isfinite(refined).all():
        if gate is not None:
            gate.reset()
        return refined, irises
    eyes = []
    for eye, (corners, contour, mirrored) in enumerate(EYE_CONTOURS):  # the corners are not the other eye's
        region = eye_region(refined, corners)
        if region.side >= 1.0:
            tensor, crop, gap, kept = eye_input(image, region, mirrored), eye_crop(region), 0.0, None
            if gate is not None:  # the mesh's own lid gap in crop pixels, against the last run's
                gap = lid_gap(refined[list(contour), :2].astype(np.float64) @ crop[:, :2].T + crop[:, 2])
                kept = gate.kept(eye, tensor, gap)
            eyes.append((eye, region, crop, contour, mirrored, tensor, gap, kept))
    runs = [entry for entry in eyes if entry[-1] is None]
    second = eye_thread().submit(iris_outputs, runs[1][5]) if len(runs) > 1 else None
    outputs = {runs[0][0]: iris_outputs(runs[0][5])} if runs else {}
    if second is not None:
        outputs[runs[1][0]] = second.result()
    for eye, region, crop, contour, mirrored, tensor, gap, kept in eyes:
        eye_points, iris = kept if kept is not None else outputs[eye]
        if gate is not None and kept is None:
            gate.ran(eye, tensor, gap, (eye_points, iris))
        points = eye_points[: len(contour), :2].astype(np.float64)
        if mirrored:
            points[:, 0] = IRIS_SIZE - points[:, 0]
        points -= 0.5  # the net's pixels span [0, 64] (MediaPipe's normalised points); OpenCV's centres are integers
        refined[list(contour), :2] = to_frame(points, crop)
        irises[eye] = eye_iris(eye_points, iris, region, mirrored)
    return refined, irises


def refine_eye_contours(image: np.ndarray, mesh: np.ndarray) -> np.ndarray:
    """``refine_eyes``' mesh alone."""
    return refine_eyes(image, mesh)[0]


def predict_mesh(image: np.ndarray, region: Region, eyes: bool = True, gate: IrisGate | None = None) -> MeshResult:
    """Run the face-mesh net inside ``region`` of ``image`` ((H, W, 3) uint8 RGB); eyes: then refine both eyes'
    contours with the iris net and keep its irises (``refine_eyes``, through ``gate`` where given)."""
    matrix = region.to_crop(MESH_SIZE)
    crop = cv2.warpAffine(image, matrix, (MESH_SIZE, MESH_SIZE), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    tensor = (crop.astype(np.float32) / 255.0)[None]  # (1, 192, 192, 3) in [0, 1]
    net = session(MESH_FILE)
    raw, flag = net.run(None, {net.get_inputs()[0].name: tensor})
    points = raw.reshape(MESH_POINTS, 3).astype(np.float64)
    xy = to_frame(points[:, :2], matrix)
    z = points[:, 2] * (region.side / MESH_SIZE)
    mesh = np.concatenate([xy, z[:, None]], axis=1).astype(np.float32)
    presence = float(sigmoid(flag.reshape(-1)[0]))
    irises = None
    if eyes:
        mesh, irises = refine_eyes(image, mesh, gate)
    return MeshResult(mesh=mesh, presence=presence, region=region, irises=irises)


def sources() -> dict[str, Any]:
    """The provenance record of the shipped model files (wheel, checksums, conversion check)."""
    path = ASSETS / "SOURCES.json"
    if not path.is_file():
        raise ModelFilesError(f"{path} is missing; reinstall the package")
    return json.loads(path.read_text())
