"""Shared test doubles of the evaluation tests."""

from __future__ import annotations

import pytest


class NoFaceDetector:
    """Stands in for dlib's detector (slow, and it finds no faces on tiny untrained outputs anyway)."""

    kind, max_side, upsample, min_score = "fake", 64, 0, 0.0

    def __init__(self, *args, **kwargs) -> None:
        pass

    def detect(self, image):
        return []


@pytest.fixture
def no_face_detector() -> type[NoFaceDetector]:
    """The class (tests instantiate it, or put it in place of landmarks.detect.FaceDetector)."""
    return NoFaceDetector
