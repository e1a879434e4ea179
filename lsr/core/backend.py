"""What a runtime supplies to the shared frame loop (``lsr.core.engine``): the two networks of LSR as numpy
functions. ``lsr.pipeline.TorchBackend`` runs them with torch, ``deploy.runtime`` with onnxruntime."""

from __future__ import annotations

from typing import Literal, Protocol

import numpy as np

LayoutKind = Literal["none", "latent", "segmentation"]


class SynthesisBackend(Protocol):
    """The two networks of LSR as numpy functions (thesis §4.3: E once per subject, G per frame)."""

    resolution: int
    """Crop side S of the model."""
    layout_kind: LayoutKind
    """What the layout output is: 'none' (variant has none), 'latent' (C_l latent maps), 'segmentation' (19 classes)."""
    warp_references: int
    """N > 0: a warp-guided model; ``synthesize`` also takes the N nearest shots warped onto the target (0 = none)."""

    def encode_subject(self, shots: np.ndarray, shot_landmark_images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """shots, shot_landmark_images: (1, K, 3, S, S) float32 in [-1, 1] -> (layout_latent, style_latent), (1, D) each."""
        ...

    def synthesize(
        self, landmark_image: np.ndarray, layout_latent: np.ndarray, style_latent: np.ndarray, with_layout: bool,
        references: np.ndarray | None = None, reference_masks: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """landmark_image (1, 3, S, S) in [-1, 1], latents (1, D) [, references (1, N, 3, C, C) in [-1, 1] and
        reference_masks (1, N, 1, C, C), warp-guided models, C >= S] -> (image (1, 3, C, C) in [-1, 1] (C = S
        without references), layout (1, C_l, S, S) or None)."""
        ...

    # A backend with a mouth generator (``models_def.part_generator``) also has
    #   mouth_generator_size: int (its window side P; 0 or absent: none) and
    #   draw_mouth(window (1, 3, P, P) in [-1, 1], masks (1, 2, P, P) in [0, 1]) -> (1, 3, P, P) in [-1, 1].
