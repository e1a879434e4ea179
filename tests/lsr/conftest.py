"""Shared test doubles of the evaluation tests."""

from __future__ import annotations

import pytest


class NoFaceDetector:
    """Stands in for dlib's detector (slow, and it finds no faces on tiny untrained outputs anyway)."""

    kind, settings = "fake", "fake"

    def __init__(self, *args, **kwargs) -> None:
        pass

    def detect(self, image):
        return []

    def more_sensitive(self):
        return None


@pytest.fixture
def no_face_detector() -> type[NoFaceDetector]:
    """The class (tests instantiate it, or put it in place of landmarks.detect.registry.make_detector)."""
    return NoFaceDetector
