"""Face detectors: the common interface (``FaceDetector``, ``Face``) and dlib's HOG / CNN detector with its
68-point shape predictor (``DlibDetector``). The default detector is MediaPipe's, in ``landmarks.detect.mediapipe_tracker``;
``landmarks.detect.registry.make_detector`` builds either by name.

dlib's 68-point model is licensed for non-commercial use only; the mesh detector is Apache-2.0.

Detection runs on a copy downscaled to ``max_side`` (HOG cost grows with pixel
count); the shape predictor then runs on the full-resolution image inside the
box scaled back up, so landmarks are always in original pixel coordinates.

Shapes: images are (H, W, 3) uint8 RGB (anything else goes through
``to_rgb_uint8``); boxes are (4,) float32 x0, y0, x1, y1; landmarks are
(68, 2) float32 x, y pixel coordinates.
"""

from __future__ import annotations

import abc
import dataclasses
import os
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from landmarks.detect import dlib_models as models
from landmarks.exceptions import NoFaceError
from landmarks.io.image_files import read_image, to_rgb_uint8
from landmarks.shape.ibug68 import NUM_LANDMARKS

DetectorKind = Literal["mesh", "hog", "cnn"]
"""mesh: MediaPipe's BlazeFace + 468-point mesh on onnxruntime (Apache-2.0, the default); hog / cnn: dlib's
detectors with its 68-point shape predictor (non-commercial model)."""
DEFAULT_DETECTOR: DetectorKind = "mesh"


@dataclasses.dataclass
class Face:
    """One detected face.

    box: (4,) float32 x0, y0, x1, y1 (x1, y1 exclusive); landmarks: (68, 2) float32 x, y;
    score: detector confidence (HOG SVM margin, mmod confidence, or BlazeFace probability);
    mesh: (468, 3) float32 face mesh in the same pixels (the mesh detector's), else None.
    """

    box: np.ndarray
    landmarks: np.ndarray
    score: float
    mesh: np.ndarray | None = None

    @property
    def area(self) -> float:
        return float(max(0.0, self.box[2] - self.box[0]) * max(0.0, self.box[3] - self.box[1]))


def as_image(image: np.ndarray | str | os.PathLike[str]) -> np.ndarray:
    """A path or an image array -> (H, W, 3) uint8 RGB, contiguous (dlib needs that)."""
    if isinstance(image, (str, os.PathLike)):
        return read_image(image)
    return to_rgb_uint8(image)


def predict_landmarks(image: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Run the 68-point shape predictor inside ``box``.

    image: (H, W, 3) uint8 RGB, contiguous; box: (4,) x0, y0, x1, y1 (x1, y1 exclusive) in its
    pixels, may reach outside the image. Returns (68, 2) float32 x, y.
    """
    import dlib

    x0, y0, x1, y1 = (int(round(float(v))) for v in box)
    # dlib rectangles are inclusive of right/bottom.
    predictor = models.shape_predictor_68()
    with models.DLIB_LOCK:
        shape = predictor(image, dlib.rectangle(x0, y0, x1 - 1, y1 - 1))
    points = np.empty((NUM_LANDMARKS, 2), dtype=np.float32)
    for index, part in enumerate(shape.parts()):
        points[index] = (part.x, part.y)
    return points


def auto_upsample(max_side: int) -> int:
    """HOG finds faces of >= ~80 px; upsample so faces of ~1/16 of the detection image's side are found."""
    if max_side >= 1200:
        return 0
    if max_side >= 300:
        return 1
    return 2


class FaceDetector(abc.ABC):
    """What every face detector offers: all faces of an image with their 68 points, the one asked for, and the
    smallest face it can find. ``landmarks.detect.registry.make_tracker`` gives the tracker that goes with it."""

    kind: str

    @abc.abstractmethod
    def detect(self, image: np.ndarray | str | os.PathLike[str]) -> list[Face]:
        """All faces, largest box first. image: path or array (see ``to_rgb_uint8``)."""

    @abc.abstractmethod
    def min_face_size(self, shape: tuple[int, ...]) -> int:
        """About the smallest face width (pixels of an image of ``shape``) this detector finds."""

    @property
    @abc.abstractmethod
    def settings(self) -> str:
        """Everything that changes the detector's output, as a string (keys for cached landmarks)."""

    def more_sensitive(self) -> FaceDetector | None:
        """A slower detector that finds faces this one misses (a ground-truth retry), or None."""
        return None

    def detect_one(
        self, image: np.ndarray | str | os.PathLike[str], face_index: int = 0, name: str | None = None
    ) -> Face:
        """The ``face_index``-th largest face; NoFaceError when there is none (or too few)."""
        if name is None:
            name = Path(image).name if isinstance(image, (str, os.PathLike)) else "the image"
        faces = self.detect(image)
        if not faces:
            raise NoFaceError(f"no face found in {name}; use a photo where the face is visible and well lit")
        if not 0 <= face_index < len(faces):
            raise NoFaceError(
                f"--face-index {face_index} asked for, but only {len(faces)} face(s) found in {name}; "
                f"use a face index from 0 to {len(faces) - 1}"
            )
        return faces[face_index]


class DlibDetector(FaceDetector):
    """dlib face detector + 68-point shape predictor. Models load lazily, once per process.

    kind: "hog" (fast, frontal) or "cnn" (mmod, slower, more robust to pose and light).
    max_side: detection runs on a copy downscaled so its longer side is at most this.
    upsample: dlib's pyramid upsampling count; None picks it from the detection image size
        (``auto_upsample``; one less for the CNN, which is far slower on CPU).
    min_score: detections scoring below are dropped (default 0.2 for HOG, 0 for CNN).
    """

    def __init__(
        self,
        kind: Literal["hog", "cnn"] = "hog",
        max_side: int = 640,
        upsample: int | None = None,
        min_score: float | None = None,
    ) -> None:
        if kind not in ("hog", "cnn"):
            raise ValueError(f"detector kind must be 'hog' or 'cnn', got {kind!r}")
        if max_side < 64:
            raise ValueError(f"max_side must be >= 64, got {max_side}")
        self.kind = kind
        self.max_side = max_side
        self.upsample = upsample
        # HOG SVM margins: false positives seen at ~0.1 (astronaut suit), real faces turned away at ~0.3.
        # mmod confidences are already thresholded at 0.
        self.min_score = (0.2 if kind == "hog" else 0.0) if min_score is None else min_score

    @property
    def settings(self) -> str:
        return f"{self.kind}/{self.max_side}/{self.upsample}/{self.min_score}"

    def more_sensitive(self) -> DlibDetector:
        """One pyramid level up (finds faces half as small, about 4x slower)."""
        upsample = self.upsample if self.upsample is not None else auto_upsample(self.max_side)
        return DlibDetector(kind=self.kind, max_side=self.max_side, upsample=upsample + 1, min_score=self.min_score)

    def min_face_size(self, shape: tuple[int, ...]) -> int:
        """dlib's 80-px window, halved per pyramid upsampling, in the copy scaled to ``max_side``."""
        longer = max(shape[:2])
        scale = min(1.0, self.max_side / longer)
        upsample = self.upsample
        if upsample is None:
            upsample = auto_upsample(round(longer * scale))
            if self.kind == "cnn":
                upsample = max(0, upsample - 1)
        return int(np.ceil(80 / 2**upsample / scale))

    def detect_boxes(
        self, image: np.ndarray, upsample: int | None = None, min_score: float | None = None
    ) -> list[tuple[np.ndarray, float]]:
        """Face boxes only: list of ((4,) float32 box in full-res pixels, score), unsorted.

        image: (H, W, 3) uint8 RGB; upsample and min_score override the detector's settings for this call.
        """
        min_score = self.min_score if min_score is None else min_score
        height, width = image.shape[:2]
        scale = min(1.0, self.max_side / max(height, width))
        small = image
        if scale < 1.0:
            size = (max(1, round(width * scale)), max(1, round(height * scale)))
            small = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        if upsample is None:
            upsample = self.upsample
        if upsample is None:
            upsample = auto_upsample(max(small.shape[:2]))
            if self.kind == "cnn":  # mmod on CPU costs ~4 s per 512x512 pass and 4x per upsampling
                upsample = max(0, upsample - 1)
        found: list[tuple[np.ndarray, float]] = []
        if self.kind == "hog":
            detector = models.hog_face_detector()
            with models.DLIB_LOCK:
                rects, scores, _ = detector.run(small, upsample, min_score)
            pairs = zip(rects, scores)
        else:
            detector = models.cnn_face_detector()
            with models.DLIB_LOCK:
                pairs = [(det.rect, det.confidence) for det in detector(small, upsample)]
        for rect, score in pairs:
            if score < min_score:
                continue
            box = np.array([rect.left(), rect.top(), rect.right() + 1, rect.bottom() + 1], np.float32) / scale
            found.append((box.astype(np.float32), float(score)))
        return found

    def detect(self, image: np.ndarray | str | os.PathLike[str]) -> list[Face]:
        """All faces, largest box first. image: path or array (see ``to_rgb_uint8``)."""
        image = as_image(image)
        faces = []
        for box, score in self.detect_boxes(image):
            landmarks = predict_landmarks(image, box)
            faces.append(Face(box=box, landmarks=landmarks, score=score))
        faces.sort(key=lambda face: face.area, reverse=True)
        return faces
