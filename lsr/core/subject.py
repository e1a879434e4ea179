"""An encoded subject: its K shots, their averaged latents, and what is read off its shots once (lids at rest,
irises, the anchor's gaze) for every frame it is driven in. ``lsr.core.engine.ReenactorBase.encode_subject`` makes
it; the frame loop, the live session and the web export read it. Torch-free."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from landmarks.drawn_lids import shot_lid_gaps
from landmarks.iris import gaze_offsets, iris_donor
from lsr.core.parts import found_irises, shot_irises
from lsr.core.sources import SubjectShots


@dataclasses.dataclass
class Subject:
    """An encoded subject: its K shots and averaged latents (thesis eq. 4.3: z = 1/K sum_i E(I_i))."""

    shots: SubjectShots
    layout_latent: np.ndarray
    """(1, D) float32."""
    style_latent: np.ndarray
    """(1, D) float32."""
    source: str | None
    """Resolved source path when the source was one file or folder (decides the default mode)."""

    @functools.cached_property
    def lid_gaps(self) -> np.ndarray:
        """(2,) its lids at rest, the median lid gaps of its shots (``landmarks.drawn_lids.shot_lid_gaps``)."""
        return shot_lid_gaps(self.shots.landmarks)

    @functools.cached_property
    def found_irises(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Its shots' irises (K, 2, 4) and their eyes' median open apertures (``lsr.core.parts.found_irises``): the
        iris net runs on its shots once, on first use."""
        return found_irises(self.shots.frames, self.shots.landmarks)

    @functools.cached_property
    def shot_irises(self) -> np.ndarray:
        """(K, 2, 2) each shot's iris centres in its crop pixels (``lsr.core.parts.shot_irises``), for ``eyes``
        "warped"."""
        return shot_irises(self.shots.frames, self.shots.landmarks, self.found_irises)

    @functools.cached_property
    def anchor_gaze(self) -> np.ndarray:
        """(2, 2) the anchor shot's gaze (``landmarks.iris.gaze_offsets``, NaN where not found): where relative
        motion starts the gaze from."""
        anchor = self.shots.anchor
        return gaze_offsets(self.found_irises[0][anchor], self.shots.landmarks[anchor])

    @functools.cached_property
    def irises(self) -> tuple:
        """(the irises drawn into its frames, ``landmarks.iris.iris_donor``, or None; ``anchor_gaze``), found on
        first use."""
        return iris_donor(self.shots.frames, self.shots.landmarks, self.found_irises[0]), self.anchor_gaze

    @property
    def reference_landmarks(self) -> np.ndarray:
        """(68, 2) crop landmarks of the anchor shot (the most neutral): the face relative motion is applied to."""
        return self.shots.landmarks[self.shots.anchor]

    @property
    def reference_mesh(self) -> np.ndarray | None:
        """(468, 3) crop mesh of the anchor shot, or None when the shots have no meshes."""
        meshes = self.shots.meshes
        if meshes is None or not np.isfinite(meshes[self.shots.anchor]).all():
            return None
        return meshes[self.shots.anchor]
