"""The bundled real example: two GRID corpus speakers, CC BY 4.0 (attribution and provenance in NOTICE.md here).

``lsr demo`` re-enacts ``REAL_SOURCE`` with ``REAL_DRIVER``; the app's example person and driver are made from
the same two clips (``app.examples``), the example person's shots by ``example_shots`` (the web site's too,
``lsr export --web``).
"""

from __future__ import annotations

from pathlib import Path

EXAMPLES = Path(__file__).resolve().parent
REAL_SOURCE = EXAMPLES / "grid_brbk7n.mp4"
"""The source person: a GRID corpus speaker (a woman), 75 frames, 360x288, 25 fps, no audio."""
REAL_DRIVER = EXAMPLES / "grid_sbia1a.mp4"
"""The driver: another GRID corpus speaker (a man), 75 frames, 360x288, 25 fps, no audio."""
REAL_EXAMPLE = ("two GRID corpus speakers (Cooke, Barker, Cunningham and Shao, 2006; CC BY 4.0; "
                "lsr/examples/NOTICE.md), both among the default model's training people")
"""One line for users: which example this is and under which licence."""

EXAMPLE_SHOTS = 4
"""How many shots of ``REAL_SOURCE`` make the example person."""


def example_shots(count: int = EXAMPLE_SHOTS) -> list:
    """The example person's shots: ``count`` frames (H, W, 3) uint8 RGB of ``REAL_SOURCE``, spread evenly over the
    clip, so that head pose and expression differ between them."""
    import numpy as np

    from landmarks.io.video import iter_frames

    frames = list(iter_frames(REAL_SOURCE))
    return [frames[index] for index in np.linspace(0, len(frames) - 1, count).round().astype(int)]
