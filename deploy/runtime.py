"""``OnnxReenactor``: LSR re-enactment from an ``lsr export`` bundle with onnxruntime. No torch anywhere.

Needs numpy, onnxruntime, OpenCV and the ``landmarks`` toolkit (dlib only for ``detector="hog"`` / ``"cnn"``). Same API as ``lsr.pipeline.Reenactor``
(both are ``lsr.core.engine.ReenactorBase``; only the backend differs):

    reenactor = OnnxReenactor("bundle/")               # subject_encoder.onnx + frame_generator.onnx
    reenactor.encode_subject("person.jpg", k=1)
    for frame in reenactor("driving.mp4", paste_back=True):
        use(frame.image)                                # (H, W, 3) uint8 RGB

``int8=True`` runs ``frame_generator.int8.onnx`` (``lsr export --int8``) for the per-frame graph.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lsr.core.engine import ReenactorBase
from landmarks.exceptions import InputFileError

SUBJECT_ENCODER_FILE = "subject_encoder.onnx"
FRAME_GENERATOR_FILE = "frame_generator.onnx"
FRAME_GENERATOR_INT8_FILE = "frame_generator.int8.onnx"
MOUTH_GENERATOR_FILE = "mouth_generator.onnx"
GPU_PROVIDERS = ("CUDAExecutionProvider",)  # tried first where this onnxruntime has them (all fp32)
CPU_PROVIDER = "CPUExecutionProvider"

LOG = logging.getLogger("deploy.runtime")


class BundleError(InputFileError):
    """An ONNX bundle folder is missing a graph or its metadata (re-run ``lsr export``)."""


def choose_providers(available: Sequence[str], asked: Sequence[str] | None = None) -> list[str]:
    """The execution providers to ask onnxruntime for, in order: those ``asked`` (None: ``GPU_PROVIDERS``) that
    ``available`` (``onnxruntime.get_available_providers()``) holds, then the CPU, always last."""
    wanted = GPU_PROVIDERS if asked is None else asked
    return [*(provider for provider in wanted if provider in available and provider != CPU_PROVIDER), CPU_PROVIDER]


def onnx_session(path: Path, providers: Sequence[str] | None = None, threads: int = 0):
    """An onnxruntime session of the graph at ``path`` on ``choose_providers(available, providers)``; where it cannot
    be made there, on the CPU alone (the reason logged). Which providers it runs on is logged (``deploy.runtime``, at
    INFO). threads: intra-op threads (0 = onnxruntime's default)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    if threads > 0:
        options.intra_op_num_threads = threads
    chosen = choose_providers(ort.get_available_providers(), providers)
    attempts = [chosen] if chosen == [CPU_PROVIDER] else [chosen, [CPU_PROVIDER]]
    for attempt in attempts:
        try:
            session = ort.InferenceSession(str(path), options, providers=attempt)
        except Exception as exc:  # onnxruntime raises its own untyped errors for bad files and failing providers
            failure = exc
            if attempt is not attempts[-1]:
                LOG.warning("%s could not be loaded on %s (%s); loading it on the CPU", path.name, ", ".join(attempt), exc)
            continue
        LOG.info("%s runs on %s", path.name, ", ".join(session.get_providers()))
        return session
    raise BundleError(f"cannot load {path} with onnxruntime: {failure}; re-run `lsr export`") from failure


class OnnxBackend:
    """``lsr.core.backend.SynthesisBackend`` over the two ONNX graphs of a bundle folder."""

    def __init__(self, folder: str | os.PathLike, *, int8: bool = False, providers: list[str] | None = None,
                 threads: int = 0) -> None:
        folder = Path(folder)
        frame_name = FRAME_GENERATOR_INT8_FILE if int8 else FRAME_GENERATOR_FILE
        for name in (SUBJECT_ENCODER_FILE, frame_name):
            if not (folder / name).is_file():
                hint = "`lsr export --int8`" if name == FRAME_GENERATOR_INT8_FILE else "`lsr export --weights DIR --out FOLDER`"
                raise BundleError(f"{folder / name} not found; make the ONNX bundle with {hint}")
        self.folder = folder
        self.subject_session = onnx_session(folder / SUBJECT_ENCODER_FILE, providers, threads)
        self.frame_session = onnx_session(folder / frame_name, providers, threads)
        self.providers = self.frame_session.get_providers()  # where the per-frame graph runs
        self.metadata = dict(self.frame_session.get_modelmeta().custom_metadata_map)
        try:
            self.resolution = int(self.metadata["resolution"])
            self.layout_kind = self.metadata["layout_kind"]
            self.config = json.loads(self.metadata.get("model_config", "{}"))
            self.warp_references = int(self.metadata.get("warp_references", 0))
            self.crop_size = int(self.metadata.get("crop_size", self.resolution))
        except (KeyError, ValueError) as exc:
            raise BundleError(f"{folder / frame_name} lacks LSR metadata ({exc}); re-run `lsr export`") from exc
        self.frame_outputs = [output.name for output in self.frame_session.get_outputs()]
        mouth = folder / MOUTH_GENERATOR_FILE
        self.mouth_session = onnx_session(mouth, providers, threads) if mouth.is_file() else None
        self.mouth_generator_size = 0 if self.mouth_session is None else int(self.mouth_session.get_inputs()[0].shape[-1])

    def draw_mouth(self, window: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """The mouth generator (``lsr.core.backend.SynthesisBackend``): (1, 3, P, P) + (1, 2, P, P) -> (1, 3, P, P)."""
        if self.mouth_session is None:
            raise BundleError(f"{self.folder} has no {MOUTH_GENERATOR_FILE}")
        feed = {"window": np.ascontiguousarray(window, np.float32), "masks": np.ascontiguousarray(masks, np.float32)}
        return self.mouth_session.run(["drawn"], feed)[0]

    def encode_subject(self, shots: np.ndarray, shot_landmark_images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(1, K, 3, S, S) each, in [-1, 1] -> (layout_latent, style_latent), (1, D) float32 each."""
        feed = {"shots": np.ascontiguousarray(shots, np.float32),
                "shot_landmark_images": np.ascontiguousarray(shot_landmark_images, np.float32)}
        layout_latent, style_latent = self.subject_session.run(["layout_latent", "style_latent"], feed)
        return layout_latent, style_latent

    def synthesize(self, landmark_image: np.ndarray, layout_latent: np.ndarray, style_latent: np.ndarray,
                   with_layout: bool, references: np.ndarray | None = None,
                   reference_masks: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """(B, 3, S, S) + (B, D) latents [+ references, reference_masks at ``crop_size``, warp-guided bundles]
        -> (image (B, 3, C, C) in [-1, 1], layout (B, C_l, S, S) or None); see ``lsr.core.backend.SynthesisBackend``."""
        feed = {"landmark_image": np.ascontiguousarray(landmark_image, np.float32),
                "layout_latent": np.ascontiguousarray(layout_latent, np.float32),
                "style_latent": np.ascontiguousarray(style_latent, np.float32)}
        if self.warp_references:
            if references is None or reference_masks is None or references.shape[-1] != self.crop_size:
                raise BundleError(f"{self.folder}: a warp-guided bundle needs references at {self.crop_size}^2 "
                                  "(run it through OnnxReenactor, which warps the shots)")
            feed["references"] = np.ascontiguousarray(references, np.float32)
            feed["reference_masks"] = np.ascontiguousarray(reference_masks, np.float32)
        wanted = ["image", "layout"] if with_layout and "layout" in self.frame_outputs else ["image"]
        outputs = self.frame_session.run(wanted, feed)
        return outputs[0], outputs[1] if len(outputs) > 1 else None


class OnnxReenactor(ReenactorBase):
    """Torch-free re-enactment. folder: an ``lsr export`` bundle. int8: use the quantised frame generator.

    providers: onnxruntime execution providers (``choose_providers``: default CUDA when available, else CPU); threads: intra-op
    threads (0 = onnxruntime's default). detector: "mesh" (the default) | "hog" | "cnn" (dlib), or a detector. API as ``lsr.pipeline.Reenactor``.
    """

    def __init__(self, folder: str | os.PathLike, *, int8: bool = False, providers: list[str] | None = None,
                 threads: int = 0, detector: str | object = "mesh") -> None:
        backend = OnnxBackend(folder, int8=int8, providers=providers, threads=threads)
        super().__init__(backend, detector=detector, crop_size=backend.crop_size)

    @property
    def metadata(self) -> dict[str, str]:
        return self.backend.metadata
