"""Copy a training run's weights into the package as the default model: ``lsr ship RUN/weights``.

Copies config.json, model.safetensors and (when present) discriminator.safetensors and the mouth generator
(``mouth/``) into ``lsr/weights/default``
through a temp folder renamed into place, checks that the copy loads, and prints sizes and SHA-256 sums for
MODEL_CARD.md. Weights may be trained on synthetic heads and on the shared real training clips
(``real_talking_heads``, whose provenance MODEL_CARD.md must list); never on the evaluation people
(see ../shared/data/README.md).
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from landmarks.io.image_files import atomic_folder
from lsr.weights import DEFAULT_WEIGHTS, MissingWeightsError, is_model_folder

if TYPE_CHECKING:
    from lsr.config import ShipConfig

FILES = ("config.json", "model.safetensors", "discriminator.safetensors", "layout_legend.json", "mouth/config.json",
         "mouth/model.safetensors")
MAX_MB = 25.0


def ship(run_weights: str | os.PathLike, target: str | os.PathLike = DEFAULT_WEIGHTS) -> list[tuple[str, int, str]]:
    """Copy ``run_weights`` to ``target`` atomically; returns (file, bytes, sha256) per shipped file."""
    from models_def import LSRModel
    from models_def.part_generator import load_mouth_generator

    source, target = Path(run_weights), Path(target)
    if not is_model_folder(source):
        raise MissingWeightsError(f"{source} is not a model folder (config.json + model.safetensors)")
    names = [name for name in FILES if (source / name).is_file()]
    total_mb = sum((source / name).stat().st_size for name in names) / 2**20
    if total_mb > MAX_MB:
        raise MissingWeightsError(f"{source} holds {total_mb:.1f} MB of weights; the package ships at most {MAX_MB} MB")
    with atomic_folder(target) as temp:
        for name in names:
            (temp / name).parent.mkdir(exist_ok=True)
            shutil.copyfile(source / name, temp / name)
        LSRModel.from_pretrained(temp)  # refuse to ship what does not load
        load_mouth_generator(temp)
    return [(name, (target / name).stat().st_size, hashlib.sha256((target / name).read_bytes()).hexdigest())
            for name in names]


def run_ship(cfg: ShipConfig) -> list[tuple[str, int, str]]:
    """Entry point of ``lsr ship RUN/weights`` (``lsr.config.ShipConfig``): ship, then print sizes and sums."""
    rows = ship(cfg.weights)
    print(f"shipped to {DEFAULT_WEIGHTS}:")
    for name, size, digest in rows:
        print(f"  {name:28s} {size / 2**20:7.2f} MB  sha256 {digest}")
    return rows
