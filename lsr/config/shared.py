"""What many commands' configs share, declared once: the optional-value types of --help, the --weights and
metric-weights checks, where the shared real data is, and the evaluation split's options."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Annotated

import tyro

from lsr.errors import ConfigError

OptionalPath = Annotated[Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(optional)")]
"""An optional path option: shown as ``--opt PATH ... (optional)`` in --help, not ``{None}|PATH (default: None)``."""


def check_weights(weights: str | os.PathLike | None, label: str = "--weights") -> None:
    """The one ``--weights`` check of every command: None (the default model) or an existing folder."""
    if weights is not None and not Path(weights).is_dir():
        raise ConfigError(f"{label} {weights} is not a folder: give a model folder (config.json + model.safetensors "
                          "from `lsr train`, or an `lsr export` bundle)")


OptionalInt = Annotated[int | None, tyro.conf.arg(metavar="INT", help_behavior_hint="(optional)")]
OptionalFloat = Annotated[float | None, tyro.conf.arg(metavar="FLOAT", help_behavior_hint="(optional)")]
OptionalStr = Annotated[str | None, tyro.conf.arg(metavar="STR", help_behavior_hint="(optional)")]


def check_metric_weights(lpips_weights: Path | None, fid_weights: Path | None) -> None:
    """The --lpips-weights / --fid-weights check of `lsr eval` and `lsr bench ablation`: unset or an existing file."""
    for flag, path in (("--lpips-weights", lpips_weights), ("--fid-weights", fid_weights)):
        if path is not None and not Path(path).is_file():
            raise ConfigError(f"{flag} {path} is not a file; pass an existing weights file or leave {flag} unset")


def shared_data_dir() -> Path:
    """Real data beside the project: $LSR_SHARED_DATA, default ../shared/data from the repo root."""
    return Path(os.environ.get("LSR_SHARED_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))


def evaluation_data(data: Path | None) -> Path:
    """``data``, or the shared FSTH sample (../shared/data/fsth_eval_sample or $LSR_SHARED_DATA/fsth_eval_sample)."""
    if data is not None:
        return Path(data)
    shared = shared_data_dir() / "fsth_eval_sample"
    if not shared.is_dir():
        raise ConfigError(f"no --data given and the shared FSTH sample {shared} is absent; pass --data FOLDER")
    return shared


@dataclasses.dataclass
class SplitOptions:
    """Which frames of each identity the protocol reads (thesis §4.4): declared once for lsr eval and lsr bench
    ablation."""

    inputs: int = 32
    """lsr dataset: the first N frames of an identity are its inputs (the K shots are drawn from them) ..."""
    holdouts: int = 32
    """... and the next N frames its hold-outs."""
    max_holdouts: int = 0
    """Use only the first N hold-out frames per identity (0 = all)."""
    max_identities: int = 0
    """Use only the first N identities of each split (0 = all)."""
