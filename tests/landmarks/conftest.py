"""Fixtures shared by the landmarks tests: a real public-domain face photo and one cached detector."""

from __future__ import annotations

import numpy as np
import pytest
import skimage.data

from landmarks.detect import FaceDetector


@pytest.fixture(scope="session")
def astronaut() -> np.ndarray:
    """scikit-image's public-domain astronaut photo: (512, 512, 3) uint8 RGB with exactly one face."""
    return skimage.data.astronaut()


@pytest.fixture(scope="session")
def detector() -> FaceDetector:
    return FaceDetector()
