"""Where the ONNX bundle of a model folder is (``--runtime onnx``): found without importing torch."""

from __future__ import annotations

from pathlib import Path

from lsr.errors import ConfigError
from lsr.export.bundle_cache import SUBJECT_ENCODER_FILE, bundle_cache_folder, holds_bundle
from lsr.weights import is_model_folder


def onnx_bundle_folder(weights: Path) -> Path:
    """--weights for --runtime onnx: an ``lsr export`` bundle, a model folder holding one in ``onnx/``, or a model
    folder without one (exported on first use into the cache, ``lsr.export.bundle.cached_bundle``; a cache hit
    imports no torch)."""
    for folder in (weights, weights / "onnx"):
        if (folder / SUBJECT_ENCODER_FILE).is_file():
            return folder
    if is_model_folder(weights):
        cached = bundle_cache_folder(weights)
        if holds_bundle(cached):
            return cached
        from lsr.export.bundle import cached_bundle  # torch: only when a bundle must be made

        return cached_bundle(weights)
    raise ConfigError(f"--runtime onnx: {weights} holds neither an ONNX bundle (subject_encoder.onnx) nor a model "
                      "(config.json + model.safetensors)")
