"""Where the ONNX bundle of a model folder is (``--runtime onnx``): found without importing torch."""

from __future__ import annotations

from pathlib import Path

from lsr.errors import ConfigError
from lsr.weights import is_model_folder


def onnx_bundle_folder(weights: Path) -> Path:
    """--weights for --runtime onnx: an ``lsr export`` bundle, a model folder holding one in ``onnx/``, or a model
    folder without one (exported on first use into the cache, ``lsr.export.bundle.cached_bundle``)."""
    for folder in (weights, weights / "onnx"):
        if (folder / "subject_encoder.onnx").is_file():
            return folder
    if is_model_folder(weights):
        from lsr.export.bundle import cached_bundle  # torch: only when a bundle must be made

        return cached_bundle(weights)
    raise ConfigError(f"--runtime onnx: {weights} holds neither an ONNX bundle (subject_encoder.onnx) nor a model "
                      "(config.json + model.safetensors)")
