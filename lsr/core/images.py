"""Pictures to and from the networks' tensors, and the pass-through picture of crop-sized output (numpy + OpenCV)."""

from __future__ import annotations

import cv2
import numpy as np


def to_network(images: np.ndarray) -> np.ndarray:
    """(..., S, S, 3) uint8 -> (..., 3, S, S) float32 in [-1, 1] (black = -1, as in training), C-contiguous (the
    channels moved while still bytes: the runtimes take it without another copy)."""
    values = np.ascontiguousarray(np.moveaxis(images, -1, -3)).astype(np.float32)
    values /= np.float32(127.5)
    values -= np.float32(1.0)
    return values


def from_network(image: np.ndarray) -> np.ndarray:
    """(3, S, S) float in [-1, 1] -> (S, S, 3) uint8."""
    return np.clip(np.rint((np.moveaxis(np.asarray(image, np.float32), 0, -1) + 1.0) * 127.5), 0, 255).astype(np.uint8)


def square_resize(frame: np.ndarray, size: int) -> np.ndarray:
    """Centre square of a frame resized to (size, size): the pass-through picture of crop-sized output."""
    height, width = frame.shape[:2]
    side = min(height, width)
    top, left = (height - side) // 2, (width - side) // 2
    square = frame[top : top + side, left : left + side]
    interpolation = cv2.INTER_AREA if side > size else cv2.INTER_CUBIC
    return cv2.resize(square, (size, size), interpolation=interpolation)
