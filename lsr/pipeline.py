"""Inference pipeline: load the weights once, encode the subject once, synthesise per frame (thesis §4.3).

``Reenactor`` is the torch runtime of the shared frame loop ``lsr.core.engine.ReenactorBase`` (source and
driver loading, tracking, retargeting, crop, rasterise, paste-back, pass-through of face-less frames live
there, torch-free, and serve ``deploy.runtime.OnnxReenactor`` too). This module adds only the torch glue:
``TorchBackend`` runs ``LSRModel.subject_encoder`` and ``LSRModel.frame_generator`` on numpy arrays.

    reenactor = Reenactor("runs/x/weights")               # fp32 on CPU by default
    reenactor.encode_subject("person.jpg")                 # or a folder, a video, several images; k=1..32
    for frame in reenactor("driving.mp4", paste_back=True):  # a generator: streams, one frame at a time
        writer.write(frame.image)

bf16 is an option (``precision="bf16"``); ``precision_error`` reports its error against fp32.
"""

from __future__ import annotations

import dataclasses
import os
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from lsr.core.backend import LayoutKind
from lsr.core.engine import ReenactorBase
from lsr.core.subject import Subject
from lsr.core.inputs import SubjectShots
from lsr.errors import ConfigError, WeightsError
from lsr.export.graphs import FrameGeneratorGraph
from models_def import LSRModel
from models_def.part_generator import PartGenerator, load_mouth_generator

Precision = Literal["fp32", "bf16"]
_DTYPES = {"fp32": torch.float32, "bf16": torch.bfloat16}


def load_model(weights: str | os.PathLike) -> LSRModel:
    """``LSRModel.from_pretrained`` with user-facing errors (a missing or mismatched folder says what to do)."""
    folder = Path(weights)
    if not folder.is_dir():
        raise WeightsError(
            f"weights folder not found: {folder}; pass --weights DIR holding config.json + model.safetensors "
            "(written by `lsr train` or LSRModel.save_pretrained)"
        )
    try:
        model = LSRModel.from_pretrained(folder)
    except ValueError as exc:  # models_def.ModelConfigError names the problem with the folder
        raise WeightsError(str(exc)) from exc
    if model.config.variant == "oracle_seg":
        raise WeightsError(
            f"{folder} is an 'oracle_seg' model: it needs the target's ground-truth segmentation, which a driving "
            "video does not have; re-enact with a latent_layout, learned_seg or spade_landmarks model"
        )
    return model.eval().requires_grad_(False)


def load_mouth(weights: Path) -> PartGenerator | None:
    """The weights folder's mouth generator (``models_def.part_generator.MOUTH_FOLDER``), or None; a broken one is a
    ``WeightsError``."""
    try:
        return load_mouth_generator(weights)
    except ValueError as exc:  # models_def.ModelConfigError names the problem with the folder
        raise WeightsError(str(exc)) from exc


_TRACING = threading.Lock()  # one trace at a time: warnings.catch_warnings changes process-wide state


class TorchBackend:
    """``lsr.core.backend.SynthesisBackend`` over an ``LSRModel`` (numpy in, numpy out, fp32 results).

    One frame at a time in fp32 on the CPU (the frame loop), the frame generator runs traced (``torch.jit.trace``,
    per input shape; the trace shares the model's parameters, and a new ``model`` drops it): eager mode dispatches
    each of its ~hundreds of ops from Python, taking the GIL each time, so beside ``lsr reenact``'s other stages on
    threads it ran 1.4x slower (torch end to end 18.5 -> 27 fps on the shared tpsmm_driving.mp4, mesh tracker, 2
    cores; outputs within 3e-7). Batches, bf16, other devices and oracle segmentations run eagerly.
    """

    def __init__(self, model: LSRModel, device: str | torch.device = "cpu", precision: Precision = "fp32",
                 mouth_generator: PartGenerator | None = None) -> None:
        if precision not in _DTYPES:
            raise ConfigError(f"precision must be 'fp32' or 'bf16', got {precision!r}")
        self.model = model.eval().requires_grad_(False)
        self.device = torch.device(device)
        self.precision = precision
        self.model.to(self.device)
        self.resolution = model.config.resolution
        self.layout_kind: LayoutKind = model.config.layout_kind  # type: ignore[assignment]
        self.warp_references = model.config.warp_references if model.config.uses_references else 0
        self.crop_scale = model.config.crop_scale
        self.mouth_generator = None if mouth_generator is None else mouth_generator.eval().requires_grad_(False)
        self.mouth_generator_size = 0 if mouth_generator is None else mouth_generator.config.size

    @torch.inference_mode()
    def draw_mouth(self, window: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """The mouth generator (``lsr.core.backend.SynthesisBackend``): (1, 3, P, P) + (1, 2, P, P) -> (1, 3, P, P)."""
        if self.mouth_generator is None:
            raise ConfigError("this model has no mouth generator")
        return self.mouth_generator(torch.from_numpy(np.ascontiguousarray(window, np.float32)),
                                    torch.from_numpy(np.ascontiguousarray(masks, np.float32))).numpy()

    @property
    def model(self) -> LSRModel:
        return self._model

    @model.setter
    def model(self, model: LSRModel) -> None:  # fine-tuning swaps in a copy and back: its traces go with it
        self._model = model
        self._traced: dict[tuple, torch.jit.ScriptModule | None] = {}

    def _traced_frame(self, with_layout: bool, tensors: tuple[torch.Tensor, ...]) -> torch.jit.ScriptModule | None:
        """The frame generator traced for these inputs' shapes (once; shape-dependent Python in the model, e.g. the
        blur's radius, is fixed per shape, as in the ONNX export of the same call); None where tracing fails (a
        torch without ``torch.jit.trace``, which torch 2.15 deprecates: then eager mode, as before)."""
        import warnings

        key = (with_layout, *(tuple(tensor.shape) for tensor in tensors))
        if key not in self._traced:
            with _TRACING, warnings.catch_warnings():  # shapes read as Python numbers (keyed above); the deprecation
                warnings.simplefilter("ignore", torch.jit.TracerWarning)
                warnings.simplefilter("ignore", FutureWarning)
                try:
                    self._traced[key] = torch.jit.trace(FrameGeneratorGraph(self.model.frame_generator, with_layout),
                                                        tensors, check_trace=False)
                except Exception:  # noqa: BLE001 - any failure to trace leaves the exact eager path
                    self._traced[key] = None
        return self._traced[key]

    def _autocast(self):
        # bf16 via autocast keeps norms/softmax in fp32 where torch deems it necessary (fp32 is the default).
        return torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.precision == "bf16")

    def _tensor(self, array: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(array, np.float32)).to(self.device)

    @torch.inference_mode()
    def encode_subject(self, shots: np.ndarray, shot_landmark_images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(1, K, 3, S, S) each, in [-1, 1] -> (layout_latent, style_latent), (1, D) float32 each."""
        with self._autocast():
            layout_latent, style_latent = self.model.subject_encoder(self._tensor(shots), self._tensor(shot_landmark_images))
        return layout_latent.float().cpu().numpy(), style_latent.float().cpu().numpy()

    @torch.inference_mode()
    def synthesize(
        self, landmark_image: np.ndarray, layout_latent: np.ndarray, style_latent: np.ndarray, with_layout: bool,
        references: np.ndarray | None = None, reference_masks: np.ndarray | None = None,
        oracle_segmentation: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """(B, 3, S, S) + (B, D) latents -> (image (B, 3, S, S) in [-1, 1], layout (B, C_l, S, S) or None).

        references / reference_masks: warp-guided models (``lsr.core.backend.SynthesisBackend``); the image is then at
        their side. oracle_segmentation: (B, 19, S, S) one-hot ground truth, for ``oracle_seg`` models only (evaluation).
        """
        oracle = None if oracle_segmentation is None else self._tensor(oracle_segmentation)
        warped = None if references is None else self._tensor(references)
        masks = None if reference_masks is None else self._tensor(reference_masks)
        with_layout = with_layout and self.model.config.layout_kind != "none"
        if (oracle is None and len(landmark_image) == 1 and self.precision == "fp32" and self.device.type == "cpu"
                and (warped is None) == (masks is None)):
            latents = (layout_latent, style_latent) if self.model.config.uses_layout_predictor else (style_latent,)
            inputs = (self._tensor(landmark_image), *map(self._tensor, latents),  # the ONNX export's frame graph
                      *((warped, masks) if warped is not None else ()))
            traced = self._traced_frame(with_layout, inputs)
            if traced is not None:
                result = traced(*inputs)
                image, layout = result if with_layout else (result, None)
                return image.numpy(), None if layout is None else layout.numpy()
        with self._autocast():
            outputs = self.model.frame_generator.synthesize(
                self._tensor(landmark_image), self._tensor(layout_latent), self._tensor(style_latent), oracle,
                references=warped, reference_masks=masks,
            )
        layout = outputs.layout.float().cpu().numpy() if with_layout and outputs.layout is not None else None
        return outputs.image.float().cpu().numpy(), layout


@dataclasses.dataclass(frozen=True)
class PrecisionError:
    """Error of a faster precision against fp32 on the same inputs (images in [-1, 1])."""

    precision: str
    frames: int
    max_abs: float
    mean_abs: float

    def __str__(self) -> str:
        return (f"{self.precision} vs fp32 over {self.frames} frame(s): max abs error {self.max_abs:.4g}, "
                f"mean abs error {self.mean_abs:.4g} (images in [-1, 1])")


class Reenactor(ReenactorBase):
    """Torch re-enactment (inference only). API: ``encode_subject``, ``reenact`` / ``__call__`` (``ReenactorBase``).

    weights: model folder (config.json + model.safetensors). device: "cpu", "cuda", ... precision: "fp32"
    (default) or "bf16". detector: "mesh" (the default) | "hog" | "cnn" (dlib), or a detector, for the source shots and the driver. crop_size: the
    crop and output side (``lsr.core.engine.default_crop_size``: 2x the model resolution for warp-guided models).
    mouth_generator: a part generator that redraws the mouth (``lsr.core.finish``); default: the weights folder's
    ``mouth/``, when it has one.
    """

    def __init__(
        self,
        weights: str | os.PathLike | LSRModel,
        *,
        device: str | torch.device = "cpu",
        precision: Precision = "fp32",
        detector: str | object = "mesh",
        crop_size: int | None = None,
        mouth_generator: PartGenerator | None = None,
    ) -> None:
        model = weights if isinstance(weights, LSRModel) else load_model(weights)
        self.weights_path = None if isinstance(weights, LSRModel) else Path(weights)
        mouth = mouth_generator if mouth_generator is not None or self.weights_path is None else load_mouth(self.weights_path)
        super().__init__(TorchBackend(model, device, precision, mouth), detector=detector, crop_size=crop_size)

    @property
    def model(self) -> LSRModel:
        return self.backend.model

    def precision_error(self, driver_landmarks: Iterable[np.ndarray], precision: Precision = "bf16") -> PrecisionError:
        """Synthesise the same crop landmarks (each (68, 2) in crop pixels) in fp32 and ``precision``; print and return the error."""
        subject = self._require_subject()
        reference = Reenactor(self.backend.model, device=self.backend.device, precision="fp32")
        other = Reenactor(self.backend.model, device=self.backend.device, precision=precision)
        for runtime in (reference, other):
            runtime.subject = Subject(subject.shots, subject.layout_latent, subject.style_latent, subject.source)
        max_abs, total, count = 0.0, 0.0, 0
        for points in driver_landmarks:
            inputs = reference.network_inputs(points)[1]  # a warp-guided model's warped shots included
            extra = (inputs["references"], inputs["reference_masks"]) if "references" in inputs else ()
            outputs = [r.backend.synthesize(inputs["landmark_image"], inputs["layout_latent"], inputs["style_latent"],
                                            False, *extra)[0] for r in (reference, other)]
            difference = np.abs(outputs[0] - outputs[1])
            max_abs, total, count = max(max_abs, float(difference.max())), total + float(difference.mean()), count + 1
        if count == 0:
            raise ConfigError("precision_error needs at least one set of driver landmarks")
        error = PrecisionError(precision, count, max_abs, total / count)
        print(error)
        return error


def subject_shots_from_training(frames: np.ndarray, landmarks: np.ndarray, meshes: np.ndarray | None = None) -> SubjectShots:
    """Wrap already-cropped shots ((K, S, S, 3) uint8, (K, 68, 2) crop pixels, optionally (K, 468, 3) meshes in
    the same pixels) for ``encode_subject``."""
    return SubjectShots(np.asarray(frames, np.uint8), np.asarray(landmarks, np.float32),
                        [f"shot#{i}" for i in range(len(frames))],
                        meshes=None if meshes is None else np.asarray(meshes, np.float32))
