"""Landmarks, identity descriptors and embeddings of the images ``lsr eval`` reads, memoised (``FaceAnalysis``)."""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np

from landmarks.detect.same_person import DESCRIPTOR_SIZE, judged, same_person
from lsr.eval import idsim


class FaceAnalysis:
    """Landmarks and embeddings of images, memoised by content hash (copies of input frames,
    as the nearest-shot baseline outputs, are analysed once)."""

    def __init__(self, detector: Any) -> None:
        self.detector = detector
        self._landmarks: dict[bytes, np.ndarray | None] = {}
        self._embeddings: dict[bytes, np.ndarray] = {}

    @staticmethod
    def key(image: np.ndarray, extra: bytes = b"") -> bytes:
        return hashlib.blake2b(image.tobytes() + extra, digest_size=16).digest()

    def seed(self, images: np.ndarray, landmarks: np.ndarray) -> None:
        """Register already-detected landmarks (N, 68, 2) for images (N, S, S, 3)."""
        for image, points in zip(images, landmarks):
            self._landmarks[self.key(image)] = points if np.all(np.isfinite(points)) else None

    def landmarks(self, image: np.ndarray) -> np.ndarray | None:
        key = self.key(image)
        if key not in self._landmarks:
            faces = self.detector.detect(image)
            self._landmarks[key] = faces[0].landmarks.astype(np.float32) if faces else None
        return self._landmarks[key]

    def descriptor(self, image: np.ndarray, points: np.ndarray) -> np.ndarray:
        """dlib's raw 128-D descriptor (``landmarks.detect.same_person``), memoised."""
        key = self.key(image, np.asarray(points, np.float32).tobytes())
        if key not in self._embeddings:
            self._embeddings[key] = idsim.face_descriptor(image, points)
        return self._embeddings[key]

    def embedding(self, image: np.ndarray, points: np.ndarray) -> np.ndarray:
        """The unit-norm embedding ID-SIM compares (``lsr.eval.idsim.face_embedding``'s)."""
        return idsim.unit(self.descriptor(image, points))

    def same_person(self, images: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
        """Which frames (N, S, S, 3) show the majority's person (``landmarks.detect.same_person.same_person``; faces turned
        too far to judge count as the person's, NaN landmark rows as not) -> (N,) bool."""
        found = np.isfinite(landmarks).all(axis=(1, 2))
        descriptors = np.full((len(images), DESCRIPTOR_SIZE), np.nan)
        for index in np.flatnonzero(found):
            if judged(landmarks[index], images[index].shape):
                descriptors[index] = self.descriptor(images[index], landmarks[index])
        return same_person(descriptors) & found
