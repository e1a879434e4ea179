"""A trained LSR model as an evaluation ``Method`` (``lsr.eval.protocol.Method``), over ``lsr.pipeline``.

Shots and targets arrive at the evaluation resolution S (224 for the FSTH sample); the model
runs at its own resolution R: shots are resized to R (landmarks scaled with the pixel-centre
convention), outputs resized back to S. ``finetune`` returns a fresh subject-specific copy
(thesis §4.3.5: G^l, G^s and D fine-tuned on the K shots only), so identities never share weights.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import cv2
import numpy as np

from lsr.eval.baselines import check_method_inputs


def scale_points(points: np.ndarray, scale: float) -> np.ndarray:
    """x, y pixel centres at integers: (p + 0.5) * scale - 0.5."""
    return (np.asarray(points, np.float64) + 0.5) * scale - 0.5


def _resize(image: np.ndarray, size: int) -> np.ndarray:
    if image.shape[0] == size:
        return image
    interpolation = cv2.INTER_AREA if image.shape[0] > size else cv2.INTER_LINEAR
    return cv2.resize(image, (size, size), interpolation=interpolation)


class LsrModelMethod:
    """weights: model folder (config.json + model.safetensors). finetune_steps: steps of subject
    fine-tuning when the runner asks for the fine-tuned variant (0 = the method has no ``finetune``)."""

    def __init__(self, weights: str | os.PathLike, *, device: str = "cpu", finetune_steps: int = 0,
                 finetune_lr: float = 1e-4, name: str | None = None) -> None:  # fmt: skip
        from lsr.pipeline import Reenactor

        self.weights = Path(weights)
        self.device = device
        self.finetune_steps = finetune_steps
        self.finetune_lr = finetune_lr
        self.name = name or f"lsr:{self.weights.name}"
        self.reenactor = Reenactor(self.weights, device=device)
        self._encoded: bytes | None = None
        if finetune_steps <= 0:
            self.finetune = None  # type: ignore[assignment]  # the runner then evaluates the meta-learned model only

    def _encode(self, shots: list[np.ndarray], shot_landmarks: np.ndarray) -> float:
        """Encode the K shots at the model resolution (once per distinct shot set); returns R / S."""
        from lsr.pipeline import subject_shots_from_training

        size = self.reenactor.resolution
        scale = size / shots[0].shape[0]
        key = hashlib.blake2b(b"".join(s.tobytes() for s in shots) + shot_landmarks.tobytes(), digest_size=16).digest()
        if key != self._encoded:
            frames = np.stack([_resize(shot, size) for shot in shots])
            self.reenactor.encode_subject(subject_shots_from_training(frames, scale_points(shot_landmarks, scale)))
            self._encoded = key
        return scale

    def reenact(self, shots: list[np.ndarray], shot_landmarks: np.ndarray, target_landmarks: np.ndarray) -> np.ndarray:
        """shots: K x (S, S, 3) uint8; shot_landmarks: (K, 68, 2); target_landmarks: (T, 68, 2) -> (T, S, S, 3) uint8."""
        check_method_inputs(shots, shot_landmarks, target_landmarks)
        scale = self._encode(shots, shot_landmarks)
        size = shots[0].shape[0]
        outputs = [_resize(self.reenactor.synthesize_crop(scale_points(points, scale))[0], size) for points in target_landmarks]
        return np.stack(outputs) if outputs else np.zeros((0, size, size, 3), np.uint8)

    def finetune(self, shots: list[np.ndarray], shot_landmarks: np.ndarray) -> LsrModelMethod:
        """A subject-specific copy fine-tuned on the shots only (fresh weights from disk each time)."""
        check_method_inputs(shots, shot_landmarks, shot_landmarks)
        subject = LsrModelMethod(self.weights, device=self.device, name=self.name)
        subject._encode(shots, shot_landmarks)
        subject.reenactor.finetune(self.finetune_steps, lr=self.finetune_lr, batch_size=min(4, len(shots)))
        return subject
