"""Landmark tracking through a video with dlib: detect once, then follow with the shape predictor.

(The default tracker is the face mesh's, ``landmarks.detect.mediapipe_tracker.MeshTracker``; both share ``FrameTracker``.)

Per frame (all arrays (H, W, 3) uint8 RGB; landmarks (68, 2) float32 x, y):

1. While tracking, the face box is predicted from the previous frame's 68 points:
   their bounding box mapped through the box<->landmarks relation measured at the
   last detection (offset of the box centre and box size, both relative to the
   landmarks' extent). The shape predictor was trained on detector boxes, so keeping
   that relation keeps it in its comfort zone. Only the predictor runs (~1-2 ms).
2. The new landmarks are accepted if they are plausible:
   - size change vs the previous frame within ``max_scale_change`` (default 30 %),
   - centre shift below ``max_shift`` (default 40 %) of the face size,
   - face geometry sane: inter-ocular distance 20-70 % of the face size, the mouth
     below the eye line (perpendicular to it within 60 degrees),
   - at least half of the box inside the frame,
   - the face looks like the previous frame's face: normalised cross-correlation of
     32x32 grey patches of the two boxes above ``min_patch_correlation`` (0.35;
     ~0.5 is the lowest seen on a real talking-head clip, ~0 for a cut to another scene). The
     shape predictor returns a face-like shape even on a wall, so geometry alone cannot
     catch a scene cut or an occlusion; this costs ~0.1 ms.
3. Every ``verify_every`` frames a cheap re-detection runs in a small region of
   interest around the face (a crop of twice the face box, resized so the face is
   ~100 px, detector without upsampling: a few ms). We know where to look, so the
   HOG threshold is lenient there (``roi_min_score`` -0.5, and the box must overlap
   the tracked one, IoU > 0.3): turned heads the predictor still follows are kept.
   No face there = lost; a face there re-anchors the box (limits drift) and
   refreshes the relation.
4. When lost (or on the first frame), a full detection runs on that same frame; if
   it finds nothing the frame is marked missing and detection is retried next frame.

No frame is ever dropped: each gets landmarks or an explicit missing mark.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Iterable, Sequence

import cv2
import numpy as np
from tqdm import tqdm

from landmarks.detect.face_detector import DlibDetector, predict_landmarks
from landmarks.shape.ibug68 import NUM_LANDMARKS
from landmarks.shape.measures import inter_ocular_distance
# measured on skimage's astronaut; used only until the first detection gives a real one.
_DEFAULT_RELATION = np.array([0.0, -0.12, 0.98, 1.0], np.float32)


@dataclasses.dataclass
class TrackResult:
    """landmarks: (N, 68, 2) float32, NaN rows where missing; missing: (N,) bool; detections: full detections run."""

    landmarks: np.ndarray
    missing: np.ndarray
    detections: int


def landmark_extent(landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(68, 2) -> (centre (2,), size (2,)) of the points' bounding box."""
    low, high = landmarks.min(axis=0), landmarks.max(axis=0)
    return (low + high) / 2.0, np.maximum(high - low, 1.0)


def box_iou(first: np.ndarray, second: np.ndarray) -> float:
    """Intersection over union of two (4,) x0, y0, x1, y1 boxes."""
    width = min(first[2], second[2]) - max(first[0], second[0])
    height = min(first[3], second[3]) - max(first[1], second[1])
    inter = max(0.0, float(width)) * max(0.0, float(height))
    union = (first[2] - first[0]) * (first[3] - first[1]) + (second[2] - second[0]) * (second[3] - second[1]) - inter
    return inter / float(union) if union > 0 else 0.0


def pick_face(boxes: Sequence[np.ndarray], last_box: np.ndarray | None, face_index: int) -> int | None:
    """Which of a detection's faces (boxes, largest first) to track: after a loss the one overlapping the last
    tracked box (IoU > 0.3), else the ``face_index``-th; None when there are too few."""
    if last_box is not None and boxes:
        overlaps = [box_iou(box, last_box) for box in boxes]
        if max(overlaps) > 0.3:
            return int(np.argmax(overlaps))
    return face_index if face_index < len(boxes) else None


class FrameTracker(abc.ABC):
    """What both trackers share: the frame check, the whole-sequence loop; each gives ``reset()`` and
    ``update(frame) -> (68, 2) | None``."""

    detections: int

    @abc.abstractmethod
    def reset(self) -> None:
        """Forget the face: the next frame starts with a full detection."""

    @abc.abstractmethod
    def update(self, frame: np.ndarray) -> np.ndarray | None:
        """Track one frame. frame: (H, W, 3) uint8 RGB. Returns (68, 2) float32 or None (missing)."""

    @staticmethod
    def checked_frame(frame: np.ndarray) -> np.ndarray:
        """The frame, contiguous; ValueError unless (H, W, 3) uint8."""
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise ValueError(f"frame must be (H, W, 3) uint8 RGB, got {frame.shape} {frame.dtype}")
        return np.ascontiguousarray(frame)

    def track_frames(
        self, frames: Iterable[np.ndarray], total: int | None = None, progress: bool = False
    ) -> TrackResult:
        """Track every frame of ``frames`` (each (H, W, 3) uint8 RGB); a fresh start (reset first)."""
        self.reset()
        rows: list[np.ndarray] = []
        missing: list[bool] = []
        nan_row = np.full((NUM_LANDMARKS, 2), np.nan, np.float32)
        for frame in tqdm(frames, total=total, disable=not progress, desc="tracking", unit="frame"):
            landmarks = self.update(frame)
            rows.append(nan_row if landmarks is None else landmarks)
            missing.append(landmarks is None)
        stacked = np.stack(rows).astype(np.float32) if rows else np.zeros((0, NUM_LANDMARKS, 2), np.float32)
        return TrackResult(landmarks=stacked, missing=np.array(missing, dtype=bool), detections=self.detections)


class LandmarkTracker(FrameTracker):
    """Tracks one face's 68 landmarks through frames (see the module docstring for the policy).

    detector: used for full detections (default HOG); face_index: which face (largest first) to
    pick on the first detection (after a loss the face overlapping the last one is preferred);
    verify_every: frames between ROI re-detections (0 = never); max_scale_change, max_shift,
    roi_min_score, min_patch_correlation: the loss checks of the module docstring.
    """

    def __init__(
        self,
        detector: DlibDetector | None = None,
        *,
        face_index: int = 0,
        verify_every: int = 10,
        max_scale_change: float = 0.3,
        max_shift: float = 0.4,
        roi_min_score: float = -0.5,
        min_patch_correlation: float = 0.35,
    ) -> None:
        self.detector = detector if detector is not None else DlibDetector()
        self.face_index = face_index
        self.verify_every = verify_every
        self.max_scale_change = max_scale_change
        self.max_shift = max_shift
        self.roi_min_score = roi_min_score
        self.min_patch_correlation = min_patch_correlation
        self.reset()

    def reset(self) -> None:
        self.previous: np.ndarray | None = None  # (68, 2) of the last tracked frame, None when lost
        self.last_box: np.ndarray | None = None  # last known face box, kept across losses
        self.relation = _DEFAULT_RELATION.copy()
        self.detections = 0
        self._since_verify = 0
        self._patch: np.ndarray | None = None  # (32*32,) zero-mean unit-norm grey patch of the last face

    # -- box <-> landmarks -------------------------------------------------------------------
    def _record_relation(self, box: np.ndarray, landmarks: np.ndarray) -> None:
        centre, size = landmark_extent(landmarks)
        box_centre = np.array([(box[0] + box[2]) / 2.0, (box[1] + box[3]) / 2.0])
        box_size = np.array([box[2] - box[0], box[3] - box[1]])
        self.relation = np.concatenate([(box_centre - centre) / size, box_size / size]).astype(np.float32)

    def box_from_landmarks(self, landmarks: np.ndarray) -> np.ndarray:
        """(68, 2) -> (4,) float32 box where the detector would have put it."""
        centre, size = landmark_extent(landmarks)
        box_centre = centre + self.relation[:2] * size
        half = self.relation[2:] * size / 2.0
        return np.concatenate([box_centre - half, box_centre + half]).astype(np.float32)

    # -- checks ------------------------------------------------------------------------------
    def _plausible(self, landmarks: np.ndarray, previous: np.ndarray, frame_shape: tuple[int, ...]) -> bool:
        if not np.isfinite(landmarks).all():
            return False
        centre, size = landmark_extent(landmarks)
        old_centre, old_size = landmark_extent(previous)
        scale, old_scale = float(np.sqrt(size.prod())), float(np.sqrt(old_size.prod()))
        if not 1.0 / (1.0 + self.max_scale_change) <= scale / old_scale <= 1.0 + self.max_scale_change:
            return False
        if np.linalg.norm(centre - old_centre) > self.max_shift * old_scale:
            return False
        if not 0.2 <= float(inter_ocular_distance(landmarks)) / scale <= 0.7:
            return False
        eye_line = landmarks[42:48].mean(axis=0) - landmarks[36:42].mean(axis=0)
        down = landmarks[48:68].mean(axis=0) - (landmarks[36:48].mean(axis=0))
        cosine = float(eye_line @ down) / (np.linalg.norm(eye_line) * np.linalg.norm(down) + 1e-6)
        cross = float(eye_line[0] * down[1] - eye_line[1] * down[0])  # > 0: mouth on the image-down side
        if abs(cosine) > 0.5 or cross <= 0:
            return False
        height, width = frame_shape[:2]
        box = self.box_from_landmarks(landmarks)
        inside_w = max(0.0, min(box[2], width) - max(box[0], 0.0))
        inside_h = max(0.0, min(box[3], height) - max(box[1], 0.0))
        return inside_w * inside_h >= 0.5 * (box[2] - box[0]) * (box[3] - box[1])

    def _face_patch(self, frame: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
        """(1024,) zero-mean, unit-norm grey 32x32 patch of the face box (for appearance checks)."""
        box = self.box_from_landmarks(landmarks)
        size = 32
        scale_x, scale_y = (box[2] - box[0]) / size, (box[3] - box[1]) / size
        # An affine warp samples the box straight into 32x32, even where it leaves the frame.
        warp = np.array([[scale_x, 0.0, box[0]], [0.0, scale_y, box[1]]], np.float32)
        patch = cv2.warpAffine(
            frame, warp, (size, size), flags=cv2.INTER_AREA | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE
        )
        grey = patch.astype(np.float32).mean(axis=2).ravel()
        grey -= grey.mean()
        return grey / (np.linalg.norm(grey) + 1e-6)

    def _verify_in_roi(self, frame: np.ndarray, landmarks: np.ndarray) -> np.ndarray | None:
        """Re-detect in a small crop around the face: the detected box (frame pixels) or None."""
        box = self.box_from_landmarks(landmarks)
        side = 2.0 * max(box[2] - box[0], box[3] - box[1])
        centre = np.array([(box[0] + box[2]) / 2.0, (box[1] + box[3]) / 2.0])
        x0, y0 = (int(round(v)) for v in centre - side / 2.0)
        x1, y1 = x0 + int(round(side)), y0 + int(round(side))
        height, width = frame.shape[:2]
        cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        if cx1 - cx0 < 16 or cy1 - cy0 < 16:
            return None
        resize = 200.0 / side  # face (~side/2) becomes ~100 px: above HOG's 80 px window, no upsampling
        crop = cv2.resize(
            frame[cy0:cy1, cx0:cx1],
            (max(1, round((cx1 - cx0) * resize)), max(1, round((cy1 - cy0) * resize))),
            interpolation=cv2.INTER_AREA if resize < 1 else cv2.INTER_LINEAR,
        )
        found = self.detector.detect_boxes(np.ascontiguousarray(crop), upsample=0, min_score=self.roi_min_score)
        best, best_iou = None, 0.3
        for candidate, _ in found:
            candidate = candidate / resize + np.array([cx0, cy0, cx0, cy0], np.float32)
            iou = box_iou(candidate, box)
            if iou > best_iou:
                best, best_iou = candidate, iou
        return best

    def _detect(self, frame: np.ndarray) -> np.ndarray | None:
        self.detections += 1
        faces = self.detector.detect(frame)
        choice = pick_face([face.box for face in faces], self.last_box, self.face_index)
        if choice is None:
            return None
        chosen = faces[choice]
        self._record_relation(chosen.box, chosen.landmarks)
        return chosen.landmarks

    # -- public ------------------------------------------------------------------------------
    def update(self, frame: np.ndarray) -> np.ndarray | None:
        """Track one frame. frame: (H, W, 3) uint8 RGB. Returns (68, 2) float32 or None (missing)."""
        frame = self.checked_frame(frame)
        landmarks = None
        if self.previous is not None:
            candidate = predict_landmarks(frame, self.box_from_landmarks(self.previous))
            patch = self._face_patch(frame, candidate)
            similar = self._patch is None or float(patch @ self._patch) >= self.min_patch_correlation
            if similar and self._plausible(candidate, self.previous, frame.shape):
                landmarks = candidate
                self._since_verify += 1
                if self.verify_every > 0 and self._since_verify >= self.verify_every:
                    self._since_verify = 0
                    detected_box = self._verify_in_roi(frame, landmarks)
                    if detected_box is None:
                        landmarks = None
                    else:  # re-anchor on the detector's box
                        landmarks = predict_landmarks(frame, detected_box)
                        self._record_relation(detected_box, landmarks)
        if landmarks is None:
            landmarks = self._detect(frame)
            self._since_verify = 0
        self.previous = landmarks
        self._patch = None if landmarks is None else self._face_patch(frame, landmarks)
        if landmarks is not None:
            self.last_box = self.box_from_landmarks(landmarks)
        return landmarks
