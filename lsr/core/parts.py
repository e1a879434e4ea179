"""The mouth drawn by a part generator over the frame synthesis (issue 40), torch-free.

``draw_mouth`` cuts the mouth's window out of the synthesised crop (``landmarks.part_window``), gives it and the
target's lip masks to the backend's part generator (``models_def.part_generator``: the torch module or its ONNX
graph) and pastes the drawn window back under a feathered mask around the lips. The window is level with the
eyes and at the generator's own resolution whatever the crop's size.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from landmarks.part_window import (MOUTH, PartWindow, extract, lip_masks, paste, paste_weight, to_window,
                                   window_eye_distance, window_transform)

PartRunner = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""(window (1, 3, P, P) float32 in [-1, 1], masks (1, 2, P, P) float32 in [0, 1]) -> (1, 3, P, P) in [-1, 1]."""


def mouth_inputs(image: np.ndarray, crop_landmarks: np.ndarray, part: PartWindow = MOUTH
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The part generator's inputs for ``image`` (C, C, 3) uint8 and the target's landmarks (68, 2) in its pixels:
    (window (1, 3, P, P) float32 in [-1, 1], masks (1, 2, P, P) float32, window landmarks (68, 2), transform
    (2, 3) crop -> window), or None when the landmarks are not finite."""
    transform = window_transform(crop_landmarks, part)
    if transform is None:
        return None
    window = extract(image, transform, part.size)
    points = to_window(crop_landmarks, transform)
    tensor = (window.transpose(2, 0, 1)[None].astype(np.float32) / 127.5) - 1.0
    return tensor, lip_masks(points, part.size)[None], points, transform


def draw_mouth(image: np.ndarray, crop_landmarks: np.ndarray, run: PartRunner, part: PartWindow = MOUTH) -> np.ndarray:
    """``image`` (C, C, 3) uint8 with its mouth redrawn by ``run`` for the target's landmarks (68, 2) in crop
    pixels; a new array (``image`` itself when the landmarks are not finite)."""
    found = mouth_inputs(image, crop_landmarks, part)
    if found is None:
        return image
    window, masks, points, transform = found
    drawn = np.asarray(run(window, masks), np.float32)[0]
    drawn = np.clip(np.rint((drawn.transpose(1, 2, 0) + 1.0) * 127.5), 0, 255).astype(np.uint8)
    return paste(image, drawn, paste_weight(points, part.size, window_eye_distance(part)), transform)
