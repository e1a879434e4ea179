"""A person's matte: MediaPipe's selfie segmenter on onnxruntime (for issue 40's turn matte: what moves with the
head, hair included, against what stays).

The net (``selfie_segmentation.onnx``, converted from the same pinned MediaPipe wheel as the face models:
``landmarks.detect.rebuild_mediapipe``) takes the whole frame squashed to 256x256 RGB in [0, 1] and returns the
probability that each pixel is a person. ``person_matte`` resizes it back to the frame's size.
"""

from __future__ import annotations

import cv2
import numpy as np

from landmarks.detect.mediapipe_mesh import session

SEGMENTER_FILE = "selfie_segmentation.onnx"
SEGMENTER_SIZE = 256


def person_matte(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB -> (H, W) float32 in [0, 1]: how much each pixel is a person (hair and clothes too)."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8 or min(image.shape[:2]) < 1:
        raise ValueError(f"image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
    height, width = image.shape[:2]
    small = cv2.resize(image, (SEGMENTER_SIZE, SEGMENTER_SIZE),
                       interpolation=cv2.INTER_AREA if min(height, width) > SEGMENTER_SIZE else cv2.INTER_LINEAR)
    net = session(SEGMENTER_FILE)
    matte = net.run(None, {net.get_inputs()[0].name: (small.astype(np.float32) / 255.0)[None]})[0][0, :, :, 0]
    return np.clip(cv2.resize(matte, (width, height), interpolation=cv2.INTER_LINEAR), 0.0, 1.0).astype(np.float32)


def scene_layers(image: np.ndarray, landmarks: np.ndarray):
    """A scene frame's layers for ``landmarks.scene.compositing.composite_face``: its person matte (``person_matte``) and the
    background plate made from it (``landmarks.scene.compositing.background_plate``). image: (H, W, 3) uint8 RGB; landmarks:
    (68, 2) frame pixels of its face -> ``landmarks.scene.compositing.SceneLayers``."""
    from landmarks.scene.compositing import background_plate

    return background_plate(image, landmarks, person_matte(image))
