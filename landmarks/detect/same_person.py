"""Is it the same person? Shots of another person are left out of a subject.

A source video with a cut, or a folder of photos, can show someone else: on the FSTH sample, 3 of id00081's 32
input frames show his interviewer (the video cuts away). Averaged into the latents, warped as references and
picked as the anchor (the scene), such a shot puts another person's face, clothes and scene into the output.

dlib's ResNet face recogniser (``face_recognition_models``; the model's author released it into the public
domain) maps a face to a 128-D descriptor and was trained to put each identity inside a ball of radius
``SAME_PERSON_RADIUS`` = 0.6. ``same_person`` keeps the shots within that radius of the medoid (the shot nearest
to all the others); with no majority there it keeps every shot, and faces turned beyond ``TURNED_YAW`` are kept
unjudged. Measured with the default detector's landmarks: the shot farthest from its person's medoid is 0.56 away
over 56 training people (``real_talking_heads``, 32 frames each) and 0.57 over the FSTH sample's other 4 people;
id00081's interviewer frames are 0.75-0.80 away.

numpy + dlib; without dlib nothing is checked (``available``), and the callers say so.
"""

from __future__ import annotations

import numpy as np

from landmarks.detect import dlib_models as models
from landmarks.exceptions import ModelFilesError
from landmarks.shape.ibug68 import NUM_LANDMARKS

DESCRIPTOR_SIZE = 128
SAME_PERSON_RADIUS = 0.6
"""dlib's: its recogniser was trained to put each identity inside a ball of this radius (Euclidean, raw descriptors)."""
TURNED_YAW = 45.0
"""Degrees: a face turned further hides its far eye, and dlib's chip (aligned from the eyes and nose) and descriptor
drift with it (the same person in profile came 0.61 from his frontal medoid): such faces are kept, not judged."""


def available() -> bool:
    """dlib and its face-recognition model can be loaded."""
    try:
        models.face_recognizer()
    except ModelFilesError:
        return False
    return True


def face_descriptor(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """dlib's 128-D descriptor of the face ``landmarks`` outline (dlib aligns its face chip from them).

    image: (H, W, 3) uint8 RGB; landmarks: (68, 2) finite x, y pixels on that image -> (128,) float64, not
    normalised (``SAME_PERSON_RADIUS`` is a distance between these). Raises ``ModelFilesError`` without dlib."""
    points = np.asarray(landmarks, np.float64)
    if points.shape != (NUM_LANDMARKS, 2) or not np.all(np.isfinite(points)):
        raise ValueError(f"face_descriptor needs ({NUM_LANDMARKS}, 2) finite landmarks, got {points.shape}")
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"face_descriptor needs an (H, W, 3) uint8 image, got {image.shape} {image.dtype}")
    recognizer = models.face_recognizer()  # ModelFilesError without dlib or its model
    import dlib

    x0, y0 = np.floor(points.min(axis=0)).astype(int)
    x1, y1 = np.ceil(points.max(axis=0)).astype(int)
    shape = dlib.full_object_detection(dlib.rectangle(int(x0), int(y0), int(x1), int(y1)),
                                       [dlib.point(int(round(x)), int(round(y))) for x, y in points])
    with models.DLIB_LOCK:
        return np.array(recognizer.compute_face_descriptor(np.ascontiguousarray(image), shape), np.float64)


def judged(landmarks: np.ndarray, image_shape: tuple[int, ...]) -> bool:
    """Whether a face can be judged: its (68, 2) landmarks are finite and it is turned less than ``TURNED_YAW``."""
    from landmarks.motion.head_pose import estimate_head_pose

    points = np.asarray(landmarks, np.float64)
    if not np.isfinite(points).all():
        return False
    return bool(abs(float(estimate_head_pose(points, tuple(image_shape[:2]))[0])) < TURNED_YAW)


def face_descriptors(images, landmarks) -> np.ndarray:
    """``face_descriptor`` of each face that can be ``judged``, NaN rows for the others. images: N x (H, W, 3)
    uint8; landmarks: (N, 68, 2) -> (N, 128) float64. Raises ``ModelFilesError`` without dlib."""
    descriptors = np.full((len(images), DESCRIPTOR_SIZE), np.nan)
    for index, (image, points) in enumerate(zip(images, landmarks)):
        if judged(points, image.shape):
            descriptors[index] = face_descriptor(image, points)
    return descriptors


def medoid(descriptors: np.ndarray) -> int | None:
    """Index of the finite descriptor with the smallest summed distance to the other finite ones (None: none)."""
    known = np.flatnonzero(np.isfinite(descriptors).all(axis=1))
    if not len(known):
        return None
    points = descriptors[known]
    return int(known[np.linalg.norm(points[:, None] - points[None], axis=-1).sum(axis=1).argmin()])


def same_person(descriptors: np.ndarray, radius: float = SAME_PERSON_RADIUS) -> np.ndarray:
    """Which faces are the majority's person: within ``radius`` of the medoid (the descriptor with the smallest
    summed distance to the others). descriptors: (N, D), NaN rows = unknown (kept) -> (N,) bool. Every face is
    kept when at most half would be (no majority to call the person)."""
    descriptors = np.asarray(descriptors, np.float64)
    known = np.flatnonzero(np.isfinite(descriptors).all(axis=1))
    keep = np.ones(len(descriptors), bool)
    if len(known) < 3:
        return keep
    near = np.linalg.norm(descriptors[known] - descriptors[medoid(descriptors)], axis=-1) <= radius
    if near.sum() * 2 > len(known):
        keep[known[~near]] = False
    return keep
