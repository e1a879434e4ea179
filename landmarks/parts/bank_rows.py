"""A bank's rows while it is read from a person's frames, one per usable frame: bounded in memory while a long video
streams by, evenly spread over the frames at the end (shared by ``eye_bank`` and ``mouth_bank``)."""

from __future__ import annotations

import numpy as np


class BankRows:
    """Rows of a bank being built (any tuples). ``add`` keeps at most 4 x ``max_entries`` (every other one when
    full; a None row, a frame that gave none, is skipped); ``spread`` gives at most ``max_entries`` of them, evenly
    spread, in order."""

    def __init__(self, max_entries: int) -> None:
        if max_entries < 1:
            raise ValueError(f"max_entries must be >= 1, got {max_entries}")
        self.max_entries = int(max_entries)
        self.rows: list[tuple] = []

    def add(self, row: tuple | None) -> None:
        if row is None:
            return
        self.rows.append(row)
        if len(self.rows) >= 4 * self.max_entries:  # a long video: every other row, so memory stays bounded
            self.rows = self.rows[::2]

    def spread(self) -> list[tuple]:
        if len(self.rows) <= self.max_entries:
            return list(self.rows)
        return [self.rows[i] for i in np.linspace(0, len(self.rows) - 1, self.max_entries).round().astype(int)]


def usable_face(frame: np.ndarray, points: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
    """A bank's frame (H, W, 3) uint8 RGB and its 68 points -> (the frame, the points as (68, 2) float64), or None
    where the points are None or not finite (no face: skipped). A frame of another shape or type is a ValueError."""
    from landmarks.shape.measures import finite_points

    points = None if points is None else finite_points(points)
    if points is None:
        return None
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(f"bank frames must be (H, W, 3) uint8, got {frame.shape} {frame.dtype}")
    return frame, points
