"""Fixtures shared by the landmarks tests: a real public-domain face photo and cached detectors."""

from __future__ import annotations

import numpy as np
import pytest
import skimage.data

from landmarks.detect.face_detector import DlibDetector
from landmarks.detect.mediapipe_tracker import MeshDetector


@pytest.fixture(scope="session")
def astronaut() -> np.ndarray:
    """scikit-image's public-domain astronaut photo: (512, 512, 3) uint8 RGB with exactly one face."""
    return skimage.data.astronaut()


@pytest.fixture(scope="session")
def detector() -> DlibDetector:
    """dlib's HOG detector (the tests of landmarks.detect.face_detector and landmarks.detect.dlib_tracker are about it)."""
    return DlibDetector()


@pytest.fixture(scope="session")
def mesh_detector() -> MeshDetector:
    """The default detector: MediaPipe's detector and face mesh."""
    return MeshDetector()
