"""diffusers-style ``save_pretrained`` / ``from_pretrained``: config.json beside model.safetensors, no pickles.

A folder holds exactly one module: ``config.json`` (the ``ModelConfig`` fields plus ``_class_name``) and
``model.safetensors`` (its state dict). Loading rebuilds the module from the config and loads the weights
strictly; every mismatch is a ``ModelConfigError`` that says what to do.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import TypeVar

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from models_def.config import ModelConfig, ModelConfigError

CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"

T = TypeVar("T", bound="PretrainedMixin")


def _atomic_write(path: Path, write) -> None:
    """Write through a temp file in the same folder, then os.replace: readers never see half a file."""
    handle, temp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(handle)
    try:
        write(temp_name)
        umask = os.umask(0)  # mkstemp makes 0600: give the file the mode a plain open() would
        os.umask(umask)
        os.chmod(temp_name, 0o666 & ~umask)
        os.replace(temp_name, path)
    except BaseException:
        Path(temp_name).unlink(missing_ok=True)
        raise


class PretrainedMixin:
    """Adds ``save_pretrained(folder)`` and ``from_pretrained(folder)`` to a module built as ``cls(config)``."""

    config: ModelConfig

    def save_pretrained(self, folder: str | os.PathLike) -> Path:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        config = {"_class_name": type(self).__name__, **self.config.to_dict()}
        # Weights first, config last: a folder with a config.json is complete.
        tensors = {name: tensor.detach().contiguous().cpu() for name, tensor in self.state_dict().items()}
        _atomic_write(folder / WEIGHTS_NAME, lambda temp: save_file(tensors, temp, metadata={"format": "pt"}))
        text = json.dumps(config, indent=2, sort_keys=True) + "\n"
        _atomic_write(folder / CONFIG_NAME, lambda temp: Path(temp).write_text(text))
        return folder

    @classmethod
    def from_pretrained(cls: type[T], folder: str | os.PathLike, device: str | torch.device = "cpu") -> T:
        folder = Path(folder)
        config_path, weights_path = folder / CONFIG_NAME, folder / WEIGHTS_NAME
        for path in (config_path, weights_path):
            if not path.is_file():
                raise ModelConfigError(
                    f"{path} not found; a model folder needs {CONFIG_NAME} and {WEIGHTS_NAME} "
                    f"(written by {cls.__name__}.save_pretrained)"
                )
        try:
            values = json.loads(config_path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ModelConfigError(f"cannot read {config_path}: {exc}; re-save the model") from exc
        if not isinstance(values, dict):
            raise ModelConfigError(f"{config_path} must hold a JSON object of ModelConfig fields")
        class_name = values.pop("_class_name", cls.__name__)
        if class_name != cls.__name__:
            raise ModelConfigError(f"{folder} holds a {class_name}, not a {cls.__name__}; load it with {class_name}")
        model = cls(ModelConfig.from_dict(values))
        try:
            state = load_file(weights_path, device=str(device))
        except (OSError, SafetensorError) as exc:
            raise ModelConfigError(f"cannot read {weights_path}: {exc}; re-save the model") from exc
        expected = model.state_dict()
        missing, unexpected = sorted(set(expected) - set(state)), sorted(set(state) - set(expected))
        wrong_shape = [k for k in set(expected) & set(state) if expected[k].shape != state[k].shape]
        if missing or unexpected or wrong_shape:
            raise ModelConfigError(
                f"{weights_path} does not match {config_path}: missing {missing[:5]}, unexpected {unexpected[:5]}, "
                f"wrong shape {sorted(wrong_shape)[:5]} ({len(missing)}/{len(unexpected)}/{len(wrong_shape)} in all); "
                "the weights were saved from a different config"
            )
        model.load_state_dict(state, strict=True)
        return model.to(device)
