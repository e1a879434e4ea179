"""Shared test fixtures.

Real data lives beside the project at ``../shared/data`` (override with
``LSR_SHARED_DATA``). Tests that need it take the ``shared_data`` fixture and skip
cleanly, with a reason, when it is absent.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    return Path(os.environ.get("LSR_SHARED_DATA", REPO_ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    root = shared_data_dir()
    if not (root / "README.md").is_file():
        pytest.skip(f"shared real data not found at {root} (set LSR_SHARED_DATA to point at it)")
    return root


@pytest.fixture
def rng() -> np.random.Generator:
    """Seeded numpy generator: random test data is reproducible."""
    return np.random.default_rng(0)


DRAWN_SIZE = (512, 512)
SKIN, SCLERA, IRIS = (190, 150, 130), (235, 235, 235), (40, 30, 25)


def _drawn_face(iris_at=(0.0,), mouth: float = 0.0, eyes: float = 1.0, inside=(30, 20, 20)):
    """A drawn face whose answers are known: skin, white eyes whose irises sit at ``iris_at`` (eye widths from the
    corners' midpoint along the eye; several = a doubled iris, each drawn at 1/len of full darkness), the lids'
    gaps times ``eyes``, and a mouth opened to ``mouth`` whose inside is ``inside`` -> (image, its 68 points)."""
    from landmarks.shape.expression import set_mouth_opening
    from landmarks.motion.head_pose import project_canonical

    points = set_mouth_opening(project_canonical(0.0, 0.0, 0.0, DRAWN_SIZE).astype(np.float64), mouth)
    for upper, lower in ((37, 41), (38, 40), (43, 47), (44, 46)):
        middle = (points[upper] + points[lower]) / 2
        points[upper] = middle + (points[upper] - middle) * eyes
        points[lower] = middle + (points[lower] - middle) * eyes
    image = np.full((*DRAWN_SIZE, 3), SKIN, np.uint8)
    for first in (36, 42):
        eye = points[first:first + 6]
        mask = np.zeros(DRAWN_SIZE, np.uint8)
        cv2.fillPoly(mask, [np.round(eye).astype(np.int32)], 1)
        layer = np.full((*DRAWN_SIZE, 3), SCLERA, np.float64)
        width = np.linalg.norm(eye[3] - eye[0])
        for offset in iris_at:
            centre = (eye[0] + eye[3]) / 2 + np.array([offset * width, 0.0])
            disc = np.zeros(DRAWN_SIZE, np.uint8)
            cv2.circle(disc, tuple(int(v) for v in np.round(centre)), int(0.22 * width), 1, -1)
            layer[disc.astype(bool)] += (np.array(IRIS) - np.array(SCLERA)) / len(iris_at)
        image[mask.astype(bool)] = np.clip(layer, 0, 255).astype(np.uint8)[mask.astype(bool)]
    cv2.fillPoly(image, [np.round(points[60:68]).astype(np.int32)], inside)
    return image, points


@pytest.fixture(scope="session")
def drawn_face():
    """``_drawn_face``: (iris_at, mouth, eyes, inside) -> ((512, 512, 3) uint8 picture, its (68, 2) points)."""
    return _drawn_face
