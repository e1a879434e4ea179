"""The mouth step after the frame synthesis (issues 23 and 40), torch-free: the nearest warped shot's mouth, and
the mouth drawn by a part generator over it.

``finish_mouth`` applies a reenactor's ``mouth`` choice (``MOUTHS``). ``draw_mouth`` cuts the mouth's window out of the synthesised crop (``landmarks.part_window``), gives it and the
target's lip masks to the backend's part generator (``models_def.part_generator``: the torch module or its ONNX
graph) and pastes the drawn window back under a feathered mask around the lips. The window is level with the
eyes and at the generator's own resolution whatever the crop's size.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lsr.core.images import from_network, to_network
from landmarks.part_window import (MOUTH, PartWindow, extract, lip_masks, paste, paste_weight, to_window,
                                   window_eye_distance, window_transform)

PartRunner = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""(window (1, 3, P, P) float32 in [-1, 1], masks (1, 2, P, P) float32 in [0, 1]) -> (1, 3, P, P) in [-1, 1]."""
MOUTHS = ("drawn", "nearest", "blend")
"""A warp-guided model's mouth: the nearest warped shot's where the target opens it wider than the shots, then
redrawn by the mouth generator ("drawn"); without the redrawing ("nearest"); the network's blend alone ("blend")."""


def draws_mouth(backend: object) -> bool:
    """Whether ``backend`` has a mouth generator (``SynthesisBackend.draw_mouth``, ``mouth_generator_size`` > 0)."""
    return getattr(backend, "mouth_generator_size", 0) > 0


def finish_mouth(image: np.ndarray, mouth: str, inputs: dict[str, np.ndarray], crop_landmarks: np.ndarray,
                 shot_landmarks: np.ndarray, warp_references: int, backend) -> np.ndarray:
    """The synthesis ``image`` (C, C, 3) uint8 with its mouth as ``mouth`` says: "nearest" and "drawn" take the
    nearest warped shot's (``inputs``' first reference) as far as ``landmarks.nearest_mouth.mouth_strength`` says;
    "drawn" then redraws it with ``backend.draw_mouth``; "blend" leaves it. crop_landmarks: (68, 2) target pixels;
    shot_landmarks: (K, 68, 2) the subject's shots'."""
    if mouth in ("nearest", "drawn") and "references" in inputs:
        from landmarks.nearest_mouth import keep_nearest_mouth, mouth_strength

        strength = mouth_strength(crop_landmarks, shot_landmarks, warp_references)
        if strength > 0:  # most frames: the shots show this mouth, so the reference is not even converted
            image = keep_nearest_mouth(image, from_network(inputs["references"][0, 0]),
                                       inputs["reference_masks"][0, 0, 0], crop_landmarks, strength)
    if mouth == "drawn":
        image = draw_mouth(image, crop_landmarks, backend.draw_mouth)
    return image


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
    return to_network(window)[None], lip_masks(points, part.size)[None], points, transform


def draw_mouth(image: np.ndarray, crop_landmarks: np.ndarray, run: PartRunner, part: PartWindow = MOUTH) -> np.ndarray:
    """``image`` (C, C, 3) uint8 with its mouth redrawn by ``run`` for the target's landmarks (68, 2) in crop
    pixels; a new array (``image`` itself when the landmarks are not finite)."""
    found = mouth_inputs(image, crop_landmarks, part)
    if found is None:
        return image
    window, masks, points, transform = found
    drawn = from_network(run(window, masks)[0])
    return paste(image, drawn, paste_weight(points, part.size, window_eye_distance(part)), transform)
