"""Locate and load dlib model files (from the ``face_recognition_models`` package), once.

The package is found with ``importlib.util.find_spec`` and never imported: its
``__init__`` needs ``pkg_resources``, which recent setuptools no longer ships.
Loaded dlib objects are cached per process, so the 100 MB shape predictor is read
from disk on first use only.
"""

from __future__ import annotations

import functools
import importlib.util
import threading
from pathlib import Path
from typing import Any

from landmarks.exceptions import ModelFilesError

SHAPE_PREDICTOR_68 = "shape_predictor_68_face_landmarks.dat"
CNN_FACE_DETECTOR = "mmod_human_face_detector.dat"
FACE_RECOGNITION_RESNET = "dlib_face_recognition_resnet_model_v1.dat"

_INSTALL_HINT = "install them with `pip install face_recognition_models`"


def models_dir() -> Path:
    """Folder holding the dlib ``.dat`` files of ``face_recognition_models``."""
    try:
        spec = importlib.util.find_spec("face_recognition_models")
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        raise ModelFilesError(
            f"dlib model files not found (package face_recognition_models is missing); {_INSTALL_HINT}"
        )
    return Path(list(spec.submodule_search_locations)[0]) / "models"


def model_path(filename: str) -> Path:
    """Path of one dlib model file; ModelFilesError when it is absent."""
    path = models_dir() / filename
    if not path.is_file():
        raise ModelFilesError(f"dlib model file {filename} not found in {path.parent}; {_INSTALL_HINT}")
    return path


def _dlib() -> Any:
    try:
        import dlib
    except ImportError as exc:  # dlib-bin is a hard dependency; say how to get it back
        raise ModelFilesError(f"dlib is not importable ({exc}); install it with `pip install dlib-bin`") from exc
    return dlib


DLIB_LOCK = threading.Lock()
"""Held around every call into the shared dlib models: one process serves several streams and runs on threads
(the app's live tab beside batch runs, ``lsr reenact``'s tracking thread), and dlib's object detector keeps a
mutable scanner inside (dlib's docs: concurrent use of one detector is not safe). A 10-minute soak of the app
(``lsr bench soak``) once ended in heap corruption without it; this removes the one sharing known to be unsafe."""


@functools.lru_cache(maxsize=None)
def hog_face_detector() -> Any:
    """dlib's HOG + linear SVM frontal face detector (no file needed)."""
    return _dlib().get_frontal_face_detector()


@functools.lru_cache(maxsize=None)
def cnn_face_detector() -> Any:
    """dlib's CNN (max-margin object detection) face detector."""
    return _dlib().cnn_face_detection_model_v1(str(model_path(CNN_FACE_DETECTOR)))


@functools.lru_cache(maxsize=None)
def shape_predictor_68() -> Any:
    """dlib's iBUG-68 shape predictor (ensemble of regression trees)."""
    return _dlib().shape_predictor(str(model_path(SHAPE_PREDICTOR_68)))


@functools.lru_cache(maxsize=None)
def face_recognizer() -> Any:
    """dlib's ResNet face recogniser (128-D descriptors; ``landmarks.detect.same_person``)."""
    return _dlib().face_recognition_model_v1(str(model_path(FACE_RECOGNITION_RESNET)))
