"""Where ``lsr export`` bundles exported on first use are cached, and the files a bundle holds: torch-free, so that
finding a cached bundle (``lsr.export.find_bundle``) imports no torch, and shared with the export
(``lsr.export.bundle.cached_bundle``)."""

from __future__ import annotations

import hashlib
import importlib.util
import os
from pathlib import Path

SUBJECT_ENCODER_FILE = "subject_encoder.onnx"
FRAME_GENERATOR_FILE = "frame_generator.onnx"
FRAME_NETWORK_FILE = "frame_network.onnx"
"""The frame graph ending at G^s (``lsr.export.graphs.page_composite_sigma``), for the web page."""
MOUTH_FOLDER = "mouth"
"""``models_def.part_generator.MOUTH_FOLDER`` (a model's mouth generator, when it has one), named here without
importing torch."""


def onnx_cache_root() -> Path:
    """``$XDG_CACHE_HOME/lsr/onnx`` (default ``~/.cache/lsr/onnx``): bundles exported on first use."""
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache) / "lsr" / "onnx"


def bundle_cache_folder(weights: str | os.PathLike, cache_root: str | os.PathLike | None = None) -> Path:
    """Where ``lsr.export.bundle.cached_bundle`` keeps a model folder's bundle: keyed by a hash of config.json +
    model.safetensors (and its mouth generator's) and of the graphs' code (``models_def``'s sources and the exporter's,
    read, not imported): new weights or a changed graph = a new bundle."""
    weights = Path(weights)
    digest = hashlib.sha256()
    for name in ("config.json", "model.safetensors", f"{MOUTH_FOLDER}/config.json", f"{MOUTH_FOLDER}/model.safetensors"):
        if (weights / name).is_file() or not name.startswith(MOUTH_FOLDER):
            digest.update(name.encode() + (weights / name).read_bytes())
    graphs = Path(importlib.util.find_spec("models_def").origin).parent
    export = Path(__file__).resolve().parent
    # the code the graphs are traced from, and the code that traces them (which graphs, at which input sizes)
    for source in [*sorted(graphs.glob("*.py")), export / "graphs.py", export / "bundle.py"]:
        digest.update(source.name.encode() + source.read_bytes())
    root = Path(cache_root) if cache_root is not None else onnx_cache_root()
    return root / digest.hexdigest()[:20]


def holds_bundle(folder: Path) -> bool:
    """Whether ``folder`` holds an exported bundle (both graphs)."""
    return (folder / SUBJECT_ENCODER_FILE).is_file() and (folder / FRAME_GENERATOR_FILE).is_file()
