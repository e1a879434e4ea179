"""``lsr export``: a model folder -> the ONNX bundle that ``deploy.runtime.OnnxReenactor`` runs without torch.

Built on ``lsr.export.graphs`` (graph wrappers and the generic atomic ``export_onnx``). The bundle folder holds
* ``subject_encoder.onnx``: (shots, shot_landmark_images) (B, K, 3, S, S) -> (layout_latent, style_latent) (B, D),
  dynamic B and K;
* ``frame_generator.onnx``: (landmark_image (B, 3, S, S), layout_latent, style_latent) -> image (B, 3, S, S)
  [, layout (B, C_l, S, S) as a second output when the variant has one], dynamic B;
* ``frame_network.onnx`` for a warp-guided model whose composite the web page runs (``page_composite_sigma``): the
  same graph ending at G^s, its references and masks taken at S (pooled by the caller), its output ``network``
  (B, N + 4, S, S) its image and blend logits;
* with ``--int8``: ``frame_generator.int8.onnx``, static int8 quantisation of the network's dense convolutions but
  the SPADE heads (QOperator QLinearConv, per-channel int8 weights, uint8 activations), calibrated on real frames'
  landmark images and latents; the composite (the warp-guided blend, its depthwise blurs and element-wise ops)
  stays fp32 (``quantize_frame_generator`` says why). Dynamic quantisation is not offered: on these conv nets it
  was ~6x slower than fp32 on CPU. Only the per-frame graph is quantised (the subject encoder runs once per
  subject).
Every graph carries ``metadata_props``: preset, variant, resolution, latent_dim, layout_kind, landmark format,
lsr version, opset. Opset is fixed (``ONNX_OPSET``) so that every bundle runs on the same onnxruntime range.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
import torch.nn.functional as F

from landmarks.io.image_files import atomic_output, make_readable
from lsr import __version__
from lsr.errors import ConfigError, WeightsError
from lsr.export.bundle_cache import (FRAME_GENERATOR_FILE, FRAME_NETWORK_FILE, SUBJECT_ENCODER_FILE,
                                     bundle_cache_folder, holds_bundle)
from lsr.export.graphs import SUBJECT_GRAPH_IO, FrameGeneratorGraph, export_onnx, frame_graph_io, page_composite_sigma
from lsr.pipeline import load_mouth, load_model
from models_def import PRESET_NAMES, LSRModel, ModelConfig, preset_config
from models_def.part_generator import PartGenerator

if TYPE_CHECKING:
    from lsr.config import ExportConfig

ONNX_OPSET = 17
FRAME_GENERATOR_INT8_FILE = "frame_generator.int8.onnx"
MOUTH_GENERATOR_FILE = "mouth_generator.onnx"
LANDMARK_FORMAT = "ibug68-contour-rgb"  # landmarks.shape.raster.draw_landmarks at the model resolution, [-1, 1]


@dataclasses.dataclass
class ExportResult:
    folder: Path
    files: list[Path]
    metadata: dict[str, str]
    int8_error: tuple[float, float] | None = None
    """(max, mean) abs error of the int8 frame generator against fp32 on the calibration frames (images in [-1, 1])."""


def preset_name_of(config: ModelConfig) -> str:
    """The preset a config was built from (variant aside), or 'custom'."""
    for name in PRESET_NAMES:
        if preset_config(name, variant=config.variant) == config.replace(variant=config.variant):
            return name
    return "custom"


def bundle_metadata(config: ModelConfig, crop_size: int | None = None) -> dict[str, str]:
    warp_references = config.warp_references if config.uses_references else 0
    return {
        "lsr_version": __version__,
        "preset": preset_name_of(config),
        "variant": config.variant,
        "resolution": str(config.resolution),
        "latent_dim": str(config.latent_dim),
        "layout_kind": config.layout_kind,
        "layout_channels": str(config.layout_channels),
        "landmark_format": LANDMARK_FORMAT,
        "opset": str(ONNX_OPSET),
        "model_config": json.dumps(config.to_dict(), sort_keys=True),
        "warp_references": str(warp_references),
        # the side of the references a warp_guided graph takes (and of its image); the model resolution otherwise
        "crop_size": str(crop_size or config.resolution * (config.crop_scale if warp_references else 1)),
    }


def set_metadata(path: Path, metadata: dict[str, str]) -> None:
    """Write ``metadata_props`` into an ONNX file (atomically)."""
    import onnx

    model = onnx.load(str(path))
    del model.metadata_props[:]
    for key, value in metadata.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, str(value)
    with atomic_output(path) as temp:
        onnx.save(model, str(temp))


def export_graphs(model: LSRModel, out: str | os.PathLike, *, shots: int = 2,
                  mouth_generator: PartGenerator | None = None) -> ExportResult:
    """Export both graphs of ``model`` into ``out`` (fp32) with metadata, and ``mouth_generator``'s
    (``MOUTH_GENERATOR_FILE``) when given. ``shots``: K of the example input."""
    config = model.config
    if config.variant == "oracle_seg":
        raise WeightsError("'oracle_seg' models need a ground-truth segmentation per frame and cannot be deployed")
    out = Path(out)
    model = model.eval().float().cpu()
    size, generator = config.resolution, torch.Generator().manual_seed(0)
    example_shots = torch.rand(1, shots, 3, size, size, generator=generator) * 2 - 1
    example_landmarks = torch.rand(1, shots, config.landmark_channels, size, size, generator=generator) * 2 - 1
    subject_path = export_onnx(model.subject_encoder, (example_shots, example_landmarks), out / SUBJECT_ENCODER_FILE,
                               *SUBJECT_GRAPH_IO, opset=ONNX_OPSET)
    with_layout = config.layout_kind != "none"
    graph = FrameGeneratorGraph(model.frame_generator, with_layout=with_layout)
    latents = model.subject_encoder(example_shots, example_landmarks)
    frame_inputs = (example_landmarks[:, 0], *latents)
    metadata = bundle_metadata(config)
    if config.uses_references:
        crop, count = int(metadata["crop_size"]), config.warp_references
        frame_inputs += (torch.rand(1, count, 3, crop, crop, generator=generator) * 2 - 1, torch.ones(1, count, 1, crop, crop))
    frame_path = export_onnx(graph, frame_inputs, out / FRAME_GENERATOR_FILE,
                             *frame_graph_io(model.frame_generator, with_layout), opset=ONNX_OPSET)
    files = [subject_path, frame_path]
    if config.uses_references and page_composite_sigma(config, int(metadata["crop_size"])) is not None:
        network = FrameGeneratorGraph(model.frame_generator, with_layout=with_layout, network_only=True)
        pooled = (F.avg_pool2d(frame_inputs[3].flatten(1, 2), crop // size).view(1, count, 3, size, size),
                  torch.ones(1, count, 1, size, size))  # the references at the network's side
        files.append(export_onnx(network, (*frame_inputs[:3], *pooled), out / FRAME_NETWORK_FILE,
                                 *frame_graph_io(model.frame_generator, with_layout, network_only=True),
                                 opset=ONNX_OPSET))
    if mouth_generator is not None:
        part = mouth_generator.eval().float().cpu()
        size = part.config.size
        example = (torch.rand(1, 3, size, size, generator=generator) * 2 - 1,
                   torch.rand(1, part.config.mask_channels, size, size, generator=generator))
        files.append(export_onnx(part, example, out / MOUTH_GENERATOR_FILE, ["window", "masks"], ["drawn"],
                                 {}, opset=ONNX_OPSET))
        metadata = {**metadata, "mouth_generator": json.dumps(part.config.to_dict())}
    for path in files:
        set_metadata(path, metadata)
    return ExportResult(out, files, metadata)


def cached_bundle(weights: str | os.PathLike, cache_root: str | os.PathLike | None = None) -> Path:
    """The fp32 ONNX bundle of a model folder, exported on first use into the cache and reused after
    (``lsr.export.bundle_cache.bundle_cache_folder``: new weights or a changed graph = a new bundle). The export goes
    into a temp folder that is renamed into place, so a crashed or concurrent first use never leaves a half bundle.
    """
    weights = Path(weights)
    folder = bundle_cache_folder(weights, cache_root)
    if holds_bundle(folder):
        return folder
    root = folder.parent
    root.mkdir(parents=True, exist_ok=True)
    temp = Path(tempfile.mkdtemp(dir=root, prefix=f".{folder.name}.", suffix=".tmp"))
    try:
        print(f"exporting {weights} to ONNX once (cached in {folder})")
        export_graphs(load_model(weights), temp, mouth_generator=load_mouth(weights))
        make_readable(temp)  # mkdtemp makes 0700
        try:
            os.replace(temp, folder)
        except OSError:  # another process finished first: keep its bundle
            if not (folder / FRAME_GENERATOR_FILE).is_file():
                raise
    finally:
        shutil.rmtree(temp, ignore_errors=True)
    return folder


class _FrameCalibration:
    """onnxruntime CalibrationDataReader over frame-generator inputs (one frame per read)."""

    def __init__(self, inputs: Sequence[dict[str, np.ndarray]]) -> None:
        self._inputs = list(inputs)
        self._position = 0

    def get_next(self) -> dict[str, np.ndarray] | None:
        if self._position >= len(self._inputs):
            return None
        self._position += 1
        return self._inputs[self._position - 1]

    def rewind(self) -> None:
        self._position = 0


INT8_QUANTIZATION = ("int8 static QOperator, the network's dense convolutions but the SPADE heads "
                     "(per-channel int8 weights, uint8 activations)")


def quantized_convolutions(path: Path) -> list[str]:
    """Names of the Conv nodes of a frame graph that ``quantize_frame_generator`` makes int8: the dense (one-group)
    convolutions of the network, less the SPADE heads (a conv whose output is split into 1 + gamma and beta). Those
    stay fp32: an 8-bit 1 + gamma, on a range that must include 0, moves every normalised activation by ~0.4 % per
    norm (an untrained tiny model's int8 image was off by 0.14 mean abs with them, 0.007 without)."""
    import onnx

    nodes = onnx.load(str(path), load_external_data=False).graph.node
    split = {node.input[0] for node in nodes if node.op_type == "Split"}

    def groups(node) -> int:
        return next((attribute.i for attribute in node.attribute if attribute.name == "group"), 1)

    return [node.name for node in nodes if node.op_type == "Conv" and groups(node) == 1 and node.output[0] not in split]


def quantize_frame_generator(fp32_path: Path, int8_path: Path, calibration: Sequence[dict[str, np.ndarray]]) -> Path:
    """Static int8 quantisation of the frame graph's network convolutions (``quantized_convolutions``), calibrated on
    ``calibration`` (name -> (1, ...) float32); every other node stays fp32.

    Measured on the default model (onnxruntime 1.32, one thread, a loaded 2-core AMD EPYC, issue 65): quantising every
    node (QDQ) made the graph ~1.8x slower than fp32, the Quantize/Dequantize pairs around the blend's ~150
    element-wise nodes costing more than int8 saves, at 49 dB PSNR against fp32; every Conv as QDQ (the depthwise
    blurs too) was ~1.2x slower; ``quantized_convolutions`` as QLinearConv (QOperator) run ~4 % faster than fp32, at
    65 dB (QDQ of the same nodes: ~2 % faster)."""
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    if not calibration:
        raise ConfigError("int8 quantisation needs calibration frames (landmark images + latents); none were given")
    with tempfile.TemporaryDirectory() as folder, atomic_output(int8_path) as temp:
        # Constants folded first: the exporter puts equal initializers (an untrained model's zero biases) behind
        # Identity nodes, and QLinearConv's bias quantisation reads initializers only.
        prepared = Path(folder) / "prepared.onnx"
        quant_pre_process(str(fp32_path), str(prepared), skip_symbolic_shape=True)
        quantize_static(
            str(prepared), str(temp), _FrameCalibration(calibration), quant_format=QuantFormat.QOperator,
            op_types_to_quantize=["Conv"], nodes_to_quantize=quantized_convolutions(prepared),
            activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, per_channel=True,
            calibrate_method=CalibrationMethod.MinMax,
        )
    import onnx

    metadata = {p.key: p.value for p in onnx.load(str(fp32_path), load_external_data=False).metadata_props}
    set_metadata(int8_path, {**metadata, "quantization": INT8_QUANTIZATION})
    return int8_path


def graph_error(reference_path: Path, other_path: Path, inputs: Sequence[dict[str, np.ndarray]]) -> tuple[float, float]:
    """(max, mean) abs difference of the first output of two ONNX graphs over ``inputs``."""
    import onnxruntime as ort

    sessions = [ort.InferenceSession(str(p), providers=["CPUExecutionProvider"]) for p in (reference_path, other_path)]
    max_abs, total = 0.0, 0.0
    for feed in inputs:
        first, second = (session.run(None, feed)[0] for session in sessions)
        difference = np.abs(first - second)
        max_abs, total = max(max_abs, float(difference.max())), total + float(difference.mean())
    return max_abs, total / max(1, len(inputs))


def calibration_inputs(weights: str | os.PathLike | LSRModel, source, driver, *, k: int | None = None,
                       frames: int = 32) -> list[dict[str, np.ndarray]]:
    """Frame-graph inputs of real frames: ``driver``'s first ``frames`` landmark images and ``source``'s latents
    (and its shots warped onto them, for a warp-guided model), as ``ReenactorBase.network_inputs`` makes them."""
    from lsr.pipeline import Reenactor

    reenactor = Reenactor(weights)
    reenactor.encode_subject(source, k=k)
    feeds = []
    for frame in reenactor(driver):
        if frame.landmarks is not None:
            feeds.append({name: np.asarray(value, np.float32)
                          for name, value in reenactor.network_inputs(frame.landmarks)[1].items()})
        if len(feeds) >= frames:
            break
    return feeds


def run_export(cfg: ExportConfig) -> ExportResult:
    """Entry point of ``lsr export`` (``lsr.config.ExportConfig``)."""
    from landmarks.io.image_files import check_output_path
    from lsr.weights import resolve_weights

    check_output_path(cfg.out, "--out", folder=True)  # before the model loads and traces
    weights = resolve_weights(cfg.weights)
    model = load_model(weights)
    result = export_graphs(model, cfg.out, mouth_generator=load_mouth(weights))
    print(f"wrote {', '.join(p.name for p in result.files)} to {result.folder} "
          f"(opset {ONNX_OPSET}, preset {result.metadata['preset']}, {result.metadata['resolution']}^2)")
    if cfg.int8:
        from lsr.examples import REAL_DRIVER, REAL_SOURCE

        # by default the bundled example (a woman driven by a man: the frames a user's run feeds the graph), never
        # an evaluation clip: calibrating is choosing the int8 ranges
        source = cfg.calibration_source or REAL_SOURCE
        driver = cfg.calibration_driver or (source if cfg.calibration_source is not None else REAL_DRIVER)
        feeds = calibration_inputs(model, source, driver, k=cfg.calibration_k, frames=cfg.calibration_frames)
        int8_path = quantize_frame_generator(result.folder / FRAME_GENERATOR_FILE,
                                             result.folder / FRAME_GENERATOR_INT8_FILE, feeds)
        result.files.append(int8_path)
        result.int8_error = graph_error(result.folder / FRAME_GENERATOR_FILE, int8_path, feeds)
        print(f"int8 frame generator vs fp32 over {len(feeds)} calibration frame(s): max abs error "
              f"{result.int8_error[0]:.4g}, mean abs error {result.int8_error[1]:.4g} (images in [-1, 1])")
    return result
