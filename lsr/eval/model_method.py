"""A trained LSR model as an evaluation ``Method`` (``lsr.eval.protocol.Method``), over ``lsr.pipeline``.

Shots and targets arrive at the evaluation resolution S (224 for the FSTH sample); the model
runs at its own resolution R: shots are resized to R (landmarks scaled with the pixel-centre
convention), outputs resized back to S. ``finetune`` returns a fresh subject-specific copy
(thesis §4.3.5: G^l, G^s and D fine-tuned on the K shots only), so identities never share weights.

An ``oracle_seg`` model (thesis Table 4.2's upper bound) is evaluable here, unlike in ``lsr.pipeline``:
the protocol has the hold-outs' ground-truth segmentation, which the method receives as
``target_segmentations`` (it declares ``needs_target_segmentation``) and feeds to G^s in place of G^l.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import cv2
import numpy as np

from lsr.core import DEFAULT_FINETUNE_LR
from lsr.core.finish import set_parts
from lsr.core.inputs import scale_mesh, scale_points
from lsr.errors import ConfigError, WeightsError
from lsr.eval.baselines import check_method_inputs


def _resize(image: np.ndarray, size: int) -> np.ndarray:
    if image.shape[0] == size:
        return image
    interpolation = cv2.INTER_AREA if image.shape[0] > size else cv2.INTER_LINEAR
    return cv2.resize(image, (size, size), interpolation=interpolation)


def _resize_segmentation(segmentation: np.ndarray, size: int) -> np.ndarray:
    """(S, S) class ids -> (size, size); nearest, so ids stay ids."""
    if segmentation.shape[0] == size:
        return segmentation
    return cv2.resize(segmentation, (size, size), interpolation=cv2.INTER_NEAREST)


def load_eval_model(weights: str | os.PathLike):
    """``lsr.pipeline.load_model``, except that an ``oracle_seg`` model loads too (evaluation has its ground truth)."""
    from lsr.pipeline import load_model

    folder = Path(weights)
    config_path = folder / "config.json"
    try:
        variant = json.loads(config_path.read_text()).get("variant") if config_path.is_file() else None
    except (OSError, json.JSONDecodeError, AttributeError):
        variant = None  # load_model reports the broken folder
    if variant != "oracle_seg":
        return load_model(folder)
    from models_def import LSRModel

    try:
        model = LSRModel.from_pretrained(folder)
    except ValueError as exc:  # models_def.ModelConfigError names the problem with the folder
        raise WeightsError(str(exc)) from exc
    return model.eval().requires_grad_(False)


class LsrModelMethod:
    """weights: model folder (config.json + model.safetensors). finetune_steps: steps of subject
    fine-tuning when the runner asks for the fine-tuned variant (0 = the method has no ``finetune``).
    ``variant`` is the model's ablation variant (thesis Table 4.2); an ``oracle_seg`` model needs
    ``target_segmentations`` in ``reenact``."""

    def __init__(self, weights: str | os.PathLike, *, device: str = "cpu", finetune_steps: int = 0,
                 finetune_lr: float = DEFAULT_FINETUNE_LR, name: str | None = None, reenactor=None,
                 reference_warp: str = "mesh", mouth: str | None = None, eyes: str | None = None,
                 mouth_interior: str | None = None, lids: str | None = None,
                 expression_gain: float | None = None, bank: str | None = None) -> None:
        """reenactor: a ready ``ReenactorBase`` (e.g. ``deploy.runtime.OnnxReenactor`` over the bundle at
        ``weights``); None = load the torch model from ``weights``. reference_warp: how a warp-guided model's
        references are warped ("mesh": over the face mesh, given the meshes; "tps": the 68-point TPS). mouth: a
        warp-guided model's mouth ("drawn": redrawn by its mouth generator; "nearest": the nearest warped shot's;
        "blend": the network's; None: the model's default, ``lsr.core.engine.ReenactorBase.mouth``). eyes: "warped"
        (the references' irises carried to where the target looks) or "drawn" (one iris laid where it looks): the
        protocol then passes ``target_gazes``; or "blend" (None: the model's default, ``ReenactorBase.eyes``).
        mouth_interior: "driver" (the driver frame's inside an open mouth: cross-identity, the protocol then passes
        ``driver_mouths``) or "shots" (None: the model's default). lids:
        "driver" (the driver frame's shut eyes: cross-identity, the protocol then passes ``driver_eyes``) or "shots"
        (None: the model's default). expression_gain: how far mesh-warped references carry a shot's mouth toward a
        wider one (``ReenactorBase.expression_gain``; None: the model's default). bank: where its eyes and mouth
        come from ("shots": one real exemplar of the K shots per part and frame, ``landmarks.parts``; "none": the
        synthesis'; None: the model's default)."""
        self.weights = Path(weights)
        self.device = device
        self.finetune_steps = finetune_steps
        self.finetune_lr = finetune_lr
        self.name = name or f"lsr:{self.weights.name}"
        if reenactor is None:
            from lsr.pipeline import Reenactor, load_mouth

            reenactor = Reenactor(load_eval_model(self.weights), device=device, mouth_generator=load_mouth(self.weights))
            reenactor.weights_path = self.weights  # fine-tuning then starts from the saved discriminator
            self.variant: str = reenactor.model.config.variant
        else:
            self.variant = reenactor.backend.config.get("variant", "")
        self.reenactor = reenactor
        reenactor.reference_warp = reference_warp
        # bank "shots": the K shots are every frame the protocol gives (as "all" is here)
        set_parts(reenactor, mouth=mouth, eyes=eyes, mouth_interior=mouth_interior, lids=lids,
                  expression_gain=expression_gain, bank=bank)
        self.uses_gazes = reenactor.eyes != "blend"
        self.uses_driver_mouths = reenactor.mouth_interior == "driver"
        self.uses_driver_eyes = reenactor.lids == "driver"
        self.needs_target_segmentation = self.variant == "oracle_seg"
        # the protocol then passes the shots' and targets' meshes where it has them (TPS references where not)
        self.uses_meshes = bool(reenactor.warp_references) and reference_warp == "mesh"
        self._encoded: bytes | None = None
        if finetune_steps <= 0:
            self.finetune = None  # type: ignore[assignment]  # the runner then evaluates the meta-learned model only

    def _encode(self, shots: list[np.ndarray], shot_landmarks: np.ndarray, shot_meshes: np.ndarray | None = None) -> float:
        """Encode the K shots at the crop side (once per distinct shot set); returns C / S.

        A warp-guided torch model crops at the evaluation side itself (its blend runs at any side >= its
        resolution), so the shots and the outputs are never resampled; other models crop at their resolution."""
        from lsr.pipeline import TorchBackend, subject_shots_from_training

        if self.reenactor.warp_references and isinstance(self.reenactor.backend, TorchBackend):
            if self.reenactor.crop_size != max(shots[0].shape[0], self.reenactor.resolution):
                self.reenactor.crop_size = max(shots[0].shape[0], self.reenactor.resolution)
                self._encoded = None
        size = self.reenactor.crop_size
        scale = size / shots[0].shape[0]
        key = hashlib.blake2b(b"".join(s.tobytes() for s in shots) + shot_landmarks.tobytes()
                              + (b"" if shot_meshes is None else shot_meshes.tobytes()), digest_size=16).digest()
        if key != self._encoded:
            frames = np.stack([_resize(shot, size) for shot in shots])
            meshes = None if shot_meshes is None else scale_mesh(shot_meshes, scale)
            self.reenactor.encode_subject(subject_shots_from_training(frames, scale_points(shot_landmarks, scale), meshes))
            self._encoded = key
        return scale

    def reenact(self, shots: list[np.ndarray], shot_landmarks: np.ndarray, target_landmarks: np.ndarray,
                target_segmentations: np.ndarray | None = None, shot_meshes: np.ndarray | None = None,
                target_meshes: np.ndarray | None = None, target_gazes: np.ndarray | None = None,
                driver_mouths: list | None = None, driver_eyes: list | None = None) -> np.ndarray:
        """shots: K x (S, S, 3) uint8; shot_landmarks: (K, 68, 2); target_landmarks: (T, 68, 2);
        target_segmentations: (T, S, S) uint8 class ids, ground truth of the targets (``oracle_seg`` only);
        shot_meshes (K, 468, 3), target_meshes (T, 468, 3): face meshes for the references' mesh warp (NaN rows:
        none; that target's references are TPS-warped); target_gazes (T, 2, 2): where each target looks
        (``landmarks.parts.eyes.iris.gaze_offsets``; NaN: not found), for drawn eyes; driver_mouths: T x
        ``landmarks.parts.mouth.interior.DriverMouth`` or None, the driving frames' mouths (cross-identity); driver_eyes: T x
        ``landmarks.parts.eyes.driver_lids.DriverEyes`` or None, the driving frames' shut eyes (cross-identity) -> (T, S, S, 3)
        uint8."""
        check_method_inputs(shots, shot_landmarks, target_landmarks)
        scale = self._encode(shots, shot_landmarks, shot_meshes)
        size = shots[0].shape[0]
        if self.needs_target_segmentation:
            return self._reenact_with_oracle(target_landmarks, target_segmentations, scale, size)
        if target_meshes is None:
            target_meshes = np.full((len(target_landmarks), 468, 3), np.nan, np.float32)
        outputs = []
        gazes = [None] * len(target_landmarks) if target_gazes is None else list(target_gazes)
        mouths = [None] * len(target_landmarks) if driver_mouths is None else list(driver_mouths)
        shut = [None] * len(target_landmarks) if driver_eyes is None else list(driver_eyes)
        # the subject's own parts from its bank of the K shots, chosen per frame: the protocol's targets are sparse
        # hold-outs, not a sequence to keep parts steady over. Cross-identity targets (driven: driver frames come with
        # them) were retargeted, their lids as lsr reenact's
        tracks = self.reenactor.part_tracks(self.reenactor.subject, relative=driver_mouths is not None
                                            or driver_eyes is not None)
        for points, mesh, gaze, mouth, eyes in zip(target_landmarks, target_meshes, gazes, mouths, shut, strict=True):
            crop_mesh = scale_mesh(mesh, scale) if np.isfinite(mesh).all() else None
            crop_points = scale_points(points, scale)
            choices = (None, None)
            if tracks is not None:
                tracks.reset()
                choices = tracks(crop_points, gaze)
            image = self.reenactor.synthesize_crop(crop_points, crop_mesh=crop_mesh, gaze=gaze, driver_mouth=mouth,
                                                   driver_eyes=eyes, eye_choice=choices[0],
                                                   mouth_choice=choices[1])[0]
            outputs.append(_resize(image, size))
        return np.stack(outputs) if outputs else np.zeros((0, size, size, 3), np.uint8)

    def _reenact_with_oracle(self, target_landmarks: np.ndarray, target_segmentations: np.ndarray | None,
                             scale: float, size: int) -> np.ndarray:
        """Table 4.2's upper bound: G^s conditioned on the targets' one-hot ground-truth segmentation."""
        from lsr.core.engine import from_network, to_network
        from landmarks.shape.raster import draw_landmarks
        from models_def.config import NUM_SEG_CLASSES

        if target_segmentations is None:
            raise ConfigError(f"{self.name} is an 'oracle_seg' model: it needs the hold-out frames' ground-truth "
                              "segmentation; evaluate it on an lsr dataset with segmentation maps (e.g. one written "
                              "by lsr.data.synth.generate_dataset), or drop it from --weights")
        count = len(target_landmarks)
        if target_segmentations.shape != (count, size, size) or target_segmentations.dtype != np.uint8:
            raise ConfigError(f"target_segmentations must be ({count}, {size}, {size}) uint8, "
                              f"got {target_segmentations.shape} {target_segmentations.dtype}")
        subject = self.reenactor.subject  # encoded by _encode just before
        resolution = self.reenactor.resolution
        eye = np.eye(NUM_SEG_CLASSES, dtype=np.float32)
        outputs = []
        for points, segmentation in zip(target_landmarks, target_segmentations):
            landmark_image = to_network(draw_landmarks(scale_points(points, scale), resolution))[None]  # (1, 3, R, R)
            one_hot = eye[_resize_segmentation(segmentation, resolution)].transpose(2, 0, 1)[None]  # (1, 19, R, R)
            image, _ = self.reenactor.backend.synthesize(
                landmark_image, subject.layout_latent, subject.style_latent, False, oracle_segmentation=one_hot
            )
            outputs.append(_resize(from_network(image[0]), size))
        return np.stack(outputs) if outputs else np.zeros((0, size, size, 3), np.uint8)

    def finetune(self, shots: list[np.ndarray], shot_landmarks: np.ndarray) -> LsrModelMethod:
        """A subject-specific copy fine-tuned on the shots only (fresh weights from disk each time)."""
        check_method_inputs(shots, shot_landmarks, shot_landmarks)
        subject = LsrModelMethod(self.weights, device=self.device, name=self.name,
                                 reference_warp=self.reenactor.reference_warp, mouth=self.reenactor.mouth,
                                 eyes=self.reenactor.eyes, mouth_interior=self.reenactor.mouth_interior,
                                 lids=self.reenactor.lids, expression_gain=self.reenactor.expression_gain,
                                 bank=self.reenactor.bank)
        subject._encode(shots, shot_landmarks)
        from lsr.train.finetune import finetune_reenactor

        finetune_reenactor(subject.reenactor, self.finetune_steps, lr=self.finetune_lr, batch_size=min(4, len(shots)))
        return subject
