"""Contact sheet of synthetic frames: frame | frame + landmark dots | landmark image | class map."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from landmarks.shape.raster import draw_landmarks
from lsr.data.classes import colorize_segmentation
from lsr.data.synth.generate import identity_seed_of, render_video


def overlay_points(frame: np.ndarray, landmarks: np.ndarray, visible: np.ndarray | None = None) -> np.ndarray:
    """Frame (S, S, 3) uint8 with the 68 points as dots (hidden points hollow). Returns a copy."""
    out = frame.copy()
    radius = max(1, frame.shape[0] // 128)
    for index, (x, y) in enumerate(landmarks):
        if not np.isfinite([x, y]).all():
            continue
        colour = (0, 255, 0) if index < 17 else (255, 40, 40)
        filled = -1 if visible is None or visible[index] else 1
        cv2.circle(out, (int(round(x)), int(round(y))), radius, colour, filled, lineType=cv2.LINE_AA)
    return out


def contact_sheet(rows: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]]) -> np.ndarray:
    """rows of (frame (S,S,3) uint8, landmarks (68,2), segmentation (S,S) uint8, visible (68,) or None) -> RGB sheet."""
    tiles = []
    for frame, landmarks, segmentation, visible in rows:
        size = frame.shape[0]
        tiles.append(
            np.concatenate(
                [frame, overlay_points(frame, landmarks, visible), draw_landmarks(landmarks, size), colorize_segmentation(segmentation)],
                axis=1,
            )
        )
    return np.concatenate(tiles, axis=0)


def write_preview(path: str | Path, identities: int = 6, size: int = 128, seed: int = 0, preset: str = "default", frames: int = 24) -> Path:
    """Render ``identities`` people (one sampled frame each, spread over the clip) and write the sheet PNG atomically."""
    from landmarks.io.image_files import write_image

    rows = []
    for i in range(identities):
        clip = render_video(identity_seed_of(seed, i), frames, size, preset)
        index = (i * 5) % frames
        rows.append((clip.frames[index], clip.landmarks[index], clip.segmentation[index], clip.visible[index]))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, contact_sheet(rows))
    return path
