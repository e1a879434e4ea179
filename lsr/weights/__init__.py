"""The shipped default model: ``lsr/weights/default`` (config.json + model.safetensors + discriminator.safetensors).

It was trained on procedural synthetic heads only (``lsr synth``); MODEL_CARD.md gives the recipe, the
metrics and what it can and cannot do. ``lsr ship RUN/weights`` copies a training run's weights here.
"""

from __future__ import annotations

import os
from pathlib import Path

from lsr.errors import LsrError

DEFAULT_WEIGHTS = Path(__file__).resolve().parent / "default"
"""Where the default model lives inside the installed package."""
ENV_VAR = "LSR_WEIGHTS"
"""Environment variable naming another model folder to use wherever --weights is left unset."""


class MissingWeightsError(LsrError):
    """No model folder where one is expected."""


def is_model_folder(folder: str | os.PathLike) -> bool:
    folder = Path(folder)
    return (folder / "config.json").is_file() and (folder / "model.safetensors").is_file()


def default_weights() -> Path:
    """$LSR_WEIGHTS when set, else the shipped default model. Raises ``MissingWeightsError`` when it is absent."""
    override = os.environ.get(ENV_VAR)
    folder = Path(override) if override else DEFAULT_WEIGHTS
    if not is_model_folder(folder):
        where = f"${ENV_VAR}={override}" if override else f"the installed package ({folder})"
        raise MissingWeightsError(
            f"no model (config.json + model.safetensors) in {where}; "
            + (f"unset {ENV_VAR} or point it at a model folder" if override else
               "reinstall the package (pip install -e .) or pass --weights RUN/weights from `lsr train`")
        )
    return folder


def resolve_weights(weights: str | os.PathLike | None) -> Path:
    """``--weights`` when given, else the default model (see ``default_weights``)."""
    return Path(weights) if weights is not None else default_weights()
