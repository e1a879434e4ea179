"""Which bank entry a driven sequence shows, frame by frame: the nearest, kept until another is clearly nearer, and
cross-faded in when it changes (issue 63: a part that switched exemplars 50 times in 183 frames popped).

Shared by every part bank (``landmarks.parts.eyes.eye_bank``, ``landmarks.parts.mouth.mouth_bank``): each gives, per frame, the
cost of each of its entries against the target's state; ``EntryTrack`` turns the costs into the entry shown.
"""

from __future__ import annotations

import numpy as np

SWITCH = 1.0
"""The track moves to another entry only when its cost is below the kept entry's by this much (hysteresis)."""
FADE = 3
"""Frames over which a changed entry cross-fades in."""


class EntryTrack:
    """The entry a sequence shows (module docstring). ``switches``: how often it changed."""

    def __init__(self, switch: float = SWITCH, fade: int = FADE) -> None:
        if switch < 0 or fade < 0:
            raise ValueError(f"switch and fade must be >= 0, got {switch} and {fade}")
        self.switch, self.fade = float(switch), int(fade)
        self.current: int | None = None
        self.previous: int | None = None
        self.fading = 0  # frames of the cross-fade still to go
        self.switches = 0

    def reset(self) -> None:
        """A gap (no target): the next frame chooses afresh, with no cross-fade."""
        self.current = self.previous = None
        self.fading = 0

    def __call__(self, cost: np.ndarray) -> tuple[int, int | None, float]:
        """One frame's costs (N,) (inf: unusable) -> (the entry shown, the entry it fades from or None, that one's
        weight in [0, 1))."""
        cost = np.asarray(cost, np.float64)
        if cost.ndim != 1 or not len(cost):
            raise ValueError(f"cost must be a non-empty (N,) array, got {cost.shape}")
        best = int(np.argmin(cost))
        if self.current is None or self.current >= len(cost):
            self.current, self.previous, self.fading = best, None, 0
        elif best != self.current and cost[best] < cost[self.current] - self.switch:
            self.previous, self.current, self.fading = self.current, best, self.fade
            self.switches += 1
        if self.fading > 0 and self.previous is not None:
            weight = self.fading / (self.fade + 1)
            self.fading -= 1
            return self.current, self.previous, weight
        return self.current, None, 0.0
