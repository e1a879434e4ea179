"""ID-SIM: cosine similarity of face-recognition embeddings (thesis §4.4 "Metrics").

The thesis uses a VGGFace-style network [81]; those weights cannot be downloaded here, so
this toolkit uses dlib's ResNet face recogniser (``dlib_face_recognition_resnet_model_v1.dat``
from ``face_recognition_models``: 128-D embeddings, 99.38% on LFW). Numbers are therefore
comparable between methods evaluated by this toolkit, not to the thesis' absolute ID-SIM
values. Faces are aligned by dlib from a 68-point shape (``compute_face_descriptor(img, shape)``).
"""

from __future__ import annotations

import numpy as np

from landmarks.detect import same_person as identity
from landmarks.exceptions import ModelFilesError
from lsr.errors import WeightsError
from lsr.eval.metrics import check_landmarks

EMBEDDING_SIZE = identity.DESCRIPTOR_SIZE
EMBEDDER_NAME = "dlib ResNet face recognition v1 (128-D), stands in for the thesis' VGGFace"


def face_descriptor(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """dlib's raw 128-D descriptor (``landmarks.detect.same_person.face_descriptor``); ``WeightsError`` without dlib's model."""
    try:
        return identity.face_descriptor(image, check_landmarks(landmarks))
    except ModelFilesError as exc:
        raise WeightsError(f"ID-SIM needs dlib's face recognition model: {exc}") from exc


def unit(descriptor: np.ndarray) -> np.ndarray:
    """The descriptor scaled to norm 1 (what ID-SIM compares)."""
    return descriptor / max(float(np.linalg.norm(descriptor)), 1e-12)


def face_embedding(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Unit-norm 128-D embedding of the face described by ``landmarks``.

    image: (H, W, 3) uint8 RGB; landmarks: (68, 2) x, y pixels on that image (dlib aligns the
    face chip from them). Returns (128,) float64 with norm 1.
    """
    return unit(face_descriptor(image, landmarks))


def cosine_similarity(first: np.ndarray, second: np.ndarray) -> float:
    """Cosine similarity of two embeddings (any norm). first, second: (D,)."""
    first = np.asarray(first, dtype=np.float64)
    second = np.asarray(second, dtype=np.float64)
    denominator = float(np.linalg.norm(first) * np.linalg.norm(second))
    return float(first @ second / denominator) if denominator > 0 else float("nan")


def mean_embedding(embeddings: np.ndarray) -> np.ndarray:
    """Identity embedding of several frames: the renormalised mean. embeddings: (N, 128) -> (128,)."""
    embeddings = np.asarray(embeddings, dtype=np.float64)
    embeddings = embeddings[np.all(np.isfinite(embeddings), axis=1)]
    if embeddings.size == 0:
        return np.full(EMBEDDING_SIZE, np.nan)
    mean = embeddings.mean(axis=0)
    return mean / max(float(np.linalg.norm(mean)), 1e-12)
